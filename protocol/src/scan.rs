use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::message::Message;

/// The user header of a scan chunk; the points follow as a `[ScanPoint]` slice payload.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.ChunkHeader.v2")]
#[repr(C)]
pub struct ChunkHeader {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// The station's attempt the chunk belongs to (see [`crate::StationEvent::attempt`]); a
    /// u16 so that a version 1 record, which had a zero here, reads the same.
    pub attempt: u16,
    /// The station the chunk belongs to, as its Begin numbered it.
    pub station: u32,
    /// The job (one print) the station belongs to.
    pub job: u64,
    /// Starts at 0 for each station and counts up by one; gaps and repeats are detected.
    pub sequence: u64,
    /// When the scanner sent the chunk, nanoseconds since the Unix epoch.
    pub timestamp_ns: u64,
    /// Number of points in the slice that follows.
    pub point_count: u32,
    /// Set on the last chunk of a station, so the station can close without waiting.
    pub last: u8,
    /// Zero; keeps the layout free of padding.
    pub _reserved2: [u8; 3],
}

crate::message::message!(ChunkHeader, "asbuilt.ChunkHeader.v2", 2, oldest 1);

/// Required by iceoryx2 to loan a sample with this header; a real header comes from `new`.
impl Default for ChunkHeader {
    fn default() -> Self {
        Self::new(0, 0, 0, 0)
    }
}

impl ChunkHeader {
    /// The header of chunk `sequence` of a station holding `point_count` points, not last.
    pub fn new(job: u64, station: u32, sequence: u64, point_count: u32) -> Self {
        Self {
            version: Self::VERSION,
            attempt: 1,
            station,
            job,
            sequence,
            timestamp_ns: 0,
            point_count,
            last: 0,
            _reserved2: [0; 3],
        }
    }
}

/// Bit flags of a [`ScanPoint`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
pub struct ScanPointFlags(pub u16);

impl ScanPointFlags {
    /// The scanner marked the measurement invalid (no return, saturated...).
    pub const INVALID: u16 = 1 << 0;

    /// Whether the scanner marked the point invalid.
    pub fn is_invalid(self) -> bool {
        self.0 & Self::INVALID != 0
    }
}

/// One measured point in the scanner's own frame. f32 keeps 0.01 mm at 200 m range.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.ScanPoint.v1")]
#[repr(C)]
pub struct ScanPoint {
    /// Metres, scanner frame.
    pub xyz: [f32; 3],
    /// Return strength as the file or scanner gives it (LAS scaled to 0..1); 0 when unknown.
    pub intensity: f32,
    /// What the scanner says of the point.
    pub flags: ScanPointFlags,
    /// Return number (1-based) in the low nibble, number of returns in the high nibble; 0 unknown.
    pub returns: u8,
    /// Zero; keeps the layout free of padding.
    pub _reserved: u8,
}

impl ScanPoint {
    /// A valid point at (x, y, z), metres in the scanner frame, intensity 0.
    pub fn new(x: f32, y: f32, z: f32) -> Self {
        Self {
            xyz: [x, y, z],
            ..Self::default()
        }
    }
}
