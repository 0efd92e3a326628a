//! One station's inspection, chunk by chunk: validate each scan point, bring it into the design
//! frame, find its signed distance, write a [`PointDeviation`] for it and fold it into the
//! station's statistics. The agent and `asbuilt inspect` both run exactly this, so they report
//! the same bits for the same points.
//!
//! State is the statistics only: memory does not grow with the number of points.

use asbuilt_protocol::{
    DeviationFlags, Feature, FixedText, PointDeviation, RejectCounts, ScanPoint, StationReport,
};
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

use crate::c2m::triangle::Region;
use crate::c2m::{Cursor, Surface};
use crate::order;
use crate::stats::{DeviationAccumulator, StatsConfig};

/// Scanner-frame coordinates beyond this are not measurements (the longest-range TLS reach
/// about 1 km); such points are rejected as out of range.
pub const DEFAULT_MAX_RANGE: f64 = 2_000.0;

/// Points per parallel task: large enough to amortise scheduling, small enough to balance.
const TASK_POINTS: usize = 4096;
/// A chunk in no spatial order (a merged or shuffled cloud) is queried in blocks of this many
/// points sorted along a Morton curve: nearby points then find the index's cells and triangles
/// still in cache. Results go back to the points' own places, and the statistics are exact in
/// any order, so the report's bits are those of the points in file order.
const SORT_BLOCK: usize = 1 << 16;
/// Chunks smaller than this are not worth sorting.
const SORT_MIN: usize = 8 * TASK_POINTS;

/// How a station's points are inspected.
#[derive(Debug, Clone, Copy)]
pub struct InspectParams {
    /// The tolerance and the histogram's range.
    pub stats: StatsConfig,
    /// Metres, scanner frame.
    pub max_range: f64,
}

impl InspectParams {
    /// The defaults around `tolerance` metres.
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
    /// Points rejected (non-finite, out of range, flagged by the scanner).
    pub rejected: u32,
    /// Valid points farther than the maximum distance.
    pub no_match: u32,
    /// Matched points beyond the tolerance.
    pub out_of_tolerance: u32,
}

/// Everything counted for a set of points: a task, a chunk, a station or a whole job. Merging is
/// exact, so a job's tally is the merge of its stations' whatever the order.
#[derive(Clone)]
pub struct Tally {
    /// Statistics of the matched points' distances.
    pub stats: DeviationAccumulator,
    /// Rejected points by reason.
    pub rejected: RejectCounts,
    /// Every point that arrived, good or bad.
    pub points_received: u64,
    /// Valid points farther than the maximum distance.
    pub no_match: u64,
}

impl Tally {
    /// Nothing counted yet.
    pub fn new(config: StatsConfig) -> Self {
        Self {
            stats: DeviationAccumulator::new(config),
            rejected: RejectCounts::default(),
            points_received: 0,
            no_match: 0,
        }
    }

    /// Adds another tally's counts.
    pub fn merge(&mut self, other: &Self) {
        self.stats.merge(&other.stats);
        self.rejected += other.rejected;
        self.points_received += other.points_received;
        self.no_match += other.no_match;
    }

    /// A report of these counts. What a tally cannot know (maximum distance, pose σ, layer,
    /// chunk counts) is the caller's to fill in.
    pub fn report(&self, job: u64, station: u32, name: &str) -> StationReport {
        let mut r = StationReport::new(job, station);
        r.name = FixedText::truncated(name);
        r.tolerance = self.stats.config().tolerance;
        r.points_received = self.points_received;
        r.no_match = self.no_match;
        r.stats = self.stats.finish();
        r.rejected = self.rejected;
        r.histogram = self.stats.histogram();
        r
    }

    fn outcome(&self) -> ChunkOutcome {
        ChunkOutcome {
            rejected: self.rejected.total() as u32,
            no_match: self.no_match as u32,
            out_of_tolerance: self.stats.out_of_tolerance() as u32,
        }
    }
}

/// Inspects one station's chunks against a design surface: borrowed (`&C2mIndex`) by a tool that
/// inspects one design, shared (`Arc<PrintedDesign>`) by the agent, whose stations see the design
/// cut at different printed heights.
pub struct StationInspector<I = std::sync::Arc<crate::printed::PrintedDesign>> {
    index: I,
    t_design_scanner: Isometry3<f64>,
    config: InspectParams,
    tally: Tally,
    /// A sorted block's points and deviations, made the first time a chunk comes unordered
    /// (at most [`SORT_BLOCK`] points each).
    sorted: Option<(Vec<ScanPoint>, Vec<PointDeviation>)>,
}

impl<I> StationInspector<I>
where
    I: std::ops::Deref,
    I::Target: Surface,
{
    /// An inspector for points in the scanner frame placed by `t_design_scanner`.
    pub fn new(index: I, t_design_scanner: Isometry3<f64>, config: InspectParams) -> Self {
        Self {
            index,
            t_design_scanner,
            config,
            tally: Tally::new(config.stats),
            sorted: None,
        }
    }

    /// Compares the chunks that follow with another design: the design as printed, once the
    /// station says how high the print is.
    pub fn set_index(&mut self, index: I) {
        self.index = index;
    }

    /// Sets the scanner pose for the chunks that follow (a station can open before its pose).
    pub fn set_pose(&mut self, t_design_scanner: Isometry3<f64>) {
        self.t_design_scanner = t_design_scanner;
    }

    /// Counts points that arrived but were not inspected, under the given reason.
    pub fn reject(&mut self, points: u64, reason: fn(&mut RejectCounts) -> &mut u64) {
        self.tally.points_received += points;
        *reason(&mut self.tally.rejected) += points;
    }

    /// Counts points that could not be used because their station has no pose.
    pub fn reject_without_pose(&mut self, points: u64) {
        self.tally.points_received += points;
        self.tally.rejected.without_pose += points;
    }

    /// Processes one chunk; `out[i]` receives the deviation of `points[i]`.
    pub fn process(&mut self, points: &[ScanPoint], out: &mut [PointDeviation]) -> ChunkOutcome {
        assert_eq!(points.len(), out.len(), "one deviation per scan point");
        let chunk = if points.len() >= SORT_MIN && !in_spatial_order(points) {
            self.process_sorted(points, out)
        } else {
            self.inspection().in_parallel(points, out)
        };
        let Some(chunk) = chunk else {
            return ChunkOutcome::default();
        };
        self.tally.merge(&chunk);
        chunk.outcome()
    }

    /// [`StationInspector::process`] for a chunk in no spatial order: block by block, along a
    /// Morton curve.
    fn process_sorted(
        &mut self,
        points: &[ScanPoint],
        out: &mut [PointDeviation],
    ) -> Option<Tally> {
        // The buffers are kept across chunks, taken out while the inspection borrows the rest.
        let (mut sorted_points, mut sorted_out) = self.sorted.take().unwrap_or_else(|| {
            (
                Vec::with_capacity(SORT_BLOCK),
                Vec::with_capacity(SORT_BLOCK),
            )
        });
        let inspection = self.inspection();
        let mut total: Option<Tally> = None;
        for (ps, os) in points.chunks(SORT_BLOCK).zip(out.chunks_mut(SORT_BLOCK)) {
            let order = morton_order(ps);
            order::gather(ps, &order, &mut sorted_points);
            sorted_out.clear();
            sorted_out.resize(ps.len(), PointDeviation::default());
            let block = inspection.in_parallel(&sorted_points, &mut sorted_out);
            order::put_back(&sorted_out, &order, os);
            if let Some(b) = block {
                match &mut total {
                    Some(t) => t.merge(&b),
                    None => total = Some(b),
                }
            }
        }
        self.sorted = Some((sorted_points, sorted_out));
        total
    }

    fn inspection(&self) -> Inspection<'_, I::Target> {
        Inspection {
            index: &*self.index,
            t_design_scanner: &self.t_design_scanner,
            config: &self.config,
        }
    }

    /// What the station has counted so far.
    pub fn tally(&self) -> &Tally {
        &self.tally
    }

    /// The station's report so far.
    pub fn report(&self, job: u64, station: u32, name: &str) -> StationReport {
        let mut r = self.tally.report(job, station, name);
        r.max_distance = self.index.max_distance();
        r
    }
}

/// What every point of a chunk is inspected with: the design, the station's pose, the settings.
struct Inspection<'a, S: ?Sized> {
    index: &'a S,
    t_design_scanner: &'a Isometry3<f64>,
    config: &'a InspectParams,
}

impl<S: Surface + ?Sized> Inspection<'_, S> {
    /// `out[i]` receives the deviation of `points[i]`; the chunk's tally, `None` for no points.
    fn in_parallel(&self, points: &[ScanPoint], out: &mut [PointDeviation]) -> Option<Tally> {
        points
            .par_chunks(TASK_POINTS)
            .zip(out.par_chunks_mut(TASK_POINTS))
            .map(|(ps, os)| self.task(ps, os))
            .reduce_with(|mut a, b| {
                a.merge(&b);
                a
            })
    }

    /// One task's share of a chunk, on one thread.
    fn task(&self, points: &[ScanPoint], out: &mut [PointDeviation]) -> Tally {
        let (index, t, config) = (self.index, self.t_design_scanner, self.config);
        let mut tally = Tally::new(config.stats);
        tally.points_received = points.len() as u64;
        let mut cursor = Cursor::default();
        let tol = config.stats.tolerance;
        for (sp, o) in points.iter().zip(out) {
            let [x, y, z] = sp.xyz;
            let reject = if !(x.is_finite() && y.is_finite() && z.is_finite()) {
                Some(&mut tally.rejected.non_finite)
            } else if sp.flags.is_invalid() {
                Some(&mut tally.rejected.scanner_invalid)
            } else if (x as f64).abs().max((y as f64).abs()).max((z as f64).abs())
                > config.max_range
            {
                Some(&mut tally.rejected.out_of_range)
            } else {
                None
            };
            if let Some(counter) = reject {
                *counter += 1;
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
            *o = match index.closest(&p, &mut cursor) {
                None => {
                    tally.no_match += 1;
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
}

/// A scan point's position (scanner frame) for the order of a chunk; `None` when not finite.
fn scan_position(p: &ScanPoint) -> Option<[f64; 3]> {
    p.xyz
        .iter()
        .all(|v| v.is_finite())
        .then(|| p.xyz.map(f64::from))
}

fn in_spatial_order(points: &[ScanPoint]) -> bool {
    order::in_spatial_order(points, scan_position)
}

fn morton_order(points: &[ScanPoint]) -> Vec<u32> {
    order::morton_order(points, scan_position)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(n: usize) -> Vec<ScanPoint> {
        (0..n)
            .map(|i| {
                let a = i as f32 * 1e-3;
                ScanPoint::new(a.cos(), a.sin(), 0.01 * (i / 500) as f32)
            })
            .collect()
    }

    #[test]
    fn scan_order_is_told_from_a_shuffle() {
        let scan = line(50_000);
        assert!(in_spatial_order(&scan));
        let shuffled: Vec<ScanPoint> = (0..scan.len()).map(|i| scan[i * 7919 % 50_000]).collect();
        assert!(!in_spatial_order(&shuffled));
        // Nothing finite, or one spot: nothing to sort.
        assert!(in_spatial_order(&[ScanPoint::new(f32::NAN, 0.0, 0.0); 10]));
        assert!(in_spatial_order(&[ScanPoint::new(1.0, 2.0, 3.0); 10]));
    }

    #[test]
    fn the_morton_order_is_a_permutation_with_neighbours_together() {
        let mut points = line(20_000);
        points[7] = ScanPoint::new(f32::NAN, 0.0, 0.0);
        let order = morton_order(&points);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..20_000u32).collect::<Vec<_>>());
        // The point that is not finite comes first.
        assert_eq!(order[0], 7);
        let sorted: Vec<ScanPoint> = order[1..].iter().map(|&i| points[i as usize]).collect();
        let step = |ps: &[ScanPoint]| -> f64 {
            ps.windows(2)
                .map(|w| {
                    (0..3)
                        .map(|k| (w[0].xyz[k] as f64 - w[1].xyz[k] as f64).powi(2))
                        .sum::<f64>()
                        .sqrt()
                })
                .sum::<f64>()
                / ps.len() as f64
        };
        let shuffled: Vec<ScanPoint> = (0..20_000)
            .map(|i| i * 7919 % 20_000)
            .filter(|&i| i != 7)
            .map(|i| points[i])
            .collect();
        let (a, b) = (step(&sorted), step(&shuffled));
        assert!(a < 0.1 * b, "{a} vs {b}");
    }
}
