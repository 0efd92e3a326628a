use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::message::Message;
use crate::text::FixedText;

/// Bins of the signed-distance histogram carried in every report.
pub const HISTOGRAM_BINS: usize = 64;

/// Streaming statistics of the signed distances of the matched points of a station.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
pub struct DeviationStats {
    /// Points with a distance (valid and matched).
    pub count: u64,
    /// Mean signed distance, metres.
    pub mean: f64,
    /// Standard deviation of the signed distances, metres.
    pub std: f64,
    /// Root mean square of the signed distances, metres.
    pub rms: f64,
    /// Smallest signed distance, metres.
    pub min: f64,
    /// Largest signed distance, metres.
    pub max: f64,
    /// Median of |d|, estimated from a histogram; see `asbuilt_core::stats` for the error bound.
    pub median_abs: f64,
    /// 95th percentile of |d|, same estimate.
    pub p95_abs: f64,
    /// |d| <= tolerance.
    pub within: u64,
    /// d > tolerance (excess material).
    pub above: u64,
    /// d < -tolerance (missing material).
    pub below: u64,
}

/// Fixed-bin histogram of signed distances over `[low, high)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
pub struct Histogram {
    /// Lower edge of the first bin, metres.
    pub low: f64,
    /// Upper edge of the last bin, metres.
    pub high: f64,
    /// Distances below `low`.
    pub underflow: u64,
    /// Distances at or above `high`.
    pub overflow: u64,
    /// Counts of the equal bins between `low` and `high`.
    #[serde(with = "bounded_bins")]
    pub bins: [u64; HISTOGRAM_BINS],
}

impl Default for Histogram {
    fn default() -> Self {
        Self {
            low: 0.0,
            high: 0.0,
            underflow: 0,
            overflow: 0,
            bins: [0; HISTOGRAM_BINS],
        }
    }
}

/// Points that were not used, by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
pub struct RejectCounts {
    /// NaN or infinite coordinates.
    pub non_finite: u64,
    /// Coordinates beyond any plausible scanner range.
    pub out_of_range: u64,
    /// Marked invalid by the scanner.
    pub scanner_invalid: u64,
    /// Arrived for a station without a usable pose.
    pub without_pose: u64,
    /// In a chunk rejected whole: oversized, repeated, too late, or whose header disagrees with
    /// its payload.
    pub in_rejected_chunks: u64,
}

impl std::ops::AddAssign for RejectCounts {
    fn add_assign(&mut self, o: Self) {
        self.non_finite += o.non_finite;
        self.out_of_range += o.out_of_range;
        self.scanner_invalid += o.scanner_invalid;
        self.without_pose += o.without_pose;
        self.in_rejected_chunks += o.in_rejected_chunks;
    }
}

impl RejectCounts {
    /// Every rejected point, whatever the reason.
    pub fn total(&self) -> u64 {
        self.non_finite
            + self.out_of_range
            + self.scanner_invalid
            + self.without_pose
            + self.in_rejected_chunks
    }
}

/// How a station's chunk stream went.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
pub struct ChunkCounts {
    /// Chunks that arrived for the station.
    pub received: u64,
    /// From the station's End event; 0 when unknown.
    pub expected: u64,
    /// Chunks whose sequence had already arrived (dropped).
    pub duplicate: u64,
    /// Chunks that arrived after a later one.
    pub out_of_order: u64,
    /// Sequences that never arrived, as far as the last sequence or End says.
    pub missing: u64,
    /// Chunks without points.
    pub empty: u64,
    /// Chunks larger than the agent accepts (dropped, their points counted rejected).
    pub oversized: u64,
}

/// How a station closed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum StationStatus {
    /// Everything that was announced arrived.
    #[default]
    Complete = 0,
    /// Chunks or points are missing, repeated or out of order.
    Incomplete = 1,
    /// No End event within the station timeout.
    TimedOut = 2,
    /// The agent shut down while the station was open.
    Partial = 3,
    /// The agent stopped unplanned (killed, power lost) while the station was open, or it
    /// started after the station had begun sending: the cell scans or sends the station again
    /// as its next attempt. Reported as soon as the agent is back.
    Interrupted = 4,
}

/// What the crew gets back when a station closes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.StationReport.v2")]
#[repr(C)]
pub struct StationReport {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// A [`StationStatus`] as `u8`; read it with [`StationReport::status`].
    pub status: u8,
    /// The station's attempt this report is about (see [`crate::StationEvent::attempt`]).
    pub attempt: u8,
    /// The station's number within the job, as its Begin numbered it.
    pub station: u32,
    /// The job (one print) the station belongs to.
    pub job: u64,
    /// The last printed layer when the station was scanned, from its Begin.
    pub layer: u32,
    /// Zero; keeps the layout free of padding.
    pub _reserved2: u32,
    /// The station's name, from its Begin.
    pub name: FixedText<48>,
    /// Metres; NaN when not printing.
    pub printed_height: f64,
    /// The tolerance the points were judged with, metres.
    pub tolerance: f64,
    /// Points farther than this from the design had no match, metres.
    pub max_distance: f64,
    /// One-sigma position uncertainty of the station's pose, metres.
    pub position_sigma: f64,
    /// Every point that arrived, good or bad.
    pub points_received: u64,
    /// Valid points farther than `max_distance` from the design.
    pub no_match: u64,
    /// Statistics of the matched points' signed distances.
    pub stats: DeviationStats,
    /// Rejected points by reason.
    pub rejected: RejectCounts,
    /// How the station's chunks arrived.
    pub chunks: ChunkCounts,
    /// Histogram of the matched points' signed distances.
    pub histogram: Histogram,
}

crate::message::message!(StationReport, "asbuilt.StationReport.v2", 2, oldest 1);

impl StationReport {
    /// The status, or `None` for a value no known sender writes.
    pub fn status(&self) -> Option<StationStatus> {
        match self.status {
            0 => Some(StationStatus::Complete),
            1 => Some(StationStatus::Incomplete),
            2 => Some(StationStatus::TimedOut),
            3 => Some(StationStatus::Partial),
            4 => Some(StationStatus::Interrupted),
            _ => None,
        }
    }

    /// An empty report of a complete station: no points, no chunks.
    pub fn new(job: u64, station: u32) -> Self {
        Self {
            version: Self::VERSION,
            status: StationStatus::Complete as u8,
            attempt: 1,
            station,
            job,
            layer: 0,
            _reserved2: 0,
            name: FixedText::empty(),
            printed_height: f64::NAN,
            tolerance: 0.0,
            max_distance: 0.0,
            position_sigma: 0.0,
            points_received: 0,
            no_match: 0,
            stats: DeviationStats::default(),
            rejected: RejectCounts::default(),
            chunks: ChunkCounts::default(),
            histogram: Histogram::default(),
        }
    }
}

/// On the wire the bins are a `heapless::Vec`, so a decoder never allocates for them and a
/// record with a different bin count is rejected instead of misread.
mod bounded_bins {
    use super::HISTOGRAM_BINS;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub fn serialize<S: Serializer>(bins: &[u64; HISTOGRAM_BINS], s: S) -> Result<S::Ok, S::Error> {
        let v = heapless::Vec::<u64, HISTOGRAM_BINS>::from_slice(bins)
            .map_err(|_| serde::ser::Error::custom("histogram larger than its capacity"))?;
        v.serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[u64; HISTOGRAM_BINS], D::Error> {
        let v = heapless::Vec::<u64, HISTOGRAM_BINS>::deserialize(d)?;
        v.as_slice().try_into().map_err(|_| {
            serde::de::Error::custom(format!(
                "histogram has {} bins, expected {HISTOGRAM_BINS}",
                v.len()
            ))
        })
    }
}
