//! Reverse C2C and coverage: what C2M cannot see.
//!
//! A missing part of the print leaves no scan point, so no point-to-design distance exists for
//! it. Turned around, every design sample keeps the distance to the nearest scan point seen so
//! far (updated chunk by chunk; the state is per sample, never per point), and the sign of that
//! point's offset along the sample's normal tells whether the as-built surface lies inside the
//! design there. At the end of a station each sample is classified:
//!
//! - **observed**: a scan point within the threshold, or the design surface is buried under
//!   material: a scan point outside it, within reach, on the sample's normal line (within the
//!   threshold of it). The nearest point alone cannot tell: beside an edge of a part printed
//!   too tall, the nearest point is on the wall next to the sample, not on the top above it;
//! - **missing**: no such point, and the sample faces a station in range at an acceptable
//!   incidence with a clear line of sight: the scanner should have seen material there;
//! - **occluded**: it faces a station in range but the design itself blocks the view;
//! - **not scanned**: no station could have seen it (out of range, facing away, grazing).
//!
//! A scan is a lattice of points, as sparse as the scanner's angular step times the range: on a
//! 5 mm lattice every spot of a complete surface lies up to 3.5 mm from its nearest point. So the
//! threshold a sample is held to is the larger of the fixed one and the spacing its stations
//! scan at there ([`ScanSpacing`]): a gap is missing only where the scan around it is denser.

use nalgebra::{Isometry3, Point3, Vector3};

use crate::c2m::Surface;
use crate::probes::{ProbeGrid, Region, Scratch};
use crate::profiler::{Sweep, SweepParams};
use crate::sampling::DesignSamples;

mod nearest;

use nearest::Nearest;

/// The parameters of coverage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoverageParams {
    /// Farthest a scan point may be from a sample and still count as its nearest, metres. It is
    /// the largest reverse distance reported, and the cost per point grows with its square.
    pub reach: f64,
    /// A sample with a scan point this close is observed, metres.
    pub threshold: f64,
    /// Farthest a station sees, metres.
    pub max_range: f64,
    /// Largest angle between a sample's normal and its line of sight that still returns points.
    pub max_incidence_deg: f64,
    /// How far apart a station's points are expected on the surface.
    pub spacing: ScanSpacing,
}

/// The expected distance between neighbouring scan points on the design surface, which raises a
/// sample's threshold where the scan is sparser than the fixed threshold.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ScanSpacing {
    /// The fixed threshold alone, whatever the scan's density (a threshold set by hand).
    Fixed,
    /// The scanner's angular step, radians: points lie `step × range` apart across the line
    /// of sight and `1 / cos(incidence)` times that along it; a gap up to
    /// `step × range / √cos(incidence)` is allowed, which covers the widest spot of such a
    /// lattice up to 74° of incidence.
    AngularStep(f64),
    /// The angular step measured per station from its own points: the median over the samples
    /// it faces and reached of (nearest point's distance across the surface × √cos / range),
    /// divided by that median's value on a square lattice of unit spacing (0.40). Gaps pull
    /// only the upper tail.
    Measured,
}

/// Median distance from a random spot to the nearest node of a unit square lattice.
const LATTICE_MEDIAN: f64 = 0.398;

/// Fewest samples a station must reach for its angular step to be measured.
const MIN_SAMPLES_FOR_STEP: usize = 32;

impl CoverageParams {
    /// A fixed `threshold`, raised to the measured scan spacing where that is larger.
    pub fn with_threshold(threshold: f64, reach: f64) -> Self {
        Self {
            reach,
            threshold,
            max_range: 60.0,
            max_incidence_deg: 80.0,
            spacing: ScanSpacing::Measured,
        }
    }

    fn validate(&self) -> Result<(), CoverageError> {
        let positive = |v: f64| v > 0.0 && v.is_finite();
        if !positive(self.reach) || !positive(self.threshold) || self.threshold > self.reach {
            return Err(CoverageError::Distances {
                threshold: self.threshold,
                reach: self.reach,
            });
        }
        if let ScanSpacing::AngularStep(step) = self.spacing
            && !(positive(step) && step < 0.1)
        {
            return Err(CoverageError::Step { step });
        }
        if !positive(self.max_range) || !(0.0..=90.0).contains(&self.max_incidence_deg) {
            return Err(CoverageError::Sight {
                max_range: self.max_range,
                max_incidence_deg: self.max_incidence_deg,
            });
        }
        Ok(())
    }
}

/// Coverage parameters that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum CoverageError {
    #[error(
        "coverage threshold ({threshold} m) and reach ({reach} m) must be positive, with the \
         threshold no larger than the reach"
    )]
    /// The threshold or the reach is not positive, or the threshold exceeds the reach.
    Distances {
        /// The threshold, metres.
        threshold: f64,
        /// The reach, metres.
        reach: f64,
    },
    #[error(
        "maximum range ({max_range} m) must be positive and the maximum incidence \
         ({max_incidence_deg}°) between 0 and 90"
    )]
    /// The range or the incidence is out of bounds.
    Sight {
        /// The maximum range, metres.
        max_range: f64,
        /// The maximum incidence, degrees.
        max_incidence_deg: f64,
    },
    /// The scanner's angular step is out of bounds.
    #[error("the scanner's angular step ({step} rad) must be positive and under 0.1 rad")]
    Step {
        /// The step, radians.
        step: f64,
    },
}

/// What a design sample's stations saw of it (see the module's classes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleClass {
    /// A scan point within the threshold, or material buried it.
    Observed,
    /// A station should have seen material there and saw none.
    Missing,
    /// A station faces it in range but the design blocks the view.
    Occluded,
    /// No station could have seen it.
    NotScanned,
}

/// What coverage has gathered over the closed stations: each sample's nearest point (squared
/// distance, offset along the normal, buried) and each station's origin and angular step.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct CoverageState {
    /// Per sample: the nearest point's squared distance, its offset along the normal, buried.
    pub nearest: Vec<(f64, f64, bool)>,
    /// Per closed station: its origin and angular step.
    pub stations: Vec<([f64; 3], Option<f64>)>,
    /// Per sample, whether a line profiler's pass swept it (empty: no pass did).
    pub swept: Vec<bool>,
}

/// Where a closing station saw the design from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Viewpoint {
    /// A scanner at one origin (design frame): it should have seen what faces it in range
    /// with a clear line of sight.
    Origin(Point3<f64>),
    /// A line profiler's pass: it should have seen what its laser's plane swept
    /// ([`Coverage::sweep`]).
    Swept,
}

/// Coverage over the stations closed so far, in design samples.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CoverageSummary {
    /// Samples observed.
    pub observed: u64,
    /// Samples missing.
    pub missing: u64,
    /// Samples occluded.
    pub occluded: u64,
    /// Samples no station could have seen.
    pub not_scanned: u64,
    /// The design surface the missing samples stand for, m².
    pub missing_area_m2: f64,
    /// Missing samples, as indices into [`Coverage::samples`].
    pub missing_samples: Vec<u32>,
    /// The angular step the thresholds were raised by, radians (the median over the stations
    /// classified with): given, measured, or `None` (fixed threshold, or too few samples
    /// reached to measure it).
    pub angular_step: Option<f64>,
}

/// One design sample's outcome.
#[derive(Debug, Clone, Copy)]
pub struct SampleOutcome {
    /// This sample's index in the samples coverage was built from.
    pub sample: u32,
    /// The sample's position, design frame.
    pub position: Point3<f64>,
    /// The design's outward unit normal there.
    pub normal: Vector3<f64>,
    /// Signed distance to the nearest scan point, metres: negative when that point lies inside
    /// the design. `None` when no scan point came within reach.
    pub reverse_distance: Option<f64>,
    /// Its class.
    pub class: SampleClass,
}

/// Coverage of a design's samples by a job's stations, in memory proportional to the samples:
/// each sample keeps its nearest scan point, per station and over all of them.
pub struct Coverage {
    grid: ProbeGrid,
    params: CoverageParams,
    area_per_sample: f64,
    station: Vec<Nearest>,
    total: Vec<Nearest>,
    scratch: Scratch,
    origins: Vec<Station>,
    /// What line profilers' passes swept, once one has run.
    sweep: Option<Sweep>,
}

/// A closed station: where it scanned from and its angular step, when known.
#[derive(Debug, Clone, Copy)]
struct Station {
    origin: Point3<f64>,
    step: Option<f64>,
}

impl Coverage {
    /// Coverage of `samples`, nothing seen yet.
    pub fn new(samples: &DesignSamples, params: CoverageParams) -> Result<Self, CoverageError> {
        params.validate()?;
        // Fine cells as wide as the threshold: the first box a sample searches on a scan
        // dense enough to observe it holds a point. At least a tenth of the reach, so that a
        // cell has at most 11³ fine cells and keeps its table.
        let fine = params.threshold.max(params.reach / 10.0);
        let region = Region::Narrowing {
            reach: params.reach,
            fine,
        };
        let grid = ProbeGrid::around(&samples.points, &samples.normals, region);
        let n = grid.len();
        Ok(Self {
            grid,
            params,
            area_per_sample: samples.area_per_sample,
            station: vec![Nearest::NONE; n],
            total: vec![Nearest::NONE; n],
            scratch: Scratch::default(),
            origins: Vec::new(),
            sweep: None,
        })
    }

    /// The parameters it was made with.
    pub fn params(&self) -> &CoverageParams {
        &self.params
    }

    /// Sample positions in the order every per-sample output uses.
    pub fn samples(&self) -> &[Point3<f64>] {
        self.grid.points()
    }

    /// The design surface one sample stands for, m².
    pub fn area_per_sample(&self) -> f64 {
        self.area_per_sample
    }

    /// Memory held for the whole job: per-sample state plus the largest chunk's scratch.
    pub fn bytes(&self) -> usize {
        self.grid.bytes()
            + (self.station.capacity() + self.total.capacity()) * size_of::<Nearest>()
            + self.scratch.bytes()
    }

    /// Starts a station: its own nearest points start empty; the job's are kept.
    pub fn begin_station(&mut self) {
        self.station.fill(Nearest::NONE);
    }

    /// Samples it keeps a state for.
    pub fn state_len(&self) -> usize {
        self.total.len()
    }

    /// What the closed stations gathered, for [`Self::restore`].
    pub fn state(&self) -> CoverageState {
        CoverageState {
            nearest: self
                .total
                .iter()
                .map(|n| (n.d2, n.along, n.buried))
                .collect(),
            stations: self
                .origins
                .iter()
                .map(|s| (s.origin.coords.into(), s.step))
                .collect(),
            swept: self
                .sweep
                .as_ref()
                .map_or(Vec::new(), |w| w.swept().to_vec()),
        }
    }

    /// Goes on from a [`Self::state`] of the same samples; false (and nothing changed) when it
    /// holds another number of samples.
    pub fn restore(&mut self, s: &CoverageState) -> bool {
        let n = self.total.len();
        if s.nearest.len() != n || !(s.swept.is_empty() || s.swept.len() == n) {
            return false;
        }
        self.sweep = (!s.swept.is_empty()).then(|| {
            let mut w = Sweep::new(
                self.grid.points(),
                self.grid.normals(),
                SweepParams::default(),
            );
            w.set_swept(&s.swept);
            w
        });
        for (t, &(d2, along, buried)) in self.total.iter_mut().zip(&s.nearest) {
            *t = Nearest { d2, along, buried };
        }
        self.origins = s
            .stations
            .iter()
            .map(|&(o, step)| Station {
                origin: Point3::from(o),
                step,
            })
            .collect();
        true
    }

    /// Takes a chunk of scan points already in the design frame.
    pub fn ingest(&mut self, points: &[Point3<f64>]) {
        let (reach, t) = (self.params.reach, self.params.threshold);
        let (reach2, t2) = (reach * reach, t * t);
        // Far above rounding, far below any scan's spacing.
        let pad = reach * 1e-9;
        // The points that can still change a sample: those no farther than its nearest so far
        // (a tie may be kept for its offset), and, until it is buried, those on its normal line
        // (along axis k a line within t of the normal reaches reach·|n_k| + t·√(1 − n_k²)).
        // Nearest and buried are a minimum and an or, so a point offered twice changes nothing.
        let bound = |n: &Vector3<f64>, st: &Nearest| {
            let ball = Vector3::repeat(st.d2.sqrt().min(reach) + pad);
            if st.buried {
                return ball;
            }
            let line = n.map(|c| (reach * c.abs() + t * (1.0 - c * c).max(0.0).sqrt()).min(reach));
            ball.sup(&line.add_scalar(pad))
        };
        self.grid.offer_narrowing(
            &mut self.scratch,
            &mut self.station,
            points,
            bound,
            |p, n, qs, st| st.take(p, n, qs, reach2, t2),
        );
    }

    /// A line profiler's next profile, taken from `sensor` (`T_design_sensor`) with the field
    /// of view `params`: the samples its plane swept since the pass's previous profile count as seen by the pass.
    pub fn sweep(&mut self, sensor: &Isometry3<f64>, params: SweepParams, design: &dyn Surface) {
        let (points, normals) = (self.grid.points(), self.grid.normals());
        let w = self
            .sweep
            .get_or_insert_with(|| Sweep::new(points, normals, params));
        // A restored sweep kept its flags, not its field of view.
        w.set_params(params);
        w.profile(sensor, design);
    }

    /// Closes the station that saw the design from `view`: classifies every sample by this
    /// station alone (and what earlier passes swept), then adds what it saw to the job.
    pub fn end_station(&mut self, view: Viewpoint, design: &dyn Surface) -> CoverageSummary {
        let station = match view {
            Viewpoint::Origin(origin) => Some(Station {
                origin,
                step: self.angular_step(origin),
            }),
            Viewpoint::Swept => {
                if let Some(w) = self.sweep.as_mut() {
                    w.end_pass();
                }
                None
            }
        };
        let summary = self.classify(&self.station, station.as_slice(), design);
        for (t, s) in self.total.iter_mut().zip(&self.station) {
            t.merge(s);
        }
        self.origins.extend(station);
        summary
    }

    /// The angular step of the station just scanned from `origin`, as [`ScanSpacing`] says.
    fn angular_step(&self, origin: Point3<f64>) -> Option<f64> {
        match self.params.spacing {
            ScanSpacing::Fixed => None,
            ScanSpacing::AngularStep(step) => Some(step),
            ScanSpacing::Measured => {
                // Over the samples that face the station and have a point within reach: those
                // around a face's rim reach over to a neighbouring face's points.
                let cos_max = self.params.max_incidence_deg.to_radians().cos();
                let mut q: Vec<f64> = (0..self.station.len())
                    .filter_map(|i| {
                        let n = &self.station[i];
                        let v = origin - self.grid.points()[i];
                        let range = v.norm();
                        let cos = v.dot(&self.grid.normals()[i]) / range.max(1e-3);
                        let faces = range > 1e-3 && cos >= cos_max;
                        (n.d2.is_finite() && faces).then(|| n.lateral() * cos.sqrt() / range)
                    })
                    .collect();
                if q.len() < MIN_SAMPLES_FOR_STEP {
                    return None;
                }
                let mid = q.len() / 2;
                let (_, median, _) = q.select_nth_unstable_by(mid, f64::total_cmp);
                Some(*median / LATTICE_MEDIAN)
            }
        }
    }

    /// The job so far: every sample against every station closed so far.
    pub fn total(&self, design: &dyn Surface) -> CoverageSummary {
        self.classify(&self.total, &self.origins, design)
    }

    /// Every sample's reverse distance and class over the job so far.
    pub fn outcomes(&self, design: &dyn Surface) -> Vec<SampleOutcome> {
        use rayon::prelude::*;
        let g = &self.grid;
        (0..g.len())
            .into_par_iter()
            .map(|i| {
                let s = &self.total[i];
                SampleOutcome {
                    sample: g.ids()[i],
                    position: g.points()[i],
                    normal: g.normals()[i],
                    reverse_distance: s.d2.is_finite().then(|| signed(s)),
                    class: self.class_of(i, s, &self.origins, design),
                }
            })
            .collect()
    }

    /// The summary of outcomes already classified, without casting their rays again.
    pub fn summary_of(&self, outcomes: &[SampleOutcome]) -> CoverageSummary {
        let mut summary = self.summarize(outcomes.iter().map(|o| o.class));
        summary.angular_step = median_step(&self.origins);
        summary
    }

    fn classify(
        &self,
        state: &[Nearest],
        origins: &[Station],
        design: &dyn Surface,
    ) -> CoverageSummary {
        use rayon::prelude::*;
        let classes: Vec<SampleClass> = (0..state.len())
            .into_par_iter()
            .map(|i| self.class_of(i, &state[i], origins, design))
            .collect();
        let mut summary = self.summarize(classes.into_iter());
        summary.angular_step = median_step(origins);
        summary
    }

    fn summarize(&self, classes: impl Iterator<Item = SampleClass>) -> CoverageSummary {
        let mut s = CoverageSummary::default();
        for (i, c) in classes.enumerate() {
            match c {
                SampleClass::Observed => s.observed += 1,
                SampleClass::Missing => {
                    s.missing += 1;
                    s.missing_samples.push(i as u32);
                }
                SampleClass::Occluded => s.occluded += 1,
                SampleClass::NotScanned => s.not_scanned += 1,
            }
        }
        s.missing_area_m2 = s.missing as f64 * self.area_per_sample;
        s
    }

    fn class_of(
        &self,
        i: usize,
        nearest: &Nearest,
        origins: &[Station],
        design: &dyn Surface,
    ) -> SampleClass {
        let t = self.params.threshold;
        if nearest.d2 <= t * t || nearest.buried {
            return SampleClass::Observed;
        }
        let p = self.grid.points()[i];
        let n = self.grid.normals()[i];
        let cos_max = self.params.max_incidence_deg.to_radians().cos();
        // A station that faces the sample leaves gaps up to its own spacing there.
        let spacing = |o: &Station| -> Option<f64> {
            let v = o.origin - p;
            let range = v.norm();
            let cos = v.dot(&n) / range;
            (range > 0.0 && range <= self.params.max_range && cos >= cos_max)
                .then(|| o.step.map_or(0.0, |s| s * range / cos.sqrt()))
        };
        // Across the surface the gap may be as wide as the spacing; along the normal the
        // threshold stays: material short of the design is missing however sparse the scan.
        let widest = origins.iter().filter_map(spacing).fold(0.0, f64::max);
        let across = t.max(widest).min(self.params.reach);
        if (nearest.along / t).powi(2) + (nearest.lateral() / across).powi(2) <= 1.0 {
            return SampleClass::Observed;
        }
        // A profiler's plane swept it with the design clear between: it should be there.
        if self.sweep.as_ref().is_some_and(|w| w.swept()[i]) {
            return SampleClass::Missing;
        }
        // Lines of sight start just off the surface, so the sample's own face never blocks.
        let margin = (0.25 * t).min(1e-3);
        let mut facing = false;
        for o in origins.iter().filter(|o| spacing(o).is_some()) {
            facing = true;
            if !design.blocks_sight(&o.origin, &(p + n * margin), margin) {
                return SampleClass::Missing;
            }
        }
        if facing {
            SampleClass::Occluded
        } else {
            SampleClass::NotScanned
        }
    }
}

/// The median angular step of the stations that have one.
fn median_step(origins: &[Station]) -> Option<f64> {
    let mut steps: Vec<f64> = origins.iter().filter_map(|o| o.step).collect();
    steps.sort_by(f64::total_cmp);
    steps.get(steps.len() / 2).copied()
}

fn signed(n: &Nearest) -> f64 {
    let d = n.d2.sqrt();
    if n.along < 0.0 { -d } else { d }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::c2m::{C2mIndex, C2mParams};
    use crate::design::shapes;

    fn plane_points(z: f64, x: (f64, f64), y: (f64, f64), step: f64) -> Vec<Point3<f64>> {
        let mut v = Vec::new();
        let mut xi = x.0;
        while xi <= x.1 {
            let mut yi = y.0;
            while yi <= y.1 {
                v.push(Point3::new(xi, yi, z));
                yi += step;
            }
            xi += step;
        }
        v
    }

    /// A 1 m box scanned from above: only its top is within reach of the scan. The top is
    /// observed where points are; a hole in the scan is missing with its area; the sides face
    /// away from a station straight overhead at grazing angles (not scanned), the bottom faces
    /// away.
    #[test]
    fn a_hole_in_the_top_of_a_box_is_missing_with_its_area() {
        let d = shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 1.0, 1.0));
        let index = C2mIndex::build(&d, C2mParams::default()).unwrap();
        let samples = DesignSamples::generate(&d, 0.01, 1).unwrap();
        let params = CoverageParams::with_threshold(0.005, 0.05);
        let mut cov = Coverage::new(&samples, params).unwrap();
        let hole = |p: &Point3<f64>| (0.3..0.5).contains(&p.x) && (0.3..0.6).contains(&p.y);
        let scan: Vec<_> = plane_points(1.001, (0.0, 1.0), (0.0, 1.0), 0.002)
            .into_iter()
            .filter(|p| !hole(p))
            .collect();
        cov.begin_station();
        cov.ingest(&scan[..10_000]);
        let held = cov.bytes();
        for c in scan.chunks(10_000) {
            cov.ingest(c);
        }
        // Per-sample state and one chunk's scratch: nothing grows with the scan.
        assert_eq!(cov.bytes(), held);
        let s = cov.end_station(Viewpoint::Origin(Point3::new(0.5, 0.5, 3.0)), &index);
        // The hole's centre part (more than 5 mm from any scan point) is 0.19 × 0.29 m.
        let truth = (0.2 - 0.01) * (0.3 - 0.01);
        assert!(
            (s.missing_area_m2 - truth).abs() < 0.1 * truth,
            "{} vs {truth}",
            s.missing_area_m2
        );
        for &i in &s.missing_samples {
            let p = cov.samples()[i as usize];
            assert!((p.z - 1.0).abs() < 1e-9 && hole(&p), "{p}");
        }
        // Sides see the station at 71° to 90° from their normal, the bottom faces away.
        assert_eq!(s.occluded, 0);
        let top_area = 1.0;
        let observed_area = s.observed as f64 * cov.area_per_sample();
        assert!(
            (observed_area - (top_area - truth)).abs() < 0.05,
            "{observed_area}"
        );
        let total = cov.total(&index);
        assert_eq!(total, s);
    }

    /// A line profiler passes 0.1 m over the middle of a box's top along x, looking down, its
    /// 60° fan 0.115 m wide there; material is missing under its path from x 0.4 to 0.6.
    /// What it swept with no point near is missing, what it never swept is not judged, and a
    /// resumed coverage keeps what was swept.
    #[test]
    fn a_profiler_pass_misses_what_it_swept_and_never_judges_what_it_did_not() {
        let d = shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 1.0, 1.0));
        let index = C2mIndex::build(&d, C2mParams::default()).unwrap();
        let samples = DesignSamples::generate(&d, 0.01, 1).unwrap();
        let params = CoverageParams::with_threshold(0.005, 0.05);
        let mut cov = Coverage::new(&samples, params).unwrap();
        let hole = |p: &Point3<f64>| (0.4..0.6).contains(&p.x);
        let scan: Vec<_> = plane_points(1.0, (0.0, 1.0), (0.4, 0.6), 0.002)
            .into_iter()
            .filter(|p| !hole(p))
            .collect();
        cov.begin_station();
        cov.ingest(&scan);
        // Sensor z (the view) down, x (the line) along world y, y (the plane's normal) along x.
        let look = nalgebra::UnitQuaternion::from_rotation_matrix(
            &nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
                0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0,
            )),
        );
        let sweep = crate::profiler::SweepParams::default();
        for k in 0..=1000 {
            let at = Isometry3::from_parts(
                nalgebra::Translation3::new(0.001 * k as f64, 0.5, 1.1),
                look,
            );
            cov.sweep(&at, sweep, &index);
        }
        let s = cov.end_station(Viewpoint::Swept, &index);
        let half_fan = 0.1 * 30f64.to_radians().tan();
        for &i in &s.missing_samples {
            let p = cov.samples()[i as usize];
            assert!((p.z - 1.0).abs() < 1e-9 && hole(&p), "{p}");
            assert!((p.y - 0.5).abs() <= half_fan + 0.01, "{p}");
        }
        // The fan's width under the hole, less the threshold's rim: 0.19 × 0.10 m.
        let truth = 0.19 * (2.0 * half_fan - 0.01);
        assert!(
            (s.missing_area_m2 - truth).abs() < 0.15 * truth,
            "{} vs {truth}",
            s.missing_area_m2
        );
        // Off the fan and without points (the rest of the top, the sides, the bottom, the
        // hole beside the fan): never judged. Observed: the scanned strip less the hole.
        let area = |n: u64| n as f64 * cov.area_per_sample();
        let observed = 0.2 - 0.2 * 0.2;
        let not_judged = 6.0 - observed - truth;
        assert!(
            (area(s.not_scanned) - not_judged).abs() < 0.03,
            "{}",
            area(s.not_scanned)
        );
        assert_eq!(s.occluded, 0);
        // Taken up again, it classifies the same.
        let state = cov.state();
        assert!(state.swept.iter().any(|&w| w));
        let mut again = Coverage::new(&samples, params).unwrap();
        assert!(again.restore(&state));
        assert_eq!(again.total(&index), cov.total(&index));
    }

    #[test]
    fn material_short_of_the_design_is_missing_and_material_beyond_it_is_not() {
        // Scan of the top face 8 mm too low (material missing) on one half and 8 mm too high
        // (excess) on the other.
        let d = shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 1.0, 1.0));
        let index = C2mIndex::build(&d, C2mParams::default()).unwrap();
        let samples = DesignSamples::generate(&d, 0.02, 1).unwrap();
        let mut cov = Coverage::new(&samples, CoverageParams::with_threshold(0.005, 0.05)).unwrap();
        let mut scan = plane_points(0.992, (0.0, 0.5), (0.0, 1.0), 0.004);
        scan.extend(plane_points(1.008, (0.504, 1.0), (0.0, 1.0), 0.004));
        cov.begin_station();
        cov.ingest(&scan);
        cov.end_station(Viewpoint::Origin(Point3::new(0.5, 0.5, 2.0)), &index);
        for o in cov.outcomes(&index) {
            if (o.position.z - 1.0).abs() > 1e-9 || (o.position.x - 0.5).abs() < 0.03 {
                continue;
            }
            let d = o.reverse_distance.expect("within reach");
            if o.position.x < 0.5 {
                assert!((d + 0.008).abs() < 1e-3, "{d}");
                assert_eq!(o.class, SampleClass::Missing);
            } else {
                assert!((d - 0.008).abs() < 1e-3, "{d}");
                assert_eq!(o.class, SampleClass::Observed);
            }
        }
    }

    /// The front of a 1000 × 200 × 500 mm box, 2 m from the station, scanned on a regular
    /// lattice with a 100 × 100 mm hole: the hole is missing, within 30 %, at 2, 5 and 10 mm
    /// spacing, though most of a sparse lattice lies beyond the fixed 3 mm threshold; the
    /// angular step is measured within 10 %.
    #[test]
    fn a_sparse_but_complete_scan_is_not_missing_only_its_hole_is() {
        let d = shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.2, 0.5));
        let index = C2mIndex::build(&d, C2mParams::default()).unwrap();
        let samples = DesignSamples::generate(&d, 0.01, 1).unwrap();
        let station = Point3::new(0.5, -2.0, 0.25);
        let hole = |x: f64, z: f64| (0.45..0.55).contains(&x) && (0.2..0.3).contains(&z);
        let truth = 0.1 * 0.1;
        for spacing in [0.002, 0.005, 0.010] {
            // A lattice that does not line up with the hole's edges, and reaches the face's
            // edges as a scan of the whole face does.
            let line = |from: f64, to: f64| {
                let mut v: Vec<f64> = (0..)
                    .map(|k| from + k as f64 * spacing)
                    .take_while(|&c| c < to)
                    .collect();
                v.push(to);
                v
            };
            let mut scan = Vec::new();
            for &x in &line(0.0013, 1.0) {
                for &z in &line(0.0007, 0.5) {
                    if !hole(x, z) {
                        scan.push(Point3::new(x, 0.0, z));
                    }
                }
            }
            for (params, adaptive) in [
                (CoverageParams::with_threshold(0.003, 0.05), true),
                (
                    CoverageParams {
                        spacing: ScanSpacing::AngularStep(spacing / 2.0),
                        ..CoverageParams::with_threshold(0.003, 0.05)
                    },
                    true,
                ),
                (
                    CoverageParams {
                        spacing: ScanSpacing::Fixed,
                        ..CoverageParams::with_threshold(0.003, 0.05)
                    },
                    false,
                ),
            ] {
                let mut cov = Coverage::new(&samples, params).unwrap();
                cov.begin_station();
                cov.ingest(&scan);
                let s = cov.end_station(Viewpoint::Origin(station), &index);
                let what = format!("{} mm lattice, {:?}", spacing * 1e3, params.spacing);
                eprintln!(
                    "{what}: {:.4} m² missing (truth {truth}), step {:?}",
                    s.missing_area_m2, s.angular_step
                );
                for &i in &s.missing_samples {
                    let p = cov.samples()[i as usize];
                    if adaptive {
                        assert!(hole(p.x, p.z) && p.y.abs() < 1e-9, "{what}: {p} missing");
                    }
                }
                if adaptive {
                    assert!(
                        (s.missing_area_m2 - truth).abs() <= 0.3 * truth,
                        "{what}: {} m² missing, truth {truth}",
                        s.missing_area_m2
                    );
                    let step = s.angular_step.unwrap();
                    assert!(
                        (step - spacing / 2.0).abs() < 0.1 * spacing / 2.0,
                        "{what}: step {step}"
                    );
                } else if spacing > 0.003 {
                    // The fixed threshold calls the lattice's gaps missing all over the face.
                    assert!(
                        s.missing_area_m2 > 2.0 * truth,
                        "{what}: {}",
                        s.missing_area_m2
                    );
                }
            }
        }
    }

    #[test]
    fn a_face_hidden_behind_another_part_is_occluded() {
        // Two boxes side by side in x; the station looks along +x from the left, so the right
        // box's left face is hidden behind the left box.
        let d = shapes::merge(&[
            shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 1.0, 1.0)),
            shapes::cuboid(Point3::new(2.0, 0.0, 0.0), Point3::new(3.0, 1.0, 1.0)),
        ]);
        let index = C2mIndex::build(&d, C2mParams::default()).unwrap();
        let samples = DesignSamples::generate(&d, 0.05, 1).unwrap();
        let mut cov = Coverage::new(&samples, CoverageParams::with_threshold(0.005, 0.05)).unwrap();
        cov.begin_station();
        let s = cov.end_station(Viewpoint::Origin(Point3::new(-3.0, 0.5, 0.5)), &index);
        for (i, p) in cov.samples().iter().enumerate() {
            let missing = s.missing_samples.contains(&(i as u32));
            if (p.x - 2.0).abs() < 1e-9 {
                assert!(!missing, "hidden face counted missing at {p}");
            }
            if p.x.abs() < 1e-9 {
                assert!(missing, "visible face not missing at {p}");
            }
        }
        let face = 1.0 / cov.area_per_sample();
        assert!(
            (s.occluded as f64 - face).abs() < 0.2 * face,
            "{}",
            s.occluded
        );
    }
}
