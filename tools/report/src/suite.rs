//! The deviation suite behind `asbuilt inspect --method`: which comparisons run beside C2M,
//! what each keeps while stations stream through, and what each adds to `report.json`. Every
//! computation is asbuilt-core's; this only feeds and collects.

use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};

use asbuilt_core::c2c::{self, C2cParams};
use asbuilt_core::cloud::CloudIndex;
use asbuilt_core::coverage::{CoverageParams, SampleClass, ScanSpacing, Viewpoint};
use asbuilt_core::findings::{FindingParams, Findings};
use asbuilt_core::layers::{BandRow, LayerBands};
use asbuilt_core::m3c2::classic::{self, ClassicParams};
use asbuilt_core::m3c2::streaming::StreamingParams;
use asbuilt_core::sampling::DesignSamples;
use asbuilt_core::scan_layer::{ScanLayer, ScanLayerParams, defaults};
use asbuilt_core::stats::{DeviationAccumulator, StatsConfig};
use asbuilt_core::{C2mIndex, Design};
use asbuilt_protocol::{DeviationFlags, PointDeviation};

use crate::sections::{
    BandMethods, BandStats, CoverageSection, DistanceSection, M3c2Section, SuiteSection,
    SuiteTotals, TwoCloudSection,
};
use nalgebra::{Point3, Vector3};

use asbuilt_io::ply::{Property, Scalar, point_columns, write_table};

/// What a core or file error was caused by.
type Cause = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Why the suite cannot run as asked; each case names the option to change.
#[derive(Debug, thiserror::Error)]
pub enum SuiteError {
    /// The tolerance is not a positive length.
    #[error("--tolerance must be a positive number of metres, got {0}")]
    Tolerance(f64),
    /// An option that must be positive is not.
    #[error("{name} must be a positive number, got {value}")]
    NotPositive {
        /// The option.
        name: &'static str,
        /// What it was.
        value: f64,
    },
    /// A reference cloud without a method that uses it.
    #[error("--reference is for C2C and two-cloud M3C2: add --method c2c or --method m3c2")]
    ReferenceWithoutMethod,
    /// An option's value does not work with this design or scan.
    #[error("{what}")]
    Option {
        /// The option, and what it was asked to do.
        what: String,
        /// Why it does not work.
        #[source]
        source: Cause,
    },
    /// The layer height does not fit the design.
    #[error("--layer-height {0} m does not fit the design's height")]
    LayerHeight(f64),
    /// A file cannot be read or written.
    #[error(transparent)]
    File(#[from] asbuilt_io::IoError),
    /// A computation over the clouds failed.
    #[error(transparent)]
    Cloud(Cause),
    /// Two-cloud M3C2 without a valid scan point.
    #[error("two-cloud M3C2: no valid scan point to compare with the reference")]
    NoScanPoint,
}

impl From<asbuilt_core::cloud::CloudError> for SuiteError {
    fn from(e: asbuilt_core::cloud::CloudError) -> Self {
        Self::Cloud(e.into())
    }
}

impl SuiteError {
    fn option(what: impl Into<String>) -> impl FnOnce(Cause) -> Self {
        let what = what.into();
        move |source| Self::Option { what, source }
    }
}

type Result<T, E = SuiteError> = std::result::Result<T, E>;

/// A comparison `--method` can ask for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Method {
    /// Signed point-to-mesh distance.
    C2m,
    /// Cloud-to-cloud distance, to design samples or a `--reference` cloud.
    C2c,
    /// Which design samples the scan observed, and which are missing.
    Coverage,
    /// M3C2 along the design's normals at the design samples.
    M3c2,
}

impl Method {
    /// Every method, in report order.
    pub const ALL: [Method; 4] = [Method::C2m, Method::C2c, Method::Coverage, Method::M3c2];

    /// The method as `--method` and report.json spell it.
    pub fn name(self) -> &'static str {
        match self {
            Method::C2m => "c2m",
            Method::C2c => "c2c",
            Method::Coverage => "coverage",
            Method::M3c2 => "m3c2",
        }
    }
}

/// A `--method` list, sorted, without repeats.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Methods(pub Vec<Method>);

/// A `--method` list that names no method, or one this build does not know.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MethodsError {
    /// A word that is not a method.
    #[error("unknown method {0:?}: use any of c2m, c2c, coverage, m3c2, or all")]
    Unknown(String),
    /// No method at all.
    #[error("no method given: use any of c2m, c2c, coverage, m3c2, or all")]
    Empty,
}

/// `c2m,c2c,coverage,m3c2` in any subset, or `all`.
pub fn parse_methods(text: &str) -> Result<Methods, MethodsError> {
    let mut out = Vec::new();
    for word in text.split(',').map(str::trim).filter(|w| !w.is_empty()) {
        if word.eq_ignore_ascii_case("all") {
            out.extend(Method::ALL);
            continue;
        }
        match Method::ALL
            .iter()
            .find(|m| m.name().eq_ignore_ascii_case(word))
        {
            Some(m) => out.push(*m),
            None => return Err(MethodsError::Unknown(word.to_string())),
        }
    }
    if out.is_empty() {
        return Err(MethodsError::Empty);
    }
    out.sort();
    out.dedup();
    Ok(Methods(out))
}

/// The layer printed when the scans were taken, counted from the design's base (`lowest`):
/// 0 without a printed height and a layer height.
pub fn printed_layer(printed_height: Option<f64>, layer_height: Option<f64>, lowest: f64) -> u32 {
    match (printed_height, layer_height) {
        (Some(h), Some(lh)) => ((h - lowest) / lh).round().max(0.0) as u32,
        _ => 0,
    }
}

/// A job's findings as the message the agent sends for a scan layer: offline there is one,
/// drawn from all `stations`, at the layer [`printed_layer`] counts, each finding judged by
/// `limits` as the agent judges them.
pub fn findings_message(
    f: &Findings,
    stations: u32,
    (tolerance, limits): (f64, &asbuilt_core::verdict::Limits),
    (printed_height, layer_height): (Option<f64>, Option<f64>),
    lowest: f64,
) -> asbuilt_protocol::StationFindings {
    let layer = printed_layer(printed_height, layer_height, lowest);
    let printed = printed_height.unwrap_or(f64::NAN);
    let mut m = f.to_message(
        (0, stations.saturating_sub(1)),
        stations,
        tolerance,
        (layer, printed),
    );
    asbuilt_core::findings::judge_message(&mut m, limits);
    m
}

/// The suite's parameters, checked and with every default resolved ([`SuiteOptions::resolve`]).
/// Metres.
#[derive(Debug, Clone)]
pub struct SuiteConfig {
    /// The methods to run, sorted; C2M always runs.
    pub methods: Vec<Method>,
    /// |d| at most this is within tolerance.
    pub tolerance: f64,
    /// Spacing of the design samples.
    pub spacing: f64,
    /// M3C2 cylinder diameter.
    pub projection_diameter: f64,
    /// M3C2 cylinder half-length: the largest deviation it measures.
    pub max_depth: f64,
    /// Neighbourhood diameter for the normals of two-cloud M3C2.
    pub normal_diameter: f64,
    /// A design sample with a scan point this close is observed.
    pub coverage_threshold: f64,
    /// What raises the coverage threshold where the scan is sparser.
    pub coverage_spacing: ScanSpacing,
    /// C2C's maximum distance: points farther from the reference have no match.
    pub reach: f64,
    /// Nominal layer height, for the per-layer rows and the findings.
    pub layer_height: Option<f64>,
    /// The printed height the design is cut at.
    pub printed_height: Option<f64>,
    /// The reference cloud, for C2C and two-cloud M3C2 against it.
    pub reference: Option<PathBuf>,
    /// C2C local plane neighbours; `None` for the default (6 against samples, off against a
    /// reference), `Some(0)` for nearest point only.
    pub local_plane: Option<usize>,
    /// Seed of the design sampling, so a job gives the same samples each time.
    pub seed: u64,
}

impl SuiteConfig {
    /// Whether method `m` runs.
    pub fn has(&self, m: Method) -> bool {
        self.methods.contains(&m)
    }
}

/// The suite's parameters as a user gives them, `None` for the default: `asbuilt inspect`'s
/// flags and the Python package's keywords (the flags' names) both resolve here, so they mean
/// the same when left out. Errors name the flags.
#[derive(Debug, Clone, Default)]
pub struct SuiteOptions {
    /// C2M runs whatever is listed.
    pub methods: Vec<Method>,
    /// |d| at most this is within tolerance, metres.
    pub tolerance: f64,
    /// Default 10 × tolerance.
    pub max_distance: Option<f64>,
    /// Spacing of the design samples, metres.
    pub spacing: f64,
    /// Default twice the spacing, at most half the layer height.
    pub projection_diameter: Option<f64>,
    /// Default the maximum distance.
    pub max_depth: Option<f64>,
    /// Default the projection diameter.
    pub normal_diameter: Option<f64>,
    /// Default max(3 mm, tolerance / 2), at most the maximum distance; given, used as it is.
    pub coverage_threshold: Option<f64>,
    /// The scanner's angular step, milliradians; without it the spacing is measured.
    pub scanner_step_mrad: Option<f64>,
    /// Nominal layer height, metres, for the per-layer rows and the findings.
    pub layer_height: Option<f64>,
    /// The printed height to cut the design at, metres.
    pub printed_height: Option<f64>,
    /// A reference cloud for C2C and two-cloud M3C2.
    pub reference: Option<PathBuf>,
    /// C2C local plane neighbours (see [`SuiteConfig::local_plane`]).
    pub local_plane: Option<usize>,
}

impl SuiteConfig {
    /// What report.json says the job was run with; `histogram_range` is C2M's statistics'.
    pub fn parameters(&self, histogram_range: f64) -> crate::Parameters {
        crate::Parameters {
            tolerance_m: self.tolerance,
            max_distance_m: self.reach,
            histogram_range_m: histogram_range,
            spacing_m: self.spacing,
            coverage_threshold_m: self.coverage_threshold,
            // A threshold given by hand is used as it is; else it is raised to the scan's
            // spacing, from the scanner's step when given, measured per station otherwise.
            coverage_spacing: match self.coverage_spacing {
                ScanSpacing::Fixed => "fixed".into(),
                ScanSpacing::AngularStep(a) => format!("scanner step {:.3} mrad", a * 1e3),
                ScanSpacing::Measured => "measured per station".into(),
            },
            projection_diameter_m: self.projection_diameter,
            max_depth_m: self.max_depth,
            printed_height_m: self.printed_height,
            layer_height_m: self.layer_height,
            reference: self.reference.as_ref().map(|p| p.display().to_string()),
        }
    }
}

impl SuiteOptions {
    /// The options checked and their defaults resolved.
    pub fn resolve(&self) -> Result<SuiteConfig> {
        if !(self.tolerance > 0.0 && self.tolerance.is_finite()) {
            return Err(SuiteError::Tolerance(self.tolerance));
        }
        for (name, v) in [
            ("--max-distance", self.max_distance),
            ("spacing", Some(self.spacing)),
            ("--projection-diameter", self.projection_diameter),
            ("--max-depth", self.max_depth),
            ("--normal-diameter", self.normal_diameter),
            ("--coverage-threshold", self.coverage_threshold),
            ("--scanner-step-mrad", self.scanner_step_mrad),
            ("--layer-height", self.layer_height),
        ] {
            if let Some(v) = v
                && !(v > 0.0 && v.is_finite())
            {
                return Err(SuiteError::NotPositive { name, value: v });
            }
        }
        let mut methods = self.methods.clone();
        methods.push(Method::C2m);
        methods.sort();
        methods.dedup();
        if self.reference.is_some()
            && !methods
                .iter()
                .any(|m| matches!(m, Method::C2c | Method::M3c2))
        {
            return Err(SuiteError::ReferenceWithoutMethod);
        }
        let max_distance = self.max_distance.unwrap_or(10.0 * self.tolerance);
        let coverage_threshold = self
            .coverage_threshold
            .unwrap_or_else(|| defaults::coverage_threshold(self.tolerance))
            .min(max_distance);
        let projection_diameter = self
            .projection_diameter
            .unwrap_or_else(|| defaults::projection_diameter(self.spacing, self.layer_height));
        let coverage_spacing = match (self.scanner_step_mrad, self.coverage_threshold) {
            (Some(step), _) => ScanSpacing::AngularStep(step * 1e-3),
            (None, Some(_)) => ScanSpacing::Fixed,
            (None, None) => ScanSpacing::Measured,
        };
        Ok(SuiteConfig {
            methods,
            tolerance: self.tolerance,
            spacing: self.spacing,
            projection_diameter,
            max_depth: self.max_depth.unwrap_or(max_distance),
            normal_diameter: self.normal_diameter.unwrap_or(projection_diameter),
            coverage_threshold,
            coverage_spacing,
            reach: max_distance,
            layer_height: self.layer_height,
            printed_height: self.printed_height,
            reference: self.reference.clone(),
            local_plane: self.local_plane,
            seed: defaults::SAMPLE_SEED,
        })
    }
}

struct C2cRun {
    reference: CloudIndex,
    params: C2cParams,
    station: DeviationAccumulator,
    total: DeviationAccumulator,
    station_no_match: u64,
    total_no_match: u64,
    out: Vec<Option<f64>>,
}

struct Layers {
    c2m: LayerBands,
    c2c: LayerBands,
}

/// The offline deviation suite: C2C, coverage and M3C2 over a job's stations, beside the C2M
/// the command line runs; the findings as the agent draws them.
pub struct Suite {
    config: SuiteConfig,
    c2c: Option<C2cRun>,
    /// M3C2 and coverage over the design samples: the agent's scan-layer state.
    scan_layer: Option<ScanLayer>,
    layers: Option<Layers>,
    /// Reference and every scan point kept, only for two-cloud M3C2 (offline, in memory).
    two_cloud: Option<(CloudIndex, Vec<Point3<f64>>)>,
    positions: Vec<Point3<f64>>,
    missing_by_station: Vec<Vec<u32>>,
    above_station: u64,
    above_total: u64,
    sigma_max: f64,
}

impl Suite {
    /// `design` is what is compared with: the whole design or the part cut at the printed
    /// height.
    pub fn new(design: &Design, config: SuiteConfig) -> Result<Self> {
        let needs_samples = config.has(Method::Coverage)
            || config.has(Method::M3c2)
            || (config.has(Method::C2c) && config.reference.is_none());
        let samples = if needs_samples {
            let s = DesignSamples::generate(design, config.spacing, config.seed)
                .map_err(|e| SuiteError::option("--spacing")(e.into()))?;
            eprintln!(
                "design samples: {} at {:.1} mm spacing ({:.2} cm² each)",
                s.len(),
                config.spacing * 1e3,
                s.area_per_sample * 1e4
            );
            Some(s)
        } else {
            None
        };
        let reference = match &config.reference {
            Some(path) if config.has(Method::C2c) || config.has(Method::M3c2) => {
                let (pts, notes) = asbuilt_io::scan::read_cloud(path)?;
                if notes.malformed_lines > 0 {
                    eprintln!(
                        "warning: reference {}: {} unreadable lines skipped (first at line {})",
                        path.display(),
                        notes.malformed_lines,
                        notes.first_malformed_line.unwrap_or(0)
                    );
                }
                eprintln!("reference cloud {}: {} points", path.display(), pts.len());
                Some(pts)
            }
            _ => None,
        };
        let stats = StatsConfig::with_tolerance(config.tolerance);
        let c2c = if config.has(Method::C2c) {
            let (points, default_k) = match (&reference, &samples) {
                (Some(r), _) => (r.as_slice(), 0),
                // Against design samples the nearest sample is up to a spacing off the surface;
                // a local plane through six of them follows the face.
                (None, Some(s)) => (s.points.as_slice(), 6),
                (None, None) => unreachable!("samples exist without a reference"),
            };
            let local_plane_k = NonZeroUsize::new(config.local_plane.unwrap_or(default_k));
            let params = C2cParams {
                max_distance: config.reach,
                local_plane_k,
            };
            params
                .validate()
                .map_err(|e| SuiteError::option("--local-plane")(e.into()))?;
            Some(C2cRun {
                reference: CloudIndex::new(points)?,
                params,
                station: DeviationAccumulator::new(stats),
                total: DeviationAccumulator::new(stats),
                station_no_match: 0,
                total_no_match: 0,
                out: Vec::new(),
            })
        } else {
            None
        };
        let scan_layer = match &samples {
            Some(s) if config.has(Method::Coverage) || config.has(Method::M3c2) => {
                Some(Self::scan_layer(design, s, &config)?)
            }
            _ => None,
        };
        let layers = match config.layer_height {
            Some(h) => {
                let (lo, hi) = design.bounds();
                let top = config.printed_height.unwrap_or(hi.z).min(hi.z);
                let bands = LayerBands::new(lo.z, top, h).ok_or(SuiteError::LayerHeight(h))?;
                Some(Layers {
                    c2m: bands.clone(),
                    c2c: bands,
                })
            }
            None => None,
        };
        let two_cloud = match reference {
            Some(r) if config.has(Method::M3c2) => Some((CloudIndex::new(&r)?, Vec::new())),
            _ => None,
        };
        Ok(Self {
            config,
            c2c,
            scan_layer,
            layers,
            two_cloud,
            positions: Vec::new(),
            missing_by_station: Vec::new(),
            above_station: 0,
            above_total: 0,
            sigma_max: 0.0,
        })
    }

    /// M3C2 and coverage over `samples`, as the agent sets up a scan layer, with the
    /// command's parameters.
    fn scan_layer(
        design: &Design,
        samples: &DesignSamples,
        config: &SuiteConfig,
    ) -> Result<ScanLayer> {
        let coverage = CoverageParams {
            spacing: config.coverage_spacing,
            max_incidence_deg: defaults::MAX_INCIDENCE_DEG,
            ..CoverageParams::with_threshold(
                config.coverage_threshold,
                defaults::coverage_reach(config.coverage_threshold, config.max_depth),
            )
        };
        let m3c2 = StreamingParams {
            projection_diameter: config.projection_diameter,
            max_depth: config.max_depth,
            min_points: defaults::MIN_POINTS,
        };
        // Findings need both; their M3C2 cylinders must not average across sharp edges.
        let both = config.has(Method::Coverage) && config.has(Method::M3c2);
        let sharp_edges = if both {
            design.sharp_edges(asbuilt_core::printed::SHARP_EDGE_DEG)
        } else {
            Vec::new()
        };
        let params = ScanLayerParams {
            m3c2: config.has(Method::M3c2).then_some(m3c2),
            coverage: config.has(Method::Coverage).then_some(coverage),
            findings: FindingParams {
                tolerance: config.tolerance,
                layer_height: config.layer_height,
                printed_height: config.printed_height.unwrap_or(f64::NAN),
                spacing: config.spacing,
                radius: 0.5 * config.projection_diameter,
                min_region_samples: defaults::MIN_REGION_SAMPLES,
                coverage_threshold: config.coverage_threshold,
                min_missing_area_m2: defaults::MIN_MISSING_AREA_M2,
            },
        };
        // A job run here has the workstation's memory: larger batches, fewer searches.
        Ok(ScanLayer::new(samples, sharp_edges, params)
            .map_err(|e| SuiteError::option("--method coverage/m3c2")(e.into()))?
            .with_batch(asbuilt_core::scan_layer::OFFLINE_BATCH_POINTS))
    }

    /// Starts a station: its own statistics begin at zero.
    pub fn begin_station(&mut self) {
        if let Some(c) = &mut self.c2c {
            c.station = DeviationAccumulator::new(c.station.config());
            c.station_no_match = 0;
        }
        if let Some(l) = &mut self.scan_layer {
            l.begin_station();
        }
        self.above_station = 0;
    }

    /// Takes a processed chunk: the design-frame positions of its valid points and their C2M.
    pub fn chunk(&mut self, devs: &[PointDeviation]) {
        self.positions.clear();
        for d in devs {
            if d.flags.contains(DeviationFlags::REJECTED) {
                continue;
            }
            let p = Point3::from(d.position);
            self.positions.push(p);
            if let Some(h) = self.config.printed_height
                && p.z > h + self.config.tolerance
            {
                self.above_station += 1;
            }
            if let Some(l) = &mut self.layers
                && d.distance.is_finite()
            {
                l.c2m.push(p.z, d.distance);
            }
        }
        let positions = &self.positions;
        if let Some(c) = &mut self.c2c {
            c.out.resize(positions.len(), None);
            c2c::distances(&c.reference, positions, &c.params, &mut c.out);
            for (p, d) in positions.iter().zip(&c.out) {
                match d {
                    Some(d) => {
                        c.station.push(*d);
                        if let Some(l) = &mut self.layers {
                            l.c2c.push(p.z, *d);
                        }
                    }
                    None => c.station_no_match += 1,
                }
            }
        }
        if let Some(l) = &mut self.scan_layer {
            l.ingest(positions);
        }
        if let Some((_, kept)) = &mut self.two_cloud {
            kept.extend_from_slice(positions);
        }
    }

    /// Closes a station scanned from `origin` with position σ `sigma`.
    pub fn end_station(
        &mut self,
        origin: Point3<f64>,
        sigma: f64,
        index: &C2mIndex,
    ) -> SuiteSection {
        self.sigma_max = self.sigma_max.max(sigma);
        self.above_total += self.above_station;
        let mut s = SuiteSection {
            above_printed_height: self.config.printed_height.map(|_| self.above_station),
            ..Default::default()
        };
        if let Some(c) = &mut self.c2c {
            s.c2c = Some(DistanceSection::new(
                &c.station.finish(),
                c.station_no_match,
            ));
            c.total.merge(&c.station);
            c.total_no_match += c.station_no_match;
        }
        if let Some(l) = &mut self.scan_layer {
            let part = l.end_station(Viewpoint::Origin(origin), sigma, index);
            if let Some(summary) = part.coverage {
                s.coverage = Some(CoverageSection::new(&summary, l.area_per_sample()));
                self.missing_by_station.push(summary.missing_samples);
            }
            if let Some(m) = part.m3c2 {
                s.m3c2 = Some(M3c2Section::new(&m, sigma));
            }
        }
        s
    }

    /// The job's sections; writes `missing.ply` and `m3c2.ply` into `out`.
    pub fn finish(self, index: &C2mIndex, out: &Path) -> Result<SuiteTotals> {
        let mut t = SuiteTotals {
            section: SuiteSection {
                above_printed_height: self.config.printed_height.map(|_| self.above_total),
                ..Default::default()
            },
            ..Default::default()
        };
        if let Some(c) = &self.c2c {
            t.section.c2c = Some(DistanceSection::new(&c.total.finish(), c.total_no_match));
        }
        let layer = self.scan_layer.as_ref();
        if let Some((f, samples)) = layer.and_then(|l| l.measure(self.sigma_max, index, true)) {
            t.findings = Some((f, layer.map_or(0, ScanLayer::stations)));
            t.samples = samples;
        }
        let missing_bands = match layer.and_then(ScanLayer::coverage) {
            Some(c) => self.finish_coverage(c, index, out, &mut t)?,
            None => None,
        };
        let m3c2_bands = match layer.and_then(ScanLayer::m3c2) {
            Some(m) => self.finish_m3c2(m, out, &mut t)?,
            None => None,
        };
        if let Some(l) = &self.layers {
            t.layers = Some(layer_table(
                &l.c2m,
                self.c2c.as_ref().map(|_| &l.c2c),
                m3c2_bands.as_ref(),
                missing_bands.as_ref(),
            ));
        }
        if let Some((reference, scan)) = self.two_cloud {
            t.m3c2_two_cloud = Some(two_cloud(&self.config, reference, scan, out)?);
        }
        Ok(t)
    }

    /// Coverage's job-level section, the missing samples for the view and missing.ply; the
    /// missing area per layer band with `--layer-height`.
    fn finish_coverage(
        &self,
        c: &asbuilt_core::coverage::Coverage,
        index: &C2mIndex,
        out: &Path,
        t: &mut SuiteTotals,
    ) -> Result<Option<LayerBands>> {
        eprintln!("coverage: classifying {} design samples", c.samples().len());
        let outcomes = c.outcomes(index);
        let summary = c.summary_of(&outcomes);
        let mut section = CoverageSection::new(&summary, c.area_per_sample());
        let mut rev = DeviationAccumulator::new(StatsConfig::with_tolerance(self.config.tolerance));
        let mut none = 0;
        for o in &outcomes {
            match o.reverse_distance {
                Some(d) => rev.push(d),
                None => none += 1,
            }
        }
        section.reverse_c2c = Some(DistanceSection::new(&rev.finish(), none));
        t.section.coverage = Some(section);
        t.missing_view = outcomes
            .iter()
            .filter(|o| o.class == SampleClass::Missing)
            .map(|o| {
                (
                    o.position,
                    o.reverse_distance.unwrap_or(f64::NAN) as f32,
                    true,
                )
            })
            .collect();
        write_missing(
            &out.join("missing.ply"),
            c.samples(),
            &self.missing_by_station,
            &outcomes,
        )?;
        Ok(self.layers.as_ref().map(|l| {
            let mut b = l.c2m.clone_empty();
            for o in outcomes.iter().filter(|o| o.class == SampleClass::Missing) {
                b.push(o.position.z, c.area_per_sample());
            }
            b
        }))
    }

    /// M3C2's job-level section, the core points for the view and m3c2.ply; the mean distance
    /// per layer band with `--layer-height`.
    fn finish_m3c2(
        &self,
        m: &asbuilt_core::m3c2::streaming::StreamingM3c2,
        out: &Path,
        t: &mut SuiteTotals,
    ) -> Result<Option<LayerBands>> {
        let sigma = self.sigma_max;
        t.section.m3c2 = Some(M3c2Section::new(&m.total(sigma), sigma));
        let results = m.results(sigma);
        t.m3c2_view = results
            .iter()
            .filter_map(|r| r.distance.map(|d| (r.position, d as f32, r.significant)))
            .collect();
        write_table(
            &out.join("m3c2.ply"),
            "asbuilt design-referenced M3C2: core points on the design (metres), distance \
             along the design normal (positive: outside), NaN where the cylinder is empty",
            &with_position_and_normal(&[
                Property::new("distance", Scalar::F32),
                Property::new("lod95", Scalar::F32),
                Property::new("spread", Scalar::F32),
                Property::new("count", Scalar::F32),
                Property::new("significant", Scalar::F32),
            ]),
            results.iter().map(|r| {
                vec![
                    r.position.x,
                    r.position.y,
                    r.position.z,
                    r.normal.x,
                    r.normal.y,
                    r.normal.z,
                    r.distance.unwrap_or(f64::NAN),
                    r.lod95.unwrap_or(f64::NAN),
                    r.spread.unwrap_or(f64::NAN),
                    r.count as f64,
                    r.significant as u8 as f64,
                ]
            }),
        )?;
        Ok(self.layers.as_ref().map(|l| {
            let mut b = l.c2m.clone_empty();
            for r in &results {
                if let Some(d) = r.distance {
                    b.push(r.position.z, d);
                }
            }
            b
        }))
    }
}

fn layer_table(
    c2m: &LayerBands,
    c2c: Option<&LayerBands>,
    m3c2: Option<&LayerBands>,
    missing: Option<&LayerBands>,
) -> Vec<BandMethods> {
    let rows = |b: Option<&LayerBands>| -> std::collections::BTreeMap<u32, BandRow> {
        b.map(|b| b.rows().into_iter().map(|r| (r.layer, r)).collect())
            .unwrap_or_default()
    };
    let (a, b, c, d) = (rows(Some(c2m)), rows(c2c), rows(m3c2), rows(missing));
    let mut layers: Vec<u32> = a
        .keys()
        .chain(b.keys())
        .chain(c.keys())
        .chain(d.keys())
        .copied()
        .collect();
    layers.sort_unstable();
    layers.dedup();
    let (z0, h) = c2m.geometry();
    layers
        .into_iter()
        .map(|k| BandMethods {
            layer: k,
            z_min: z0 + k as f64 * h,
            z_max: z0 + (k + 1) as f64 * h,
            top_m: a.get(&k).map(|r| r.top),
            c2m: a.get(&k).map(BandStats::from),
            c2c: c2c.map(|_| b.get(&k).map(BandStats::from)).unwrap_or(None),
            m3c2: m3c2.map(|_| c.get(&k).map(BandStats::from)).unwrap_or(None),
            missing_area_m2: missing.map(|_| d.get(&k).map_or(0.0, |r| r.mean * r.count as f64)),
        })
        .collect()
}

/// Missing samples of each station (`station` = its index) and of the job (`station` = −1).
fn write_missing(
    path: &Path,
    samples: &[Point3<f64>],
    per_station: &[Vec<u32>],
    outcomes: &[asbuilt_core::coverage::SampleOutcome],
) -> Result<u64> {
    let stations = per_station.iter().enumerate().flat_map(|(k, ids)| {
        ids.iter().map(move |&i| {
            let p = samples[i as usize];
            vec![
                p.x,
                p.y,
                p.z,
                f64::NAN,
                f64::NAN,
                f64::NAN,
                f64::NAN,
                k as f64,
            ]
        })
    });
    let total = outcomes
        .iter()
        .filter(|o| o.class == SampleClass::Missing)
        .map(|o| {
            vec![
                o.position.x,
                o.position.y,
                o.position.z,
                o.normal.x,
                o.normal.y,
                o.normal.z,
                o.reverse_distance.unwrap_or(f64::NAN),
                -1.0,
            ]
        });
    write_table(
        path,
        "asbuilt missing material: design samples (metres) a station should have seen with no \
         scan point within the coverage threshold. station = -1: the whole job, with normal and \
         reverse_c2c (signed distance to the nearest scan point, NaN: none within reach); \
         station = k: what station k alone missed",
        &with_position_and_normal(&[
            Property::new("reverse_c2c", Scalar::F32),
            Property::new("station", Scalar::F32),
        ]),
        stations.chain(total),
    )
    .map_err(Into::into)
}

/// A sample table's columns: the point (metres, f64), its unit normal, then `rest`.
fn with_position_and_normal(rest: &[Property]) -> Vec<Property> {
    let normal = ["nx", "ny", "nz"].map(|n| Property::new(n, Scalar::F32));
    point_columns(&[&normal[..], rest].concat())
}

fn two_cloud(
    config: &SuiteConfig,
    reference: CloudIndex,
    scan: Vec<Point3<f64>>,
    out: &Path,
) -> Result<TwoCloudSection> {
    let path = config
        .reference
        .as_ref()
        .expect("two-cloud runs with a reference");
    if scan.is_empty() {
        return Err(SuiteError::NoScanPoint);
    }
    // Core points: the first reference point in each cell of the sample spacing.
    let mut seen = std::collections::HashSet::new();
    let cores: Vec<Point3<f64>> = (0..reference.len() as u32)
        .map(|i| reference.point(i))
        .filter(|p| seen.insert((p / config.spacing).map(|v| v.floor() as i64).coords))
        .collect();
    eprintln!(
        "two-cloud M3C2: {} core points from {} reference points against {} scan points",
        cores.len(),
        reference.len(),
        scan.len()
    );
    let scan_index = CloudIndex::new(&scan)?;
    let mut params = ClassicParams::new(
        config.normal_diameter,
        config.projection_diameter,
        config.max_depth,
    );
    params.orientation = Vector3::z();
    let results = classic::compare(&reference, &scan_index, &cores, &params)
        .map_err(|e| SuiteError::Cloud(e.into()))?;
    let with: Vec<f64> = results.iter().filter_map(|r| r.distance).collect();
    write_table(
        &out.join("m3c2_two_cloud.ply"),
        "asbuilt two-cloud M3C2 from the reference to the scans: core points subsampled from the \
         reference, distance along the normal (NaN where a cylinder is empty)",
        &point_columns(&[
            Property::new("distance", Scalar::F32),
            Property::new("lod95", Scalar::F32),
            Property::new("significant", Scalar::F32),
        ]),
        cores.iter().zip(&results).map(|(p, r)| {
            vec![
                p.x,
                p.y,
                p.z,
                r.distance.unwrap_or(f64::NAN),
                r.lod95.unwrap_or(f64::NAN),
                r.significant as u8 as f64,
            ]
        }),
    )?;
    Ok(TwoCloudSection {
        reference: path.display().to_string(),
        reference_points: reference.len(),
        scan_points: scan.len(),
        core_points: cores.len(),
        with_distance: with.len(),
        significant: results.iter().filter(|r| r.significant).count(),
        mean_distance: (!with.is_empty()).then(|| with.iter().sum::<f64>() / with.len() as f64),
        normal_diameter_m: config.normal_diameter,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn methods_parse_as_a_subset_or_all() {
        assert_eq!(parse_methods("c2m").unwrap().0, vec![Method::C2m]);
        assert_eq!(
            parse_methods("m3c2, C2C,c2c").unwrap().0,
            vec![Method::C2c, Method::M3c2]
        );
        assert_eq!(parse_methods("all").unwrap().0, Method::ALL.to_vec());
        assert_eq!(
            parse_methods("icp").unwrap_err(),
            MethodsError::Unknown("icp".into())
        );
        assert_eq!(parse_methods("").unwrap_err(), MethodsError::Empty);
    }
}
