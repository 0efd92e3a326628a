//! Every message asbuilt sends or records, and nothing else.
//!
//! Each payload is `#[repr(C)]`, fixed-size and [`ZeroCopySend`](iceoryx2::prelude::ZeroCopySend),
//! so it can travel through iceoryx2 shared memory without a copy, and the same type encodes to
//! postcard for the MCAP recorder through [`codec`]. Type names carry the message version
//! (`asbuilt.PoseSnapshot.v2`): iceoryx2 refuses to connect a publisher and a subscriber whose
//! type names differ, and [`codec::decode`] refuses a record written by another version, so a
//! version mismatch is always an error and never a misread.
//!
//! Units: metres, radians, nanoseconds since the Unix epoch.

#![warn(missing_docs)]

mod applied;
pub mod codec;
mod correction;
mod deviation;
mod findings;
pub mod foxglove;
pub mod ipc;
pub mod mcap_records;
mod message;
mod pose;
mod profile;
pub mod recording;
mod records;
mod report;
mod scan;
mod scan_planes;
mod sending;
mod services;
mod station;
mod status;
mod survey;
mod table;
mod text;

pub use applied::LayerApplied;
pub use correction::{CorrectionFlags, Evidence, LayerCorrection};
pub use deviation::{DeviationFlags, DeviationHeader, Feature, PointDeviation};
pub use findings::{
    FindingsHeader, LayerFinding, MAX_FINDINGS_BYTES, MAX_LAYER_ROWS, MAX_REGIONS, RegionFinding,
    RegionKind, StationFindings,
};
pub use message::{ChunkRecord, DecodeError, Message, Record, check_version};
pub use pose::{PoseMode, PoseSnapshot};
pub use profile::{
    MAX_PROFILES_PER_CHUNK, MountPose, ProfileHeader, ProfilePoint, ProfileShapeError,
};
pub use report::{
    ChunkCounts, DeviationStats, HISTOGRAM_BINS, Histogram, RejectCounts, StationReport,
    StationStatus,
};
pub use scan::{ChunkHeader, ScanPoint, ScanPointFlags};
pub use sending::{Paced, StationSender, StationSink};
pub use station::{StationEvent, StationEventKind};
pub use status::{AgentState, AgentStatus, InputRejects, OutputDrops};
pub use survey::{
    AbruptRow, DimensionRow, FlatnessRow, MAX_ABRUPT_ROWS, MAX_SURVEY_BYTES, MAX_SURVEY_ROWS,
    SurfaceFindings, SurveyDecisionRule, SurveyVerdict,
};
pub use text::{FixedText, TextTooLong};

/// Now, in the unit every message's `timestamp_ns` uses: nanoseconds since the Unix epoch
/// (0 if the clock is set before 1970).
pub fn unix_time_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}
