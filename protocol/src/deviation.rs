use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::message::Message;

/// The user header of a deviation chunk; a `[PointDeviation]` slice follows, one entry per
/// scan point of the chunk with the same `sequence`, in the same order.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.DeviationHeader.v1")]
#[repr(C)]
pub struct DeviationHeader {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// Zero; keeps the layout free of padding.
    pub _reserved: u16,
    /// The station the chunk belongs to, as its Begin numbered it.
    pub station: u32,
    /// The job (one print) the station belongs to.
    pub job: u64,
    /// The `sequence` of the scan chunk these deviations answer.
    pub sequence: u64,
    /// When the agent finished the chunk, nanoseconds since the Unix epoch.
    pub timestamp_ns: u64,
    /// Deviations in the slice that follows, one per scan point of the chunk.
    pub point_count: u32,
    /// Points of the chunk that were rejected (non-finite, out of range, flagged by the scanner).
    pub rejected: u32,
    /// Points farther than the maximum distance from the design.
    pub no_match: u32,
    /// Points outside the tolerance band.
    pub out_of_tolerance: u32,
}

crate::message::message!(DeviationHeader, "asbuilt.DeviationHeader.v1", 1);

/// Required by iceoryx2 to loan a sample with this header; a real header comes from `new`.
impl Default for DeviationHeader {
    fn default() -> Self {
        Self::new(0, 0, 0)
    }
}

impl DeviationHeader {
    /// The header of chunk `sequence` of a station, all counts zero.
    pub fn new(job: u64, station: u32, sequence: u64) -> Self {
        Self {
            version: Self::VERSION,
            _reserved: 0,
            station,
            job,
            sequence,
            timestamp_ns: 0,
            point_count: 0,
            rejected: 0,
            no_match: 0,
            out_of_tolerance: 0,
        }
    }
}

/// Which part of the closest triangle the closest design point lies on. The sign of a distance
/// comes from this feature's angle-weighted pseudo-normal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum Feature {
    /// No closest point: the point was rejected or had no match.
    #[default]
    None = 0,
    /// The closest point lies inside a triangle.
    Face = 1,
    /// The closest point lies on an edge (`feature_index` says which).
    Edge = 2,
    /// The closest point is a vertex (`feature_index` says which).
    Vertex = 3,
}

/// Bit flags of a [`PointDeviation`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
pub struct DeviationFlags(pub u8);

impl DeviationFlags {
    /// Farther from the design than the maximum distance; `distance` is NaN, never clamped.
    pub const NO_MATCH: u8 = 1 << 0;
    /// The input point was rejected; `distance` is NaN and `position` is what arrived.
    pub const REJECTED: u8 = 1 << 1;
    /// |distance| exceeds the tolerance.
    pub const OUT_OF_TOLERANCE: u8 = 1 << 2;

    /// Whether flag `bit` (one of the constants above) is set.
    pub fn contains(self, bit: u8) -> bool {
        self.0 & bit != 0
    }
}

/// The deviation of one scan point from the design.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.PointDeviation.v1")]
#[repr(C)]
pub struct PointDeviation {
    /// Design frame, metres.
    pub position: [f64; 3],
    /// Signed distance to the design surface, metres; positive outside (excess material).
    pub distance: f64,
    /// Index of the closest design triangle; `u32::MAX` when there is none.
    pub triangle: u32,
    /// A [`Feature`] as `u8`; read it with [`PointDeviation::feature`].
    pub feature: u8,
    /// Which edge (0: v0-v1, 1: v1-v2, 2: v2-v0) or vertex (0..3) when `feature` says so.
    pub feature_index: u8,
    /// What happened to the point: no match, rejected, out of tolerance.
    pub flags: DeviationFlags,
    /// Zero; keeps the layout free of padding.
    pub _reserved: u8,
}

impl Feature {
    /// `None` for a value no known sender writes.
    pub fn from_u8(v: u8) -> Option<Self> {
        match v {
            0 => Some(Self::None),
            1 => Some(Self::Face),
            2 => Some(Self::Edge),
            3 => Some(Self::Vertex),
            _ => None,
        }
    }
}

impl PointDeviation {
    /// The closest feature, or `None` for a value no known sender writes.
    pub fn feature(&self) -> Option<Feature> {
        Feature::from_u8(self.feature)
    }
}
