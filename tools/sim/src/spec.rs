//! A simulated job as a person describes it (`asbuilt sim`'s flags, the Python
//! `SimulatedJob`'s keywords), checked once into a [`SimJob`].

use std::path::PathBuf;

use asbuilt_core::Units;
use asbuilt_protocol::PoseMode;

use crate::profiler::ProfilerModel;
use crate::{Defect, DefectSpecError, Part, PartError, SimJob};

/// The part to print.
#[derive(Debug, Clone, PartialEq)]
pub enum PartSpec {
    /// The source study's 2 m shotcrete wall, in 20 mm layers.
    Wall,
    /// A twisted elliptical column, in 20 mm layers.
    Column,
    /// A closed design file (STL, OBJ, PLY) standing on z = 0, sliced in `layer_height` layers.
    File {
        /// The design file.
        path: PathBuf,
        /// Its units, declared: they are never guessed.
        units: Units,
        /// Layer height, metres.
        layer_height: f64,
    },
}

/// What to print and how to scan it; [`JobSpec::default`] is `asbuilt sim`'s default job.
#[derive(Debug, Clone, PartialEq)]
pub struct JobSpec {
    /// The part.
    pub part: PartSpec,
    /// Layer counts after which the robot scans.
    pub scan_after: Vec<u32>,
    /// Stations per scan layer.
    pub stations: u32,
    /// Defects, as `KIND[:key=value,...]` ([`Defect::parse`]).
    pub defects: Vec<String>,
    /// Seed of pose and scanner noise.
    pub seed: u64,
    /// Fixed orientation (the Z+F mounting) or six-DoF.
    pub pose_mode: PoseMode,
    /// Pose error σ, metres.
    pub pose_sigma: f64,
    /// Points per second the scanner sends; `None` for as fast as the agent takes them.
    pub rate: Option<f64>,
    /// Angle between rays, degrees.
    pub step_deg: f64,
    /// Job number.
    pub job: u64,
    /// Tries at a station before the cell gives up on it (see [`SimJob::max_attempts`]).
    pub attempts: u8,
    /// The printer applies the agent's advice (see [`SimJob::closed_loop`]).
    pub closed_loop: bool,
    /// The share of each advice it applies (see [`SimJob::apply`]).
    pub apply: f64,
    /// Scan while printing with a line profiler behind the nozzle, every layer a pass,
    /// instead of stopping for a terrestrial scanner's stations.
    pub profiler: Option<ProfilerSpec>,
}

/// A line profiler as a person describes it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProfilerSpec {
    /// Points per profile.
    pub points: usize,
    /// Profiles per second.
    pub rate_hz: f64,
    /// The robot's poses per second.
    pub pose_rate_hz: f64,
    /// The robot's clock less the profiler's, nanoseconds.
    pub clock_offset_ns: i64,
    /// The layers printed, each a pass (`None`: the whole part).
    pub layers: Option<u32>,
}

impl Default for ProfilerSpec {
    fn default() -> Self {
        let m = ProfilerModel::default();
        Self {
            points: m.points,
            rate_hz: m.rate_hz,
            pose_rate_hz: m.pose_rate_hz,
            clock_offset_ns: m.clock_offset_ns,
            layers: None,
        }
    }
}

impl Default for JobSpec {
    fn default() -> Self {
        Self {
            part: PartSpec::Wall,
            scan_after: vec![8, 16, 24, 32, 40, 48],
            stations: 4,
            defects: Vec::new(),
            seed: 1,
            pose_mode: PoseMode::FixedOrientation,
            pose_sigma: 0.001,
            rate: Some(1.0e6),
            step_deg: 0.036,
            job: 1,
            attempts: 5,
            closed_loop: false,
            apply: 1.0,
            profiler: None,
        }
    }
}

/// A job that cannot be simulated; each case names the setting and what it takes.
#[derive(Debug, thiserror::Error)]
pub enum JobSpecError {
    /// The design file cannot be read.
    #[error("the part's design")]
    Design(#[source] asbuilt_io::IoError),
    /// The part cannot be printed in layers.
    #[error("the part cannot be printed in layers")]
    Part(#[source] PartError),
    /// Scan layers outside the part's layers.
    #[error(
        "scan after {given:?}: give layer counts from 1 to {layers} (the {part} has {layers} \
         layers of {layer_mm} mm)"
    )]
    ScanAfter {
        /// The layer counts given.
        given: Vec<u32>,
        /// The part's name.
        part: String,
        /// Its layers.
        layers: u32,
        /// Its layer height, mm.
        layer_mm: f64,
    },
    /// No station per scan layer.
    #[error("stations must be at least 1")]
    NoStations,
    /// A defect that does not parse or does not fit the part.
    #[error(transparent)]
    Defect(#[from] DefectSpecError),
    /// A pose σ outside [0, 0.1) m.
    #[error("pose sigma {0}: give metres in [0, 0.1)")]
    PoseSigma(f64),
    /// An angular step outside [0.005, 2] degrees.
    #[error("step {0}°: give degrees in [0.005, 2]")]
    StepDeg(f64),
    /// No attempt at a station.
    #[error("attempts must be at least 1")]
    Attempts,
    /// A rate that is not a positive number of points per second.
    #[error("rate {0}: give points per second above 0")]
    Rate(f64),
    /// A profiler that cannot be simulated.
    #[error(
        "profiler: {0}; give 2 to 65,536 points a profile, 1 to 100,000 profiles a second, \
         1 to 10,000 poses a second and layers the part has"
    )]
    Profiler(String),
    /// A share of the advice outside 0 to 1.
    #[error("apply {0}: give the share of each advice the printer applies, from 0 to 1")]
    Apply(f64),
}

impl PartSpec {
    /// The part, sliced in its layers.
    pub fn part(&self) -> Result<Part, JobSpecError> {
        match self {
            PartSpec::Wall => Ok(Part::wall()),
            PartSpec::Column => Ok(Part::column()),
            PartSpec::File {
                path,
                units,
                layer_height,
            } => {
                let design = asbuilt_io::read_design(path, *units).map_err(JobSpecError::Design)?;
                let name = path
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "part".into());
                Part::from_design(&name, design, *layer_height).map_err(JobSpecError::Part)
            }
        }
    }
}

impl JobSpec {
    /// The job: part, defects, scan layers, stations, scanner, every value checked.
    pub fn build(&self) -> Result<SimJob, JobSpecError> {
        let mut job = SimJob::new(self.part.part()?);
        let layers = job.part.layers();
        if self.scan_after.is_empty() || self.scan_after.iter().any(|&k| k == 0 || k > layers) {
            return Err(JobSpecError::ScanAfter {
                given: self.scan_after.clone(),
                part: job.part.name.clone(),
                layers,
                layer_mm: job.part.layer_height * 1e3,
            });
        }
        job.scan_after = self.scan_after.clone();
        job.scan_after.sort_unstable();
        job.scan_after.dedup();
        if self.stations == 0 {
            return Err(JobSpecError::NoStations);
        }
        job.stations_per_scan = self.stations;
        if self.attempts == 0 {
            return Err(JobSpecError::Attempts);
        }
        job.max_attempts = self.attempts;
        job.defects = self
            .defects
            .iter()
            .map(|d| Defect::parse(d, &job.part))
            .collect::<Result<_, _>>()?;
        job.seed = self.seed;
        job.job = self.job;
        job.pose_mode = self.pose_mode;
        if !(self.pose_sigma >= 0.0 && self.pose_sigma < 0.1) {
            return Err(JobSpecError::PoseSigma(self.pose_sigma));
        }
        job.position_sigma = self.pose_sigma;
        if !(self.step_deg >= 0.005 && self.step_deg <= 2.0) {
            return Err(JobSpecError::StepDeg(self.step_deg));
        }
        job.scanner.step_deg = self.step_deg;
        if let Some(r) = self.rate
            && !(r > 0.0 && r.is_finite())
        {
            return Err(JobSpecError::Rate(r));
        }
        job.rate = self.rate;
        job.closed_loop = self.closed_loop;
        if !(0.0..=1.0).contains(&self.apply) {
            return Err(JobSpecError::Apply(self.apply));
        }
        job.apply = self.apply;
        if let Some(p) = self.profiler {
            job.profiler = Some(p.model()?);
            if p.layers.is_some_and(|n| n == 0 || n > layers) {
                return Err(JobSpecError::Profiler(format!(
                    "{:?} layers to print, of the {layers} the {} has",
                    p.layers, job.part.name
                )));
            }
            job.print_layers = p.layers;
        }
        Ok(job)
    }
}

impl ProfilerSpec {
    /// The simulated profiler, every value checked.
    pub fn model(&self) -> Result<ProfilerModel, JobSpecError> {
        let bad = |what: String| Err(JobSpecError::Profiler(what));
        if !(2..=65_536).contains(&self.points) {
            return bad(format!("{} points a profile", self.points));
        }
        if !(self.rate_hz >= 1.0 && self.rate_hz <= 1e5) {
            return bad(format!("{} profiles a second", self.rate_hz));
        }
        if !(self.pose_rate_hz >= 1.0 && self.pose_rate_hz <= 1e4) {
            return bad(format!("{} poses a second", self.pose_rate_hz));
        }
        Ok(ProfilerModel {
            points: self.points,
            rate_hz: self.rate_hz,
            pose_rate_hz: self.pose_rate_hz,
            clock_offset_ns: self.clock_offset_ns,
            ..ProfilerModel::default()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_spec_is_the_default_job_and_bad_values_say_which() {
        let job = JobSpec::default().build().unwrap();
        assert_eq!(job.scan_after, vec![8, 16, 24, 32, 40, 48]);
        assert_eq!((job.stations_per_scan, job.seed, job.job), (4, 1, 1));
        assert_eq!(job.rate, Some(1.0e6));
        let bad = |f: fn(&mut JobSpec)| {
            let mut s = JobSpec::default();
            f(&mut s);
            s.build().unwrap_err()
        };
        assert!(matches!(
            bad(|s| s.scan_after = vec![50]),
            JobSpecError::ScanAfter { layers: 49, .. }
        ));
        assert!(matches!(bad(|s| s.stations = 0), JobSpecError::NoStations));
        assert!(matches!(
            bad(|s| s.defects = vec!["wobble".into()]),
            JobSpecError::Defect(_)
        ));
        assert!(matches!(
            bad(|s| s.pose_sigma = 0.2),
            JobSpecError::PoseSigma(_)
        ));
        assert!(matches!(
            bad(|s| s.step_deg = 5.0),
            JobSpecError::StepDeg(_)
        ));
        assert!(matches!(bad(|s| s.rate = Some(0.0)), JobSpecError::Rate(_)));
    }
}
