use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::codec::Message;
use crate::text::FixedText;

/// Bins of the signed-distance histogram carried in every report.
pub const HISTOGRAM_BINS: usize = 64;

/// Streaming statistics of the signed distances of the matched points of a station.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
pub struct DeviationStats {
    /// Points with a distance (valid and matched).
    pub count: u64,
    pub mean: f64,
    pub std: f64,
    pub rms: f64,
    pub min: f64,
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
    pub low: f64,
    pub high: f64,
    pub underflow: u64,
    pub overflow: u64,
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
    pub received: u64,
    /// From the station's End event; 0 when unknown.
    pub expected: u64,
    pub duplicate: u64,
    pub out_of_order: u64,
    pub missing: u64,
    pub empty: u64,
    pub oversized: u64,
}

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
}

/// What the crew gets back when a station closes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.StationReport.v1")]
#[repr(C)]
pub struct StationReport {
    pub version: u16,
    /// A [`StationStatus`] as `u8`; read it with [`StationReport::status`].
    pub status: u8,
    pub _reserved: u8,
    pub station: u32,
    pub job: u64,
    pub layer: u32,
    pub _reserved2: u32,
    pub name: FixedText<48>,
    /// Metres; NaN when not printing.
    pub printed_height: f64,
    pub tolerance: f64,
    pub max_distance: f64,
    pub position_sigma: f64,
    /// Every point that arrived, good or bad.
    pub points_received: u64,
    /// Valid points farther than `max_distance` from the design.
    pub no_match: u64,
    pub stats: DeviationStats,
    pub rejected: RejectCounts,
    pub chunks: ChunkCounts,
    pub histogram: Histogram,
}

crate::codec::message!(StationReport, "asbuilt.StationReport.v1", 1);

impl StationReport {
    pub fn status(&self) -> Option<StationStatus> {
        match self.status {
            0 => Some(StationStatus::Complete),
            1 => Some(StationStatus::Incomplete),
            2 => Some(StationStatus::TimedOut),
            3 => Some(StationStatus::Partial),
            _ => None,
        }
    }

    pub fn new(job: u64, station: u32) -> Self {
        Self {
            version: Self::VERSION,
            status: StationStatus::Complete as u8,
            _reserved: 0,
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
