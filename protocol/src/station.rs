use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::message::Message;
use crate::text::FixedText;

/// Whether a [`StationEvent`] opens or closes a station.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum StationEventKind {
    /// The station starts: its pose and chunks follow.
    Begin = 0,
    /// The station is done: everything it sent has been sent.
    End = 1,
}

/// Job control opens and closes a station; `End` says how much should have arrived.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.StationEvent.v3")]
#[repr(C)]
pub struct StationEvent {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// A [`StationEventKind`] as `u8`; read it with [`StationEvent::kind`].
    pub kind: u8,
    /// Which try at the station this is: 1 for the first, one more each time the cell scans
    /// or sends the station again (after an `Interrupted` or incomplete report). 0, from a
    /// version 1 sender, reads as 1.
    pub attempt: u8,
    /// The station's number within the job, chosen by the cell.
    pub station: u32,
    /// The job (one print) the station belongs to.
    pub job: u64,
    /// When the cell started the job, nanoseconds since the Unix epoch: the same in every event
    /// of the job, also after the cell restarts, so that with `job` it tells one print from a
    /// later one that reuses the number. 0 when the sender does not say (versions 1 and 2).
    pub job_started_ns: u64,
    /// When the cell sent the event, nanoseconds since the Unix epoch.
    pub timestamp_ns: u64,
    /// Index of the last printed layer when this station was scanned.
    pub layer: u32,
    /// Chunks the scanner will send (Begin, if known) or has sent (End); 0 when unknown.
    pub expected_chunks: u32,
    /// Points the scanner will send or has sent; 0 when unknown.
    pub expected_points: u64,
    /// Height of the printed part in the design frame, metres; NaN when not printing.
    pub printed_height: f64,
    /// The station's name for people (reports, the viewer), at most 48 bytes of UTF-8.
    pub name: FixedText<48>,
}

crate::message::message!(StationEvent, "asbuilt.StationEvent.v3", 3, oldest 3);

impl StationEvent {
    /// The kind, or `None` for a value no known sender writes.
    pub fn kind(&self) -> Option<StationEventKind> {
        match self.kind {
            0 => Some(StationEventKind::Begin),
            1 => Some(StationEventKind::End),
            _ => None,
        }
    }

    /// An event of `kind` for a station, with nothing expected and no printed height.
    pub fn new(kind: StationEventKind, job: u64, station: u32) -> Self {
        Self {
            version: Self::VERSION,
            kind: kind as u8,
            attempt: 1,
            station,
            job,
            job_started_ns: 0,
            timestamp_ns: 0,
            layer: 0,
            expected_chunks: 0,
            expected_points: 0,
            printed_height: f64::NAN,
            name: FixedText::empty(),
        }
    }
}

/// A [`StationEvent`] as versions 1 and 2 wrote it, without `job_started_ns`: recordings of
/// those releases still read.
#[derive(Debug, Clone, Copy, Deserialize)]
pub(crate) struct StationEventV2 {
    _version: u16,
    kind: u8,
    attempt: u8,
    station: u32,
    job: u64,
    timestamp_ns: u64,
    layer: u32,
    expected_chunks: u32,
    expected_points: u64,
    printed_height: f64,
    name: FixedText<48>,
}

impl From<StationEventV2> for StationEvent {
    fn from(e: StationEventV2) -> Self {
        Self {
            // Read into this version's layout: what it lacks is said as unknown.
            version: Self::VERSION,
            kind: e.kind,
            attempt: e.attempt,
            station: e.station,
            job: e.job,
            job_started_ns: 0,
            timestamp_ns: e.timestamp_ns,
            layer: e.layer,
            expected_chunks: e.expected_chunks,
            expected_points: e.expected_points,
            printed_height: e.printed_height,
            name: e.name,
        }
    }
}
