use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::codec::Message;
use crate::text::FixedText;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum StationEventKind {
    Begin = 0,
    End = 1,
}

/// Job control opens and closes a station; `End` says how much should have arrived.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.StationEvent.v1")]
#[repr(C)]
pub struct StationEvent {
    pub version: u16,
    /// A [`StationEventKind`] as `u8`; read it with [`StationEvent::kind`].
    pub kind: u8,
    pub _reserved: u8,
    pub station: u32,
    pub job: u64,
    pub timestamp_ns: u64,
    /// Index of the last printed layer when this station was scanned.
    pub layer: u32,
    /// Chunks the scanner will send (Begin, if known) or has sent (End); 0 when unknown.
    pub expected_chunks: u32,
    /// Points the scanner will send or has sent; 0 when unknown.
    pub expected_points: u64,
    /// Height of the printed part in the design frame, metres; NaN when not printing.
    pub printed_height: f64,
    pub name: FixedText<48>,
}

crate::codec::message!(StationEvent, "asbuilt.StationEvent.v1", 1);

impl StationEvent {
    pub fn kind(&self) -> Option<StationEventKind> {
        match self.kind {
            0 => Some(StationEventKind::Begin),
            1 => Some(StationEventKind::End),
            _ => None,
        }
    }

    pub fn new(kind: StationEventKind, job: u64, station: u32) -> Self {
        Self {
            version: Self::VERSION,
            kind: kind as u8,
            _reserved: 0,
            station,
            job,
            timestamp_ns: 0,
            layer: 0,
            expected_chunks: 0,
            expected_points: 0,
            printed_height: f64::NAN,
            name: FixedText::empty(),
        }
    }
}
