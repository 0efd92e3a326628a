//! One scan layer's deviation state: the design's samples, streaming M3C2 over them, coverage,
//! and the findings they give. The agent keeps one per printed height it scans; `asbuilt
//! inspect` keeps one for its job. Both feed it the same way (a station begins, its points come
//! chunk by chunk, it ends at its scanner's origin), so offline and live give the same findings
//! from the same code. Memory grows with the design and the spacing, never with the scan.

use nalgebra::{Point3, Vector3};

use crate::Surface;
use crate::coverage::{Coverage, CoverageError, CoverageParams, CoverageSummary, SampleClass};
use crate::findings::{self, FindingParams, Findings};
use crate::m3c2::streaming::{StreamingError, StreamingM3c2, StreamingParams, StreamingSummary};
use crate::sampling::DesignSamples;

/// The defaults every caller starts from, so the agent's `[findings]` and `inspect`'s flags
/// mean the same when left out.
pub mod defaults {
    /// Spacing of the design samples (the M3C2 core points), metres.
    pub const SPACING: f64 = 0.01;
    /// Seed of the design samples: the same design gives the same samples.
    pub const SAMPLE_SEED: u64 = 1;
    /// M3C2 cylinders with fewer points give a distance but never a significant change.
    pub const MIN_POINTS: u32 = 5;
    /// Steeper views than this do not call a surface missing, degrees.
    pub const MAX_INCIDENCE_DEG: f64 = 65.0;
    /// Regions and missing areas of fewer samples are noise.
    pub const MIN_REGION_SAMPLES: usize = 5;
    /// Missing areas smaller than this are left out, m² (a ledge that sticks out shadows a strip
    /// below it).
    pub const MIN_MISSING_AREA_M2: f64 = 0.001;
    /// The coverage threshold's floor, metres: about three times the robot's position σ.
    pub const COVERAGE_THRESHOLD_FLOOR: f64 = 0.003;

    /// M3C2 cylinder diameter: twice the spacing, at most half a layer height (so a layer's
    /// cylinders do not reach into the next).
    pub fn projection_diameter(spacing: f64, layer_height: Option<f64>) -> f64 {
        let d = 2.0 * spacing;
        layer_height.map_or(d, |h| d.min(0.5 * h))
    }

    /// A design sample with a scan point this close is observed: max(3 mm, tolerance / 2).
    pub fn coverage_threshold(tolerance: f64) -> f64 {
        (0.5 * tolerance).max(COVERAGE_THRESHOLD_FLOOR)
    }

    /// How far coverage looks for a sample's nearest scan point: as far as M3C2 measures
    /// (`max_depth`), and never short of the threshold. A surface that stands off by more
    /// than the reach is neither observed nor buried to coverage, so the findings, which count
    /// only what coverage says a station saw, would drop exactly the samples of the largest
    /// deviations (a top 14 mm too high, a side 6 mm too wide).
    pub fn coverage_reach(threshold: f64, max_depth: f64) -> f64 {
        max_depth.max(threshold)
    }
}

/// What a scan layer measures. Either method may be left out; findings need both.
#[derive(Debug, Clone)]
pub struct ScanLayerParams {
    /// M3C2 at the design samples, when it runs.
    pub m3c2: Option<StreamingParams>,
    /// Coverage of the design samples, when it runs.
    pub coverage: Option<CoverageParams>,
    /// How the findings are drawn; `printed_height` is this layer's.
    pub findings: FindingParams,
}

/// A scan layer that cannot be set up.
#[derive(Debug, thiserror::Error)]
pub enum ScanLayerError {
    /// M3C2's parameters cannot be used.
    #[error("M3C2: {0}")]
    M3c2(#[from] StreamingError),
    /// Coverage's parameters cannot be used.
    #[error("coverage: {0}")]
    Coverage(#[from] CoverageError),
}

/// One design sample as the findings saw it: what a map of the scan layer draws.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleState {
    /// The sample, design frame.
    pub position: Point3<f64>,
    /// Outward.
    pub normal: Vector3<f64>,
    /// M3C2 distance along the normal, metres; `None` with no point in the cylinder.
    pub m3c2: Option<f64>,
    /// Whether the M3C2 distance exceeds its level of detection.
    pub significant: bool,
    /// What coverage made of it.
    pub class: SampleClass,
    /// What the findings made of it: a map paints its deviation or missing material only
    /// where they judged it so.
    pub judged: crate::findings::Judged,
}

/// What one station added, per method that runs.
#[derive(Debug, Clone)]
pub struct StationPart {
    /// Coverage over the station, when it runs.
    pub coverage: Option<CoverageSummary>,
    /// M3C2 over the station, when it runs.
    pub m3c2: Option<StreamingSummary>,
}

/// What a scan layer has gathered over its closed stations, to go on from after a restart:
/// its size is the design samples', whatever the points scanned.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct ScanLayerState {
    /// The design samples it is over (a check that it fits).
    pub samples: usize,
    /// Stations closed.
    pub stations: u32,
    /// M3C2's cylinders over them, by core point.
    pub m3c2: Option<Vec<crate::m3c2::Running>>,
    /// Coverage over them.
    pub coverage: Option<crate::coverage::CoverageState>,
}

/// Points a station's chunks are gathered into before M3C2 and coverage take them, in the
/// agent.
///
/// Each batch costs every probe it reaches a search of its box, however few of the batch's
/// points lie there; a scanner's chunk sweeps across the whole part, so small chunks
/// reach nearly every probe with a few points each. With batches of this size `inspect
/// --method m3c2` on the bunny job took 2.5–2.7 s, against 2.7–3.3 s fed the reader's chunks of
/// 65,536 points, for a fixed 3 MB and the probes' scratch that follows the batch.
pub const BATCH_POINTS: usize = 1 << 17;

/// Batches for a job run offline (`inspect`, the Python package), where memory is the
/// workstation's: [`ScanLayer::with_batch`].
///
/// On the bunny job (`inspect --method m3c2`, 2 M points) batches of [`BATCH_POINTS`] still
/// reached each core point 15 times; this size took 1.8–2.1 s of CPU against 2.1–2.4 s
/// (`perf stat`, alternated), and 1,048,576 only 5 % less again. The agent keeps the smaller
/// batch: on the demo's recording this size gained `report` nothing and held 95 MB more (M3C2's
/// and coverage's scratch follow the batch), and the findings bench's rate was the same.
pub const OFFLINE_BATCH_POINTS: usize = 1 << 19;

/// A scan layer's state over its design samples: M3C2 and coverage fed with each station's
/// points, and the findings drawn from them. Memory proportional to the samples, plus a fixed
/// batch of points ([`BATCH_POINTS`]).
pub struct ScanLayer {
    m3c2: Option<StreamingM3c2>,
    coverage: Option<Coverage>,
    /// Where M3C2 cylinders would average two faces.
    sharp_edges: Vec<[Point3<f64>; 2]>,
    area_per_sample: f64,
    samples: usize,
    findings: FindingParams,
    stations: u32,
    /// The station's points not yet taken: batches end by count alone, so the same stream of
    /// chunks gives the same batches (and the same bits) however it was cut.
    pending: Vec<Point3<f64>>,
    /// Points a batch holds.
    batch: usize,
}

impl ScanLayer {
    /// The state over `samples` of the design as printed at this layer, whose sharp edges are
    /// `sharp_edges`.
    pub fn new(
        samples: &DesignSamples,
        sharp_edges: Vec<[Point3<f64>; 2]>,
        params: ScanLayerParams,
    ) -> Result<Self, ScanLayerError> {
        let m3c2 = params
            .m3c2
            .map(|p| StreamingM3c2::new(samples, p))
            .transpose()?;
        let coverage = params
            .coverage
            .map(|p| Coverage::new(samples, p))
            .transpose()?;
        Ok(Self {
            m3c2,
            coverage,
            sharp_edges,
            area_per_sample: samples.area_per_sample,
            samples: samples.len(),
            findings: params.findings,
            stations: 0,
            pending: Vec::new(),
            batch: BATCH_POINTS,
        })
    }

    /// Batches of `points` (at least one) instead of [`BATCH_POINTS`]: the bits follow the
    /// batch, so the agent and whoever recomputes its findings keep the default.
    pub fn with_batch(mut self, points: usize) -> Self {
        self.batch = points.max(1);
        self
    }

    /// Design samples the layer measures at.
    pub fn samples(&self) -> usize {
        self.samples
    }

    /// What the closed stations gathered (a station under way is not in it).
    pub fn state(&self) -> ScanLayerState {
        ScanLayerState {
            samples: self.samples,
            stations: self.stations,
            m3c2: self.m3c2.as_ref().map(|m| m.total_state()),
            coverage: self.coverage.as_ref().map(|c| c.state()),
        }
    }

    /// Goes on from `s`, the [`Self::state`] of a scan layer over the same samples with the
    /// same methods; false, with nothing changed, when it does not fit.
    pub fn restore(&mut self, s: &ScanLayerState) -> bool {
        let fits = s.samples == self.samples
            && s.m3c2.is_some() == self.m3c2.is_some()
            && s.coverage.is_some() == self.coverage.is_some()
            && s.m3c2
                .as_ref()
                .zip(self.m3c2.as_ref())
                .is_none_or(|(a, m)| a.len() == m.len())
            && s.coverage
                .as_ref()
                .zip(self.coverage.as_ref())
                .is_none_or(|(a, c)| a.nearest.len() == c.state_len());
        if !fits {
            return false;
        }
        if let (Some(m), Some(t)) = (self.m3c2.as_mut(), s.m3c2.as_ref()) {
            m.restore(t);
        }
        if let (Some(c), Some(t)) = (self.coverage.as_mut(), s.coverage.as_ref()) {
            c.restore(t);
        }
        self.stations = s.stations;
        true
    }

    /// The design surface one sample stands for, m².
    pub fn area_per_sample(&self) -> f64 {
        self.area_per_sample
    }

    /// Stations ended so far.
    pub fn stations(&self) -> u32 {
        self.stations
    }

    /// The M3C2 state, when it runs.
    pub fn m3c2(&self) -> Option<&StreamingM3c2> {
        self.m3c2.as_ref()
    }

    /// The coverage state, when it runs.
    pub fn coverage(&self) -> Option<&Coverage> {
        self.coverage.as_ref()
    }

    /// Memory held, bytes.
    pub fn bytes(&self) -> usize {
        self.m3c2.as_ref().map_or(0, |m| m.bytes())
            + self.coverage.as_ref().map_or(0, |c| c.bytes())
            + self.sharp_edges.len() * size_of::<[Point3<f64>; 2]>()
            + self.pending.capacity() * size_of::<Point3<f64>>()
    }

    /// Starts a station: its per-station state begins empty.
    pub fn begin_station(&mut self) {
        // A station left without its end takes none of its points along.
        self.pending.clear();
        if let Some(m) = &mut self.m3c2 {
            m.begin_station();
        }
        if let Some(c) = &mut self.coverage {
            c.begin_station();
        }
    }

    /// A chunk's design-frame points (valid and finite), taken a batch at a time
    /// ([`BATCH_POINTS`] unless [`Self::with_batch`]); [`Self::end_station`] takes the rest.
    pub fn ingest(&mut self, points: &[Point3<f64>]) {
        if self.m3c2.is_none() && self.coverage.is_none() {
            return;
        }
        let mut rest = points;
        while !rest.is_empty() {
            let room = self.batch - self.pending.len();
            let (now, later) = rest.split_at(room.min(rest.len()));
            // Grown by doubling as a Vec grows, but never past the batch.
            let want = self.pending.len() + now.len();
            if want > self.pending.capacity() {
                let to = want.next_power_of_two().min(self.batch);
                self.pending.reserve_exact(to - self.pending.len());
            }
            self.pending.extend_from_slice(now);
            rest = later;
            if self.pending.len() == self.batch {
                self.take_pending();
            }
        }
    }

    fn take_pending(&mut self) {
        // Side by side: each lays the batch out for its own grid on one thread before its
        // probes share out, and the two states are apart, so the bits are the same either way.
        let pending = &self.pending;
        rayon::join(
            || {
                if let Some(m) = &mut self.m3c2 {
                    m.ingest(pending);
                }
            },
            || {
                if let Some(c) = &mut self.coverage {
                    c.ingest(pending);
                }
            },
        );
        self.pending.clear();
    }

    /// A line profiler's next profile of the station, taken from `sensor` (`T_design_sensor`)
    /// with the field of view `params`, against `surface`: what its plane swept should have
    /// been seen ([`Coverage::sweep`]).
    pub fn sweep(
        &mut self,
        sensor: &nalgebra::Isometry3<f64>,
        params: crate::profiler::SweepParams,
        surface: &dyn Surface,
    ) {
        if let Some(c) = self.coverage.as_mut() {
            c.sweep(sensor, params, surface);
        }
    }

    /// Closes a station that saw the design from `view` with position σ `sigma` against
    /// `surface` (the design as printed at this layer).
    pub fn end_station(
        &mut self,
        view: crate::coverage::Viewpoint,
        sigma: f64,
        surface: &dyn Surface,
    ) -> StationPart {
        self.take_pending();
        self.stations += 1;
        StationPart {
            coverage: self.coverage.as_mut().map(|c| c.end_station(view, surface)),
            m3c2: self.m3c2.as_mut().map(|m| m.end_station(sigma)),
        }
    }

    /// The findings of every station so far, with M3C2's significance at position σ `sigma`.
    /// `None` unless both M3C2 and coverage run.
    pub fn findings(&self, sigma: f64, surface: &dyn Surface) -> Option<Findings> {
        self.measure(sigma, surface, false).map(|(f, _)| f)
    }

    /// The findings as [`ScanLayer::findings`] gives them and, with `samples`, every design
    /// sample's state in sample order (for maps).
    pub fn measure(
        &self,
        sigma: f64,
        surface: &dyn Surface,
        samples: bool,
    ) -> Option<(Findings, Vec<SampleState>)> {
        let (m3c2, coverage) = (self.m3c2.as_ref()?, self.coverage.as_ref()?);
        let results = m3c2.results(sigma);
        let outcomes = coverage.outcomes(surface);
        let f = findings::find(
            &results,
            &outcomes,
            &self.sharp_edges,
            self.area_per_sample,
            &self.findings,
            sigma,
        );
        let states = if samples {
            let mut states: Vec<SampleState> = outcomes
                .iter()
                .map(|o| SampleState {
                    position: o.position,
                    normal: o.normal,
                    m3c2: None,
                    significant: false,
                    class: o.class,
                    judged: Default::default(),
                })
                .collect();
            // Both were built from the same samples: their sample indices line them up.
            let mut at = vec![usize::MAX; self.samples];
            for (i, o) in outcomes.iter().enumerate() {
                if let Some(a) = at.get_mut(o.sample as usize) {
                    *a = i;
                }
            }
            for r in &results {
                if let Some(s) = at.get(r.sample as usize).and_then(|&i| states.get_mut(i)) {
                    s.m3c2 = r.distance;
                    s.significant = r.significant;
                }
            }
            for (sample, &j) in f.judged.iter().enumerate() {
                if let Some(s) = at.get(sample).and_then(|&i| states.get_mut(i)) {
                    s.judged = j;
                }
            }
            states
        } else {
            Vec::new()
        };
        Some((f, states))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::c2m::{C2mIndex, C2mParams};
    use crate::coverage::CoverageParams;
    use crate::design::shapes;
    use crate::test_points::{random_points, seeded};

    /// Batches end by count alone, so a station's points give the same state, bit for bit,
    /// however the scanner cut them into chunks; and the batch never outgrows its size.
    #[test]
    fn a_station_gives_the_same_bits_however_its_chunks_are_cut() {
        let d = shapes::cuboid(Point3::origin(), Point3::new(0.5, 0.2, 0.3));
        let index = C2mIndex::build(&d, C2mParams::default()).unwrap();
        let samples = DesignSamples::generate(&d, 0.01, 1).unwrap();
        let params = ScanLayerParams {
            m3c2: Some(StreamingParams {
                projection_diameter: 0.01,
                max_depth: 0.01,
                min_points: 3,
            }),
            coverage: Some(CoverageParams::with_threshold(0.003, 0.02)),
            findings: FindingParams {
                tolerance: 0.005,
                layer_height: Some(0.05),
                printed_height: 0.3,
                spacing: 0.01,
                radius: 0.005,
                min_region_samples: 3,
                coverage_threshold: 0.003,
                min_missing_area_m2: 0.0,
            },
        };
        // Points on and near the box's faces, two and a half batches and more per station.
        let mut rng = seeded(5);
        let scan: Vec<Point3<f64>> = random_points(&mut rng, BATCH_POINTS * 5 / 2 + 777, 0.0..1.0)
            .into_iter()
            .enumerate()
            .map(|(i, u)| {
                let noise = (u.z - 0.5) * 0.004;
                match i % 3 {
                    0 => Point3::new(u.x * 0.5, u.y * 0.2, 0.3 + noise),
                    1 => Point3::new(u.x * 0.5, -noise, u.y * 0.3),
                    _ => Point3::new(0.5 + noise, u.x * 0.2, u.y * 0.3),
                }
            })
            .collect();
        let origin = Point3::new(1.5, -1.0, 1.0);
        let run_with = |cut: usize, batch: usize| {
            let layer = ScanLayer::new(&samples, Vec::new(), params.clone()).unwrap();
            let mut layer = layer.with_batch(batch);
            for _ in 0..2 {
                layer.begin_station();
                for chunk in scan.chunks(cut) {
                    layer.ingest(chunk);
                    assert!(layer.pending.len() < batch);
                    assert!(layer.pending.capacity() <= batch);
                }
                let part =
                    layer.end_station(crate::coverage::Viewpoint::Origin(origin), 0.001, &index);
                assert!(layer.pending.is_empty());
                assert!(part.m3c2.is_some_and(|m| m.with_points > 0));
            }
            layer.state()
        };
        let run = |cut: usize| run_with(cut, BATCH_POINTS);
        let whole = run(scan.len());
        for cut in [16_384, BATCH_POINTS - 1, 1000] {
            // Not assert_eq: the states print as megabytes.
            assert!(run(cut) == whole, "chunks of {cut} give another state");
        }
        // Another batch, as offline jobs take: the same bits for every cut of the chunks.
        let batch = 70_000;
        let whole = run_with(scan.len(), batch);
        for cut in [16_384, batch - 1, 1000] {
            assert!(
                run_with(cut, batch) == whole,
                "chunks of {cut}, batches of {batch}"
            );
        }
    }
}
