//! One station's inspection, chunk by chunk: validate each scan point, bring it into the design
//! frame, find its signed distance, write a [`PointDeviation`] for it and fold it into the
//! station's statistics. The agent and `asbuilt inspect` both run exactly this, so they report
//! the same bits for the same points.
//!
//! State is the statistics only: memory does not grow with the number of points.

use asbuilt_protocol::{
    DeviationFlags, DeviationHeader, Feature, FixedText, PointDeviation, RejectCounts, ScanPoint,
    StationReport,
};
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

use crate::c2m::triangle::Region;
use crate::c2m::{C2mIndex, Cursor};
use crate::stats::{DeviationAccumulator, StatsConfig};

/// Scanner-frame coordinates beyond this are not measurements (the longest-range TLS reach
/// about 1 km); such points are rejected as out of range.
pub const DEFAULT_MAX_RANGE: f64 = 2_000.0;

/// Points per parallel task: large enough to amortise scheduling, small enough to balance.
const TASK_POINTS: usize = 4096;

#[derive(Debug, Clone, Copy)]
pub struct InspectConfig {
    pub stats: StatsConfig,
    /// Metres, scanner frame.
    pub max_range: f64,
}

impl InspectConfig {
    pub fn with_tolerance(tolerance: f64) -> Self {
        Self {
            stats: StatsConfig::with_tolerance(tolerance),
            max_range: DEFAULT_MAX_RANGE,
        }
    }
}

/// What one chunk produced, beyond the deviations written to the output slice.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChunkOutcome {
    pub rejected: u32,
    pub no_match: u32,
    pub out_of_tolerance: u32,
}

pub struct StationInspector<'a> {
    index: &'a C2mIndex,
    t_design_scanner: Isometry3<f64>,
    config: InspectConfig,
    stats: DeviationAccumulator,
    rejected: RejectCounts,
    points_received: u64,
    no_match: u64,
}

struct TaskTally {
    stats: DeviationAccumulator,
    rejected: RejectCounts,
    outcome: ChunkOutcome,
    no_match: u64,
}

impl<'a> StationInspector<'a> {
    pub fn new(
        index: &'a C2mIndex,
        t_design_scanner: Isometry3<f64>,
        config: InspectConfig,
    ) -> Self {
        Self {
            index,
            t_design_scanner,
            config,
            stats: DeviationAccumulator::new(config.stats),
            rejected: RejectCounts::default(),
            points_received: 0,
            no_match: 0,
        }
    }

    /// Counts points that could not be used because their station has no pose.
    pub fn reject_without_pose(&mut self, points: u64) {
        self.points_received += points;
        self.rejected.without_pose += points;
    }

    /// Processes one chunk; `out[i]` receives the deviation of `points[i]`.
    pub fn process(&mut self, points: &[ScanPoint], out: &mut [PointDeviation]) -> ChunkOutcome {
        assert_eq!(points.len(), out.len(), "one deviation per scan point");
        let index = self.index;
        let t = self.t_design_scanner;
        let config = self.config;
        let tally = points
            .par_chunks(TASK_POINTS)
            .zip(out.par_chunks_mut(TASK_POINTS))
            .map(|(ps, os)| inspect_task(index, &t, &config, ps, os))
            .reduce_with(|mut a, b| {
                a.stats.merge(&b.stats);
                a.rejected += b.rejected;
                a.outcome.rejected += b.outcome.rejected;
                a.outcome.no_match += b.outcome.no_match;
                a.outcome.out_of_tolerance += b.outcome.out_of_tolerance;
                a.no_match += b.no_match;
                a
            });
        self.points_received += points.len() as u64;
        let Some(tally) = tally else {
            return ChunkOutcome::default();
        };
        self.stats.merge(&tally.stats);
        self.rejected += tally.rejected;
        self.no_match += tally.no_match;
        tally.outcome
    }

    /// Fills a deviation chunk header for the outcome of [`Self::process`].
    pub fn header(
        job: u64,
        station: u32,
        sequence: u64,
        count: usize,
        o: ChunkOutcome,
    ) -> DeviationHeader {
        let mut h = DeviationHeader::new(job, station, sequence);
        h.point_count = count as u32;
        h.rejected = o.rejected;
        h.no_match = o.no_match;
        h.out_of_tolerance = o.out_of_tolerance;
        h
    }

    pub fn stats(&self) -> &DeviationAccumulator {
        &self.stats
    }

    pub fn rejected(&self) -> RejectCounts {
        self.rejected
    }

    pub fn points_received(&self) -> u64 {
        self.points_received
    }

    pub fn no_match(&self) -> u64 {
        self.no_match
    }

    /// The station's report so far.
    pub fn report(&self, job: u64, station: u32, name: &str) -> StationReport {
        let mut r = StationReport::new(job, station);
        r.name = FixedText::truncated(name);
        r.tolerance = self.config.stats.tolerance;
        r.max_distance = self.index.max_distance();
        r.points_received = self.points_received;
        r.no_match = self.no_match;
        r.stats = self.stats.finish();
        r.rejected = self.rejected;
        r.histogram = self.stats.histogram();
        r
    }
}

fn inspect_task(
    index: &C2mIndex,
    t: &Isometry3<f64>,
    config: &InspectConfig,
    points: &[ScanPoint],
    out: &mut [PointDeviation],
) -> TaskTally {
    let mut tally = TaskTally {
        stats: DeviationAccumulator::new(config.stats),
        rejected: RejectCounts::default(),
        outcome: ChunkOutcome::default(),
        no_match: 0,
    };
    let mut cursor = Cursor::default();
    let tol = config.stats.tolerance;
    for (sp, o) in points.iter().zip(out) {
        let [x, y, z] = sp.xyz;
        let reject = if !(x.is_finite() && y.is_finite() && z.is_finite()) {
            Some(&mut tally.rejected.non_finite)
        } else if sp.flags.is_invalid() {
            Some(&mut tally.rejected.scanner_invalid)
        } else if (x as f64).abs().max((y as f64).abs()).max((z as f64).abs()) > config.max_range {
            Some(&mut tally.rejected.out_of_range)
        } else {
            None
        };
        if let Some(counter) = reject {
            *counter += 1;
            tally.outcome.rejected += 1;
            *o = PointDeviation {
                position: [x as f64, y as f64, z as f64],
                distance: f64::NAN,
                triangle: u32::MAX,
                feature: Feature::None as u8,
                feature_index: 0,
                flags: DeviationFlags(DeviationFlags::REJECTED),
                _reserved: 0,
            };
            continue;
        }
        let p = t * Point3::new(x as f64, y as f64, z as f64);
        *o = match index.query(&p, &mut cursor) {
            None => {
                tally.no_match += 1;
                tally.outcome.no_match += 1;
                PointDeviation {
                    position: p.into(),
                    distance: f64::NAN,
                    triangle: u32::MAX,
                    feature: Feature::None as u8,
                    feature_index: 0,
                    flags: DeviationFlags(DeviationFlags::NO_MATCH),
                    _reserved: 0,
                }
            }
            Some(c) => {
                tally.stats.push(c.distance);
                let mut flags = 0;
                if c.distance.abs() > tol {
                    flags |= DeviationFlags::OUT_OF_TOLERANCE;
                    tally.outcome.out_of_tolerance += 1;
                }
                let (feature, feature_index) = match c.region {
                    Region::Face => (Feature::Face, 0),
                    Region::Edge(i) => (Feature::Edge, i),
                    Region::Vertex(i) => (Feature::Vertex, i),
                };
                PointDeviation {
                    position: p.into(),
                    distance: c.distance,
                    triangle: c.triangle,
                    feature: feature as u8,
                    feature_index,
                    flags: DeviationFlags(flags),
                    _reserved: 0,
                }
            }
        };
    }
    tally
}
