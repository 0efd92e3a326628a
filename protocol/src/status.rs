use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::message::Message;
use crate::report::RejectCounts;

/// What the agent is doing, as [`AgentStatus`] says it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum AgentState {
    /// Reading chunks and answering stations.
    Serving = 0,
    /// A termination signal arrived: open stations are being closed with partial reports.
    ShuttingDown = 1,
    /// Serving, but results have waited over a second for the recording's disk: the cell is
    /// told of them only once they are synced, so a slow or failing disk holds it back.
    HeldByDisk = 2,
}

/// Inputs the agent could not use, whole messages at a time, by reason. Points inside rejected
/// chunks are also counted per station in [`RejectCounts`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
pub struct InputRejects {
    /// Chunks for a station that never began (no `Begin` event or pose within the timeout).
    pub chunks_unknown_station: u64,
    /// Chunks for a station whose report was already sent.
    pub chunks_after_close: u64,
    /// Chunks pushed out of the bounded wait-for-pose buffer by newer ones.
    pub chunks_pending_overflow: u64,
    /// Chunks without points.
    pub chunks_empty: u64,
    /// Chunks larger than the agent accepts.
    pub chunks_oversized: u64,
    /// Chunks whose sequence had already arrived.
    pub chunks_duplicate: u64,
    /// Chunks that arrived after a later one of their station.
    pub chunks_out_of_order: u64,
    /// `point_count` in the header disagrees with the payload length.
    pub chunks_malformed: u64,
    /// Any message whose `version` field is not the one this build reads.
    pub version_mismatch: u64,
    /// Poses that cannot be used: unknown mode, non-unit quaternion, non-finite values.
    pub poses_invalid: u64,
    /// Events of an unknown kind, an `End` for a station that is not open, or a printer's
    /// answer ([`crate::LayerApplied`]) whose values are not usable.
    pub events_invalid: u64,
}

impl InputRejects {
    /// Every count with a short name for it, as the agent's health line gives them.
    pub fn by_reason(&self) -> [(&'static str, u64); 11] {
        [
            ("unknown station", self.chunks_unknown_station),
            ("after close", self.chunks_after_close),
            ("overflow", self.chunks_pending_overflow),
            ("duplicate", self.chunks_duplicate),
            ("out of order", self.chunks_out_of_order),
            ("empty", self.chunks_empty),
            ("oversized", self.chunks_oversized),
            ("malformed", self.chunks_malformed),
            ("version", self.version_mismatch),
            ("bad poses", self.poses_invalid),
            ("bad events", self.events_invalid),
        ]
    }

    /// Every rejected input, whatever the reason.
    pub fn total(&self) -> u64 {
        self.by_reason().iter().map(|(_, n)| n).sum()
    }
}

/// Outputs that did not reach every subscriber because the subscriber's queue was full: the agent
/// never waits for a slow consumer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
pub struct OutputDrops {
    /// Deviation chunks a full subscriber queue did not take.
    pub deviation_chunks: u64,
    /// Station reports a full subscriber queue did not take.
    pub reports: u64,
    /// Deviation chunks computed but not published because no output sample could be loaned.
    pub deviation_chunks_unloaned: u64,
}

/// The agent's health, published periodically and logged.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.AgentStatus.v1")]
#[repr(C)]
pub struct AgentStatus {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// An [`AgentState`] as `u8`; read it with [`AgentStatus::state`].
    pub state: u8,
    /// Zero; keeps the layout free of padding.
    pub _reserved: u8,
    /// The agent's operating-system process id.
    pub process_id: u32,
    /// When the status was taken, nanoseconds since the Unix epoch.
    pub timestamp_ns: u64,
    /// Nanoseconds since the agent started.
    pub uptime_ns: u64,
    /// Points of accepted chunks processed since start.
    pub points_processed: u64,
    /// Accepted chunks processed since start.
    pub chunks_processed: u64,
    /// Over the last status period.
    pub points_per_second: f64,
    /// Stations begun and not yet reported.
    pub stations_open: u32,
    /// Chunks held while they wait for their station's pose.
    pub chunks_waiting: u32,
    /// Stations reported since start.
    pub stations_reported: u64,
    /// Dead iceoryx2 nodes (crashed publishers) whose resources the agent removed.
    pub dead_nodes_cleaned: u64,
    /// Points rejected in all stations so far, by reason.
    pub rejected_points: RejectCounts,
    /// Inputs rejected whole, by reason.
    pub input: InputRejects,
    /// Outputs that did not reach every subscriber, by kind.
    pub output: OutputDrops,
}

crate::message::message!(AgentStatus, "asbuilt.AgentStatus.v1", 1);

impl AgentStatus {
    /// The state, or `None` for a value no known sender writes.
    pub fn state(&self) -> Option<AgentState> {
        match self.state {
            0 => Some(AgentState::Serving),
            1 => Some(AgentState::ShuttingDown),
            2 => Some(AgentState::HeldByDisk),
            _ => None,
        }
    }

    /// A serving agent's status with every count zero.
    pub fn new(process_id: u32) -> Self {
        Self {
            version: Self::VERSION,
            state: AgentState::Serving as u8,
            _reserved: 0,
            process_id,
            timestamp_ns: 0,
            uptime_ns: 0,
            points_processed: 0,
            chunks_processed: 0,
            points_per_second: 0.0,
            stations_open: 0,
            chunks_waiting: 0,
            stations_reported: 0,
            dead_nodes_cleaned: 0,
            rejected_points: RejectCounts::default(),
            input: InputRejects::default(),
            output: OutputDrops::default(),
        }
    }
}
