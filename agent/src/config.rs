//! `agent.toml`: what the agent inspects against, how poses become design-frame transforms, which
//! services it serves, and its limits. Loading validates everything and lists every problem with
//! its key, so one run of `asbuilt-agent --check-config` finds them all.

use std::path::{Path, PathBuf};
use std::time::Duration;

use asbuilt_core::Units;
use asbuilt_core::frames::{FrameChain, isometry};
use serde::Deserialize;
use serde::de::DeserializeOwned;

mod profiler;
pub use profiler::ProfilerConfig;

/// Methods this build can run in the agent. The deviation suite (C2C, coverage, M3C2) arrives
/// with its own issue; asking for it now is a configuration error, not a silent no-op.
pub const AVAILABLE_METHODS: &[&str] = &["c2m"];

/// `agent.toml`, read and checked: every section with its defaults filled in.
#[derive(Debug, Clone)]
pub struct AgentConfig {
    /// The file the configuration was read from, for messages.
    pub source: PathBuf,
    /// `[design]`: the design file and its units.
    pub design: DesignConfig,
    /// `[calibration]`: the chain from the robot's pose to the design frame.
    pub frames: FrameChain,
    /// `[inspect]`: methods, tolerance, maximum distance, range, index cell.
    pub inspect: InspectConfig,
    /// `[services]`: the iceoryx2 service names' prefix.
    pub services: ServicesConfig,
    /// `[limits]`: the bounds on chunks, queues and open stations.
    pub limits: Limits,
    /// `[status]`: how often the agent reports its health.
    pub status: StatusConfig,
    /// `[recorder]`: the MCAP recording.
    pub recorder: RecorderConfig,
    /// `[viewer]`: the rerun view.
    pub viewer: ViewerConfig,
    /// `[findings]`: M3C2 and coverage over each scan layer.
    pub findings: FindingsConfig,
    /// `[tolerances]`: the limits the findings are held to.
    pub tolerances: TolerancesConfig,
    /// `[corrections]`: advice for the layers still to print.
    pub corrections: CorrectionsConfig,
    /// `[profiler]`: a line profiler's clocks, wait and field of view.
    pub profiler: ProfilerConfig,
    /// The file as written, for the recording's metadata.
    pub text: String,
}

/// `[findings]`: M3C2 against the design and coverage over each scan layer's stations, turned
/// into findings (per-layer width, shift and top height, regions out of tolerance, missing
/// material) after every station. Off unless `enabled`; the state is per design sample, so
/// memory grows with the design and the spacing, never with the scan.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FindingsConfig {
    /// Findings are computed and sent after each station.
    pub enabled: bool,
    /// Spacing of the design samples (the M3C2 core points), metres.
    pub spacing: f64,
    /// M3C2 cylinder diameter, metres. Default: twice the spacing, at most half a layer height
    /// (so the cylinders of a layer do not reach into the next).
    pub projection_diameter: Option<f64>,
    /// M3C2 cylinder half-length, metres: the largest deviation it can measure. Default: the
    /// inspection's max distance.
    pub max_depth: Option<f64>,
    /// Nominal layer height, metres, for the per-layer rows. None: no per-layer rows.
    pub layer_height: Option<f64>,
    /// A design sample with a scan point this close is observed, metres. Default
    /// max(3 mm, tolerance / 2), raised to the scan's point spacing where that is wider
    /// (measured per station, or from `scanner_step_mrad`). Set here, it is used as it is.
    pub coverage_threshold: Option<f64>,
    /// The scanner's angular step, milliradians: coverage expects points step × range apart
    /// instead of measuring the spacing of each station's points.
    pub scanner_step_mrad: Option<f64>,
    /// Steeper views than this do not call a surface missing, degrees.
    pub max_incidence_deg: f64,
    /// Regions and missing areas of fewer samples are not reported.
    pub min_region_samples: usize,
    /// Missing areas smaller than this are not reported, m² (a ledge that sticks out shadows a
    /// strip below it).
    pub min_missing_area_m2: f64,
}

impl Default for FindingsConfig {
    fn default() -> Self {
        use asbuilt_core::scan_layer::defaults;
        Self {
            enabled: false,
            spacing: defaults::SPACING,
            projection_diameter: None,
            max_depth: None,
            layer_height: None,
            coverage_threshold: None,
            scanner_step_mrad: None,
            max_incidence_deg: defaults::MAX_INCIDENCE_DEG,
            min_region_samples: defaults::MIN_REGION_SAMPLES,
            min_missing_area_m2: defaults::MIN_MISSING_AREA_M2,
        }
    }
}

/// `[corrections]`: after each station's findings, advice for the layers still to print (a z
/// offset per layer, a flow factor, a lateral path offset), published on
/// `PREFIX/agent/corrections` and recorded. Off unless `enabled`; needs `[findings]` with a
/// `layer_height`. The advice is the agent's: the cell decides whether to apply it. Metres.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct CorrectionsConfig {
    /// Corrections are computed and sent after each station's findings.
    pub enabled: bool,
    /// The largest z offset advised for any one layer.
    pub max_z_per_layer: f64,
    /// The smallest flow factor advised.
    pub flow_min: f64,
    /// The largest flow factor advised.
    pub flow_max: f64,
    /// The largest lateral path offset advised.
    pub max_path_offset: f64,
    /// Errors (top height, width, shift) and changes within this are the measurement's noise:
    /// the advice is held (a change of the top, a difference of two measurements, within √2
    /// of it). Default 1.5 mm: three sigma of the top of a scan layer seen by four stations
    /// each posed to 1 mm.
    pub deadband: f64,
    /// Layers over which an accumulated top height error is taken back.
    pub absorb_layers: u32,
    /// The latest layer bands (printed since the last scan layer) whose width and shift count.
    pub bands: u32,
    /// The nominal width of a printed layer (the bead): the design file does not say it, so it
    /// is declared. Without it, widths are measured and sent but no flow factor is advised.
    pub bead_width: Option<f64>,
}

impl Default for CorrectionsConfig {
    fn default() -> Self {
        let l = asbuilt_core::corrections::CorrectionLimits::default();
        Self {
            enabled: false,
            max_z_per_layer: l.max_z_per_layer,
            flow_min: l.flow.0,
            flow_max: l.flow.1,
            max_path_offset: l.max_path_offset,
            deadband: l.deadband,
            absorb_layers: l.absorb_layers,
            bands: l.bands,
            bead_width: l.bead_width,
        }
    }
}

impl CorrectionsConfig {
    /// The corrector's limits.
    pub fn limits(&self) -> asbuilt_core::corrections::CorrectionLimits {
        asbuilt_core::corrections::CorrectionLimits {
            max_z_per_layer: self.max_z_per_layer,
            flow: (self.flow_min, self.flow_max),
            max_path_offset: self.max_path_offset,
            deadband: self.deadband,
            absorb_layers: self.absorb_layers,
            bands: self.bands,
            bead_width: self.bead_width,
        }
    }
}

fn check_corrections(c: &CorrectionsConfig, problems: &mut Vec<String>) {
    if let Err(e) = c.limits().check() {
        problems.push(format!("corrections: {e}"));
    }
}

impl FindingsConfig {
    /// The M3C2 cylinder diameter: the one given, else the default for the spacing and layer
    /// height.
    pub fn projection_diameter(&self) -> f64 {
        use asbuilt_core::scan_layer::defaults;
        self.projection_diameter
            .unwrap_or_else(|| defaults::projection_diameter(self.spacing, self.layer_height))
    }

    /// The coverage threshold: the one given, else the default for `tolerance`.
    pub fn coverage_threshold(&self, tolerance: f64) -> f64 {
        use asbuilt_core::scan_layer::defaults;
        self.coverage_threshold
            .unwrap_or_else(|| defaults::coverage_threshold(tolerance))
    }

    /// What a scan layer at `printed_height` measures: M3C2 and coverage over the design's
    /// samples, and the findings drawn from them.
    pub fn scan_layer(
        &self,
        tolerance: f64,
        max_depth: f64,
        printed_height: f64,
    ) -> asbuilt_core::scan_layer::ScanLayerParams {
        use asbuilt_core::coverage::CoverageParams;
        use asbuilt_core::findings::FindingParams;
        use asbuilt_core::m3c2::streaming::StreamingParams;
        use asbuilt_core::scan_layer::{ScanLayerParams, defaults};
        let threshold = self.coverage_threshold(tolerance);
        let projection_diameter = self.projection_diameter();
        let reach = defaults::coverage_reach(threshold, max_depth);
        let mut coverage = CoverageParams::with_threshold(threshold, reach);
        coverage.max_incidence_deg = self.max_incidence_deg;
        coverage.spacing = self.coverage_spacing();
        ScanLayerParams {
            m3c2: Some(StreamingParams {
                projection_diameter,
                max_depth,
                min_points: defaults::MIN_POINTS,
            }),
            coverage: Some(coverage),
            findings: FindingParams {
                tolerance,
                layer_height: self.layer_height,
                printed_height,
                spacing: self.spacing,
                radius: 0.5 * projection_diameter,
                min_region_samples: self.min_region_samples,
                coverage_threshold: threshold,
                min_missing_area_m2: self.min_missing_area_m2,
            },
        }
    }

    /// What raises the coverage threshold where the scan is sparser (see the fields).
    pub fn coverage_spacing(&self) -> asbuilt_core::coverage::ScanSpacing {
        use asbuilt_core::coverage::ScanSpacing;
        match (self.scanner_step_mrad, self.coverage_threshold) {
            (Some(step), _) => ScanSpacing::AngularStep(step * 1e-3),
            (None, Some(_)) => ScanSpacing::Fixed,
            (None, None) => ScanSpacing::Measured,
        }
    }
}

/// `[viewer]`: the rerun view. Off unless `rrd` or `url` is given.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ViewerConfig {
    /// A `.rrd` file to write (relative to this file).
    pub rrd: Option<PathBuf>,
    /// A rerun viewer to stream to: `rerun+http://HOST:PORT/proxy`.
    pub url: Option<String>,
    /// Points shown per station, at most (decimated evenly).
    pub max_points_per_station: usize,
    /// Items waiting for the viewer beyond which new ones are dropped (and counted).
    pub queue: usize,
}

impl Default for ViewerConfig {
    fn default() -> Self {
        Self {
            rrd: None,
            url: None,
            max_points_per_station: 200_000,
            queue: 256,
        }
    }
}

/// `[recorder]`: the MCAP flight recorder. Off unless `dir` is given.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecorderConfig {
    /// Where job recordings go (created if missing); relative to this file.
    pub dir: Option<PathBuf>,
    /// A job's file is closed and a `-partN` file begun when its messages pass this size, MB
    /// (each part repeats the metadata and the design, so each replays on its own).
    pub max_file_mb: f64,
    /// Record every Nth scan chunk (and its deviations): 1 all, 0 none (events, poses,
    /// reports and status are always recorded).
    pub scan_every: u32,
    /// Below this much free disk space, scan and deviation chunks are no longer recorded, MB.
    pub min_free_mb: f64,
    /// Bytes of chunks waiting for the writer beyond which chunks are left out, MB.
    pub queue_mb: f64,
    /// Also record deviation chunks (2.5 × the bytes of the scans; a replay recomputes them).
    pub deviations: bool,
    /// How the file's chunks are compressed: `zstd` (the default: a third smaller on scan
    /// points, on the writer's thread), `lz4` or `none`.
    pub compression: asbuilt_protocol::recording::ChunkCompression,
    /// Also write channels in Foxglove's schemas (the design, the stations' frames, the
    /// deviation-coloured points, reports and findings as JSON), so Foxglove opens the file as
    /// it is. Deviation chunks are then taken to the writer even without `deviations`.
    pub foxglove: bool,
    /// One point in this many of a chunk goes into the Foxglove deviations' cloud, if it matched
    /// (1: every point). The asbuilt channels keep every point: replay and report use those.
    pub foxglove_every: u32,
    /// At start, take up the newest job recorded in `dir`: recover files whose writer died,
    /// replay the current scan layer so its findings go on, report the stations that were open
    /// as interrupted and publish the recorded reports again.
    pub resume: bool,
    /// Keep the design with its index in `dir/design.index`, so a restart takes them up
    /// instead of indexing the design again (seconds for a million triangles). About the
    /// index's size on disk; written once per design, build and `[inspect]` parameters.
    pub index_cache: bool,
}

impl Default for RecorderConfig {
    fn default() -> Self {
        Self {
            dir: None,
            max_file_mb: 2048.0,
            scan_every: 1,
            min_free_mb: 1024.0,
            queue_mb: 256.0,
            deviations: false,
            compression: Default::default(),
            foxglove: false,
            foxglove_every: 16,
            resume: true,
            index_cache: true,
        }
    }
}

/// `[design]`: the design file and the units it is written in.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DesignConfig {
    /// Relative paths are relative to the configuration file.
    pub path: PathBuf,
    /// `m` or `mm`: the unit the design file is written in. Never guessed.
    pub units: String,
}

impl DesignConfig {
    /// The declared units (checked when the configuration is loaded).
    pub fn units(&self) -> Units {
        self.units.parse().unwrap_or(Units::Metres)
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Transform {
    translation: [f64; 3],
    rotation_xyzw: [f64; 4],
}

#[derive(Debug, Clone, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct CalibrationSection {
    t_design_base: Option<Transform>,
    t_flange_scanner: Option<Transform>,
    r_base_flange_xyzw: Option<[f64; 4]>,
}

/// `[inspect]`: how each scan point is compared with the design.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InspectConfig {
    /// Methods per point; only `c2m` today (see [`AVAILABLE_METHODS`]).
    pub methods: Vec<String>,
    /// Metres: |d| <= tolerance is within tolerance.
    pub tolerance: f64,
    /// Metres; points farther from the design have no match. Default 10 × tolerance.
    pub max_distance: Option<f64>,
    /// Metres, scanner frame: coordinates beyond this are rejected as out of range.
    pub max_range: f64,
    /// Metres; grid cell of the C2M index. Default: chosen from the design's edge length.
    pub cell_size: Option<f64>,
}

impl Default for InspectConfig {
    fn default() -> Self {
        Self {
            methods: vec!["c2m".into()],
            tolerance: 0.005,
            max_distance: None,
            max_range: asbuilt_core::station::DEFAULT_MAX_RANGE,
            cell_size: None,
        }
    }
}

impl InspectConfig {
    /// The maximum distance: the one given, else ten times the tolerance.
    pub fn max_distance(&self) -> f64 {
        self.max_distance.unwrap_or(10.0 * self.tolerance)
    }
}

/// `[services]`: where the agent's iceoryx2 services are.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServicesConfig {
    /// Every service name starts with this, e.g. `asbuilt/cell-1/scan/chunks`.
    pub prefix: String,
}

impl Default for ServicesConfig {
    fn default() -> Self {
        Self {
            prefix: "asbuilt".into(),
        }
    }
}

/// `[limits]`: what bounds the agent's memory and its queues.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Limits {
    /// Largest chunk the agent accepts; also the size of each shared-memory sample.
    pub max_points_per_chunk: usize,
    /// Scan chunks queued in shared memory for the agent before the scanner is held back.
    pub chunk_queue: usize,
    /// Chunks held (zero-copy) while their station's pose has not arrived.
    pub pending_chunks: usize,
    /// Stations open at the same time.
    pub open_stations: usize,
    /// Seconds without a message for an open station before it closes as timed out.
    pub station_timeout_s: f64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_points_per_chunk: 1 << 16,
            chunk_queue: 32,
            pending_chunks: 16,
            open_stations: 4,
            station_timeout_s: 30.0,
        }
    }
}

impl Limits {
    /// [`Limits::station_timeout_s`] as a duration.
    pub fn station_timeout(&self) -> Duration {
        Duration::from_secs_f64(self.station_timeout_s)
    }
}

/// `[status]`: the agent's health messages and log lines.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StatusConfig {
    /// Seconds between status messages and health log lines.
    pub period_s: f64,
}

impl Default for StatusConfig {
    fn default() -> Self {
        Self { period_s: 5.0 }
    }
}

impl StatusConfig {
    /// [`StatusConfig::period_s`] as a duration.
    pub fn period(&self) -> Duration {
        Duration::from_secs_f64(self.period_s)
    }
}

/// Every problem found in a configuration, each as `key: what is wrong; what to do`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}: {} problem(s):\n  - {}", problems.len(), problems.join("\n  - "))]
pub struct ConfigError {
    /// The configuration file.
    pub file: String,
    /// Every problem, as `key: what is wrong; what to do`.
    pub problems: Vec<String>,
}

const SECTIONS: &[&str] = &[
    "design",
    "calibration",
    "inspect",
    "services",
    "limits",
    "status",
    "recorder",
    "viewer",
    "findings",
    "tolerances",
    "corrections",
    "profiler",
];

impl AgentConfig {
    /// What the findings are held to: the `[tolerances]` over the job's tolerance, with their
    /// decision rule. Limits or a rule that do not parse were refused by [`AgentConfig::load`];
    /// a configuration built otherwise falls back to the tolerance for every kind.
    pub fn verdict_limits(&self) -> asbuilt_core::verdict::Limits {
        let t = &self.tolerances;
        let mut l = t.limits(self.inspect.tolerance).unwrap_or_else(|_| {
            asbuilt_core::verdict::Limits::from_tolerance(self.inspect.tolerance)
        });
        l.rule = t.decision_rule().unwrap_or_default();
        l
    }

    /// Reads and checks `path`: every problem at once, or the configuration with relative paths
    /// resolved against the file's folder.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let fail = |p: String| ConfigError {
            file: path.display().to_string(),
            problems: vec![p],
        };
        let text = std::fs::read_to_string(path)
            .map_err(|e| fail(format!("cannot read the configuration: {e}")))?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::parse(&text, base, path)
    }

    /// Parses and validates `text`; relative paths are resolved against `base`.
    pub fn parse(text: &str, base: &Path, source: &Path) -> Result<Self, ConfigError> {
        let mut problems = Vec::new();
        let table: toml::Table = toml::from_str(text).map_err(|e| ConfigError {
            file: source.display().to_string(),
            problems: vec![format!("not valid TOML: {e}")],
        })?;
        for key in table.keys() {
            if !SECTIONS.contains(&key.as_str()) {
                problems.push(format!(
                    "[{key}]: unknown section; the sections are {}",
                    SECTIONS.join(", ")
                ));
            }
        }
        let design: Option<DesignConfig> = section(&table, "design", &mut problems, false);
        let calibration: CalibrationSection =
            section(&table, "calibration", &mut problems, true).unwrap_or_default();
        let inspect: InspectConfig =
            section(&table, "inspect", &mut problems, true).unwrap_or_default();
        let services: ServicesConfig =
            section(&table, "services", &mut problems, true).unwrap_or_default();
        let limits: Limits = section(&table, "limits", &mut problems, true).unwrap_or_default();
        let status: StatusConfig =
            section(&table, "status", &mut problems, true).unwrap_or_default();
        let mut recorder: RecorderConfig =
            section(&table, "recorder", &mut problems, true).unwrap_or_default();
        let mut viewer: ViewerConfig =
            section(&table, "viewer", &mut problems, true).unwrap_or_default();
        let findings: FindingsConfig =
            section(&table, "findings", &mut problems, true).unwrap_or_default();
        check_findings(&findings, &mut problems);
        let tolerances: TolerancesConfig =
            section(&table, "tolerances", &mut problems, true).unwrap_or_default();
        let corrections: CorrectionsConfig =
            section(&table, "corrections", &mut problems, true).unwrap_or_default();
        check_corrections(&corrections, &mut problems);
        let profiler: ProfilerConfig =
            section(&table, "profiler", &mut problems, true).unwrap_or_default();
        profiler.check(&mut problems);
        if corrections.enabled && !(findings.enabled && findings.layer_height.is_some()) {
            problems.push(
                "corrections.enabled: corrections are drawn from the findings' layer bands; \
                 turn [findings] on with a layer_height"
                    .into(),
            );
        }
        // Kinds left out take inspect.tolerance, whose own problem is reported there.
        let tolerance_ok = inspect.tolerance > 0.0 && inspect.tolerance.is_finite();
        if let (true, Err(e)) = (tolerance_ok, tolerances.limits(inspect.tolerance)) {
            problems.push(format!("tolerances: {e}"));
        }
        tolerances.check_standards(&mut problems);
        check_outputs(&mut recorder, &mut viewer, base, &mut problems);

        let design = design.map(|mut d| {
            if d.path.is_relative() {
                d.path = base.join(&d.path);
            }
            if !d.path.is_file() {
                problems.push(format!(
                    "design.path: {} does not exist (relative paths are relative to this file)",
                    d.path.display()
                ));
            }
            if let Err(e) = d.units.parse::<Units>() {
                problems.push(format!("design.units: {e}"));
            }
            d
        });
        let frames = frames(&calibration, &mut problems);
        check_inspect(&inspect, &mut problems);
        check_services(&services, &mut problems);
        check_limits(&limits, &mut problems);
        if !(status.period_s > 0.0 && status.period_s <= 3600.0) {
            problems.push(format!(
                "status.period_s: {} is not a period; give seconds in (0, 3600]",
                status.period_s
            ));
        }
        match design {
            Some(design) if problems.is_empty() => Ok(Self {
                source: source.to_path_buf(),
                design,
                frames,
                inspect,
                services,
                limits,
                status,
                recorder,
                viewer,
                findings,
                tolerances,
                corrections,
                profiler,
                text: text.to_string(),
            }),
            _ => Err(ConfigError {
                file: source.display().to_string(),
                problems,
            }),
        }
    }
}

/// The parts of a configuration that decide what a recorded job's reports are: the frames and
/// the inspection settings. For reading a recording on a machine where the design path and the
/// services mean nothing.
pub fn recorded_settings(text: &str) -> Result<(FrameChain, InspectConfig), Vec<String>> {
    let table: toml::Table =
        toml::from_str(text).map_err(|e| vec![format!("not valid TOML: {e}")])?;
    let mut problems = Vec::new();
    let calibration: CalibrationSection =
        section(&table, "calibration", &mut problems, true).unwrap_or_default();
    let inspect: InspectConfig =
        section(&table, "inspect", &mut problems, true).unwrap_or_default();
    let frames = frames(&calibration, &mut problems);
    check_inspect(&inspect, &mut problems);
    if problems.is_empty() {
        Ok((frames, inspect))
    } else {
        Err(problems)
    }
}

/// The `[limits]` of a recorded configuration (the defaults where it has none), so that a reader
/// of the recording assembles its stations as the agent did.
pub fn recorded_limits(text: &str) -> Result<Limits, Vec<String>> {
    recorded_section(text, "limits", check_limits)
}

/// The `[findings]` of a recorded configuration (off where it has none), so that a reader of
/// the recording draws the findings the agent drew.
pub fn recorded_findings(text: &str) -> Result<FindingsConfig, Vec<String>> {
    recorded_section(text, "findings", check_findings)
}

/// The `[corrections]` of a recorded configuration (off where it has none), so that a reader
/// of the recording advises what the agent advised.
pub fn recorded_corrections(text: &str) -> Result<CorrectionsConfig, Vec<String>> {
    recorded_section(text, "corrections", check_corrections)
}

/// The `[profiler]` of a recorded configuration: how its passes' profiles were placed.
pub fn recorded_profiler(text: &str) -> Result<ProfilerConfig, Vec<String>> {
    recorded_section(text, "profiler", ProfilerConfig::check)
}

/// The `[tolerances]` of a recorded configuration (the job's tolerance for every kind where it
/// has none), so that a reader of the recording judges the findings by the crew's limits.
pub fn recorded_tolerances(text: &str) -> Result<TolerancesConfig, Vec<String>> {
    recorded_section(text, "tolerances", |_, _| {})
}

/// One section of a recorded configuration, its defaults where the configuration has none,
/// checked as the agent checked it at start.
fn recorded_section<T: DeserializeOwned + Default>(
    text: &str,
    name: &str,
    check: impl Fn(&T, &mut Vec<String>),
) -> Result<T, Vec<String>> {
    let table: toml::Table =
        toml::from_str(text).map_err(|e| vec![format!("not valid TOML: {e}")])?;
    let mut problems = Vec::new();
    let value: T = section(&table, name, &mut problems, true).unwrap_or_default();
    check(&value, &mut problems);
    if problems.is_empty() {
        Ok(value)
    } else {
        Err(problems)
    }
}

/// `[tolerances]`: the limits a crew holds the findings to, per kind and optionally per range
/// of layers. Lengths in metres, the missing area in m²; a kind left out is held to
/// `[inspect] tolerance`. The agent checks them at start; the report gives every finding, layer
/// band and scan layer a verdict against them (pass, warn beyond `warn_fraction` of the limit,
/// fail beyond it).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TolerancesConfig {
    /// |width deviation| of a layer band, metres.
    pub width: Option<f64>,
    /// |top of the print − printed height|, metres.
    pub top_height: Option<f64>,
    /// |shift| of a layer band in the plan, metres.
    pub position: Option<f64>,
    /// |peak deviation| of an area of the surface, metres.
    pub surface: Option<f64>,
    /// Area of missing material, m².
    pub missing_area_m2: Option<f64>,
    /// |change of a layer band's width| since the first scan layer that saw it, metres.
    pub creep: Option<f64>,
    /// A value beyond this fraction of its limit warns (default 0.75).
    pub warn_fraction: Option<f64>,
    /// Per range of layers, later entries winning: `"width=12mm@2-4"` (the `--limit` syntax).
    pub layers: Vec<String>,
    /// A standard every planar face's flatness is judged by with a virtual straightedge, as
    /// `--flatness` takes it: `"din18202:6"`, `"aci117:B"`. `asbuilt report` applies it.
    pub flatness: Option<String>,
    /// A standard the element's dimensions and plumb are judged by, as `--dimensions` takes
    /// it: `"din18202"`. `asbuilt report` applies it.
    pub dimensions: Option<String>,
    /// How the standards' verdicts weigh the measurement's uncertainty: `"iso14253-1"` (the
    /// default: a pass or a fail only where the expanded uncertainty proves it, inconclusive
    /// between) or `"simple"` (the value alone against the limit).
    pub decision_rule: Option<String>,
}

impl TolerancesConfig {
    /// The flatness standard, when one is set.
    pub fn flatness(
        &self,
    ) -> Result<
        Option<asbuilt_core::flatness::FlatnessStandard>,
        asbuilt_core::flatness::UnknownStandard,
    > {
        self.flatness.as_deref().map(str::parse).transpose()
    }

    /// The standards and the decision rule that do not parse, into `problems`.
    fn check_standards(&self, problems: &mut Vec<String>) {
        if let Err(e) = self.flatness() {
            problems.push(format!("tolerances.{e}"));
        }
        if let Err(e) = self.decision_rule() {
            problems.push(format!("[tolerances] {e}"));
        }
        if let Err(e) = self.dimensions() {
            problems.push(format!("tolerances.{e}"));
        }
    }

    /// The decision rule, ISO 14253-1 unless another is set.
    pub fn decision_rule(
        &self,
    ) -> Result<asbuilt_core::verdict::DecisionRule, asbuilt_core::verdict::UnknownDecisionRule>
    {
        self.decision_rule
            .as_deref()
            .map_or(Ok(Default::default()), str::parse)
    }

    /// The dimensions standard, when one is set.
    pub fn dimensions(
        &self,
    ) -> Result<
        Option<asbuilt_core::flatness::DimensionsStandard>,
        asbuilt_core::flatness::UnknownDimensionsStandard,
    > {
        self.dimensions.as_deref().map(str::parse).transpose()
    }

    /// The limits for a job whose tolerance is `tolerance`, then `extra` (`--limit` on the
    /// command line) over them.
    pub fn limits_with(
        &self,
        tolerance: f64,
        extra: &[asbuilt_core::verdict::LayerLimit],
    ) -> Result<asbuilt_core::verdict::Limits, asbuilt_core::verdict::LimitError> {
        use asbuilt_core::verdict::Limits;
        let mut l = Limits::from_tolerance(tolerance);
        let given = [
            (&mut l.width, self.width),
            (&mut l.top_height, self.top_height),
            (&mut l.position, self.position),
            (&mut l.surface, self.surface),
            (&mut l.missing_area_m2, self.missing_area_m2),
            (&mut l.creep, self.creep),
            (&mut l.warn_fraction, self.warn_fraction),
        ];
        for (slot, v) in given {
            if let Some(v) = v {
                *slot = v;
            }
        }
        for text in &self.layers {
            l.set(text.parse()?);
        }
        for x in extra {
            l.set(*x);
        }
        l.check()?;
        Ok(l)
    }

    /// The limits for a job whose tolerance is `tolerance`.
    pub fn limits(
        &self,
        tolerance: f64,
    ) -> Result<asbuilt_core::verdict::Limits, asbuilt_core::verdict::LimitError> {
        self.limits_with(tolerance, &[])
    }
}

/// Deserialises one section, recording its problem instead of stopping at it.
fn section<T: DeserializeOwned>(
    table: &toml::Table,
    name: &str,
    problems: &mut Vec<String>,
    optional: bool,
) -> Option<T> {
    let Some(value) = table.get(name) else {
        if !optional {
            problems.push(format!(
                "[{name}]: missing; see agent/agent.example.toml for what it holds"
            ));
        }
        return None;
    };
    match value.clone().try_into::<T>() {
        Ok(v) => Some(v),
        Err(e) => {
            problems.push(format!("[{name}]: {}", e.to_string().trim()));
            None
        }
    }
}

fn frames(c: &CalibrationSection, problems: &mut Vec<String>) -> FrameChain {
    let mut chain = FrameChain::default();
    let mut transform = |key: &str, t: &Option<Transform>| {
        t.as_ref()
            .and_then(|t| match isometry(t.translation, t.rotation_xyzw) {
                Ok(iso) => Some(iso),
                Err(e) => {
                    problems.push(format!("calibration.{key}: {e}"));
                    None
                }
            })
    };
    if let Some(t) = transform("t_design_base", &c.t_design_base) {
        chain.t_design_base = t;
    }
    if let Some(t) = transform("t_flange_scanner", &c.t_flange_scanner) {
        chain.t_flange_scanner = t;
    }
    if let Some(q) = c.r_base_flange_xyzw {
        match isometry([0.0; 3], q) {
            Ok(iso) => chain.r_base_flange = iso.rotation,
            Err(e) => problems.push(format!("calibration.r_base_flange_xyzw: {e}")),
        }
    }
    chain
}

/// `[recorder]` and `[viewer]`: relative paths resolved against `base`, sizes and the viewer's
/// address checked.
fn check_outputs(
    recorder: &mut RecorderConfig,
    viewer: &mut ViewerConfig,
    base: &Path,
    problems: &mut Vec<String>,
) {
    if let Some(d) = &mut viewer.rrd
        && d.is_relative()
    {
        *d = base.join(&*d);
    }
    if let Some(u) = &viewer.url
        && !u.starts_with("rerun+http://")
        && !u.starts_with("rerun+https://")
    {
        problems.push(format!(
            "viewer.url: {u:?} is not a rerun address; give rerun+http://HOST:PORT/proxy"
        ));
    }
    if let Some(d) = &mut recorder.dir
        && d.is_relative()
    {
        *d = base.join(&*d);
    }
    for (key, v) in [
        ("max_file_mb", recorder.max_file_mb),
        ("min_free_mb", recorder.min_free_mb + 1.0),
        ("queue_mb", recorder.queue_mb),
    ] {
        if !positive(v) {
            problems.push(format!("recorder.{key}: give a positive number of MB"));
        }
    }
}

fn check_findings(f: &FindingsConfig, problems: &mut Vec<String>) {
    for (key, v) in [
        ("spacing", Some(f.spacing)),
        ("projection_diameter", f.projection_diameter),
        ("max_depth", f.max_depth),
        ("layer_height", f.layer_height),
        ("coverage_threshold", f.coverage_threshold),
    ] {
        if let Some(v) = v
            && !positive(v)
        {
            problems.push(format!(
                "findings.{key}: give a positive number of metres, got {v}"
            ));
        }
    }
    if let Some(step) = f.scanner_step_mrad
        && !(positive(step) && step < 100.0)
    {
        problems.push(format!(
            "findings.scanner_step_mrad: give the scanner's angular step in milliradians \
             (0 < step < 100), got {step}"
        ));
    }
    if !(0.0..=89.0).contains(&f.max_incidence_deg) {
        problems.push(format!(
            "findings.max_incidence_deg: {} is not an angle in [0, 89] degrees",
            f.max_incidence_deg
        ));
    }
}

fn positive(v: f64) -> bool {
    v > 0.0 && v.is_finite()
}

fn check_inspect(i: &InspectConfig, problems: &mut Vec<String>) {
    if i.methods.is_empty() {
        problems.push("inspect.methods: empty; give at least [\"c2m\"]".into());
    }
    for m in &i.methods {
        if !AVAILABLE_METHODS.contains(&m.as_str()) {
            problems.push(format!(
                "inspect.methods: {m:?} is not available in this build of the agent (available: \
                 {})",
                AVAILABLE_METHODS.join(", ")
            ));
        }
    }
    if !positive(i.tolerance) {
        problems.push(format!(
            "inspect.tolerance: {} is not a positive number of metres (5 mm is 0.005)",
            i.tolerance
        ));
    }
    if let Some(d) = i.max_distance
        && !positive(d)
    {
        problems.push(format!(
            "inspect.max_distance: {d} is not a positive number of metres"
        ));
    }
    if let Some(c) = i.cell_size
        && !positive(c)
    {
        problems.push(format!(
            "inspect.cell_size: {c} is not a positive number of metres; leave it out to let the \
             agent choose"
        ));
    }
    if !positive(i.max_range) {
        problems.push(format!(
            "inspect.max_range: {} is not a positive number of metres",
            i.max_range
        ));
    }
}

fn check_services(s: &ServicesConfig, problems: &mut Vec<String>) {
    let ok = !s.prefix.is_empty()
        && s.prefix.len() <= 200
        && !s.prefix.starts_with('/')
        && !s.prefix.ends_with('/')
        && s.prefix
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./".contains(c));
    if !ok {
        problems.push(format!(
            "services.prefix: {:?} is not a usable service prefix; use letters, digits and - _ . / \
             (not at either end), e.g. \"asbuilt/cell-1\"",
            s.prefix
        ));
    }
}

fn check_limits(l: &Limits, problems: &mut Vec<String>) {
    let mut range = |key: &str, v: usize, lo: usize, hi: usize| {
        if !(lo..=hi).contains(&v) {
            problems.push(format!("limits.{key}: {v} is outside {lo}..={hi}"));
        }
    };
    range("max_points_per_chunk", l.max_points_per_chunk, 1, 1 << 22);
    range("chunk_queue", l.chunk_queue, 1, 1024);
    range("pending_chunks", l.pending_chunks, 0, 1024);
    range("open_stations", l.open_stations, 1, 64);
    if !(l.station_timeout_s > 0.0 && l.station_timeout_s <= 86_400.0) {
        problems.push(format!(
            "limits.station_timeout_s: {} is not a timeout; give seconds in (0, 86400]",
            l.station_timeout_s
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<AgentConfig, ConfigError> {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("wall.stl"), b"solid x\nendsolid x\n").unwrap();
        AgentConfig::parse(text, dir.path(), Path::new("agent.toml"))
    }

    #[test]
    fn minimal_config_takes_the_defaults() {
        let c = parse("[design]\npath = \"wall.stl\"\nunits = \"mm\"\n").unwrap();
        assert_eq!(c.design.units(), Units::Millimetres);
        assert_eq!(c.inspect.methods, ["c2m"]);
        assert_eq!(c.inspect.max_distance(), 0.05);
        assert_eq!(c.services.prefix, "asbuilt");
        assert_eq!(c.frames, FrameChain::default());
    }

    #[test]
    fn every_problem_is_listed_with_its_key() {
        let err = parse(
            r#"
            [design]
            path = "missing.stl"
            units = "inches"
            [calibration]
            t_design_base = { translation = [0, 0, 0], rotation_xyzw = [0, 0, 0, 2] }
            [inspect]
            methods = ["c2m", "m3c2"]
            tolerance = -1
            [services]
            prefix = "/bad prefix"
            [limits]
            open_stations = 0
            station_timeout_s = 0
            [recorder]
            path = "x"
            [rerun]
            url = "x"
            "#,
        )
        .unwrap_err();
        let text = err.to_string();
        for key in [
            "design.path",
            "design.units",
            "calibration.t_design_base",
            "\"m3c2\" is not available",
            "inspect.tolerance",
            "services.prefix",
            "limits.open_stations",
            "limits.station_timeout_s",
            "[recorder]: unknown field `path`",
            "[rerun]: unknown section",
        ] {
            assert!(text.contains(key), "{key} missing from:\n{text}");
        }
        assert_eq!(err.problems.len(), 10, "{text}");
    }

    #[test]
    fn a_wrong_type_names_its_section_and_the_rest_is_still_checked() {
        let err = parse(
            "[design]\npath = \"wall.stl\"\nunits = \"m\"\n[limits]\nchunk_queue = \"many\"\n\
             [inspect]\ntolerance = 0\n",
        )
        .unwrap_err();
        assert!(err.problems[0].starts_with("[limits]"), "{err}");
        assert!(err.problems[1].starts_with("inspect.tolerance"), "{err}");
    }

    #[test]
    fn tolerances_default_to_the_inspection_tolerance_and_bad_ones_are_named() {
        let base = "[design]\npath = \"wall.stl\"\nunits = \"m\"\n[inspect]\ntolerance = 0.004\n";
        let c = parse(base).unwrap();
        let l = c.tolerances.limits(c.inspect.tolerance).unwrap();
        assert_eq!((l.width, l.surface, l.creep), (0.004, 0.004, 0.004));
        let c = parse(&format!(
            "{base}[tolerances]\nwidth = 0.008\nlayers = [\"width=12mm@2-4\"]\n"
        ))
        .unwrap();
        let l = c.tolerances.limits(c.inspect.tolerance).unwrap();
        assert_eq!(
            l.at_layer(asbuilt_core::verdict::LimitKind::Width, 3),
            0.012
        );
        let c = parse(&format!(
            "{base}[tolerances]\nflatness = \"din18202:6\"\ndimensions = \"din18202\"\n"
        ))
        .unwrap();
        assert_eq!(
            c.tolerances.flatness().unwrap(),
            Some(asbuilt_core::flatness::FlatnessStandard::Din18202 { row: 6 })
        );
        assert!(c.tolerances.dimensions().unwrap().is_some());
        assert_eq!(
            l.at_layer(asbuilt_core::verdict::LimitKind::Width, 5),
            0.008
        );
        for (bad, says) in [
            ("layers = [\"depth=1mm\"]", "unknown kind"),
            ("width = -0.001", "width limit must be positive"),
            ("warn_fraction = 2.0", "warn_fraction"),
            ("widht = 0.003", "widht"),
            ("flatness = \"din18202:9\"", "aci117:A"),
            ("dimensions = \"iso\"", "give din18202"),
        ] {
            let err = parse(&format!("{base}[tolerances]\n{bad}\n")).unwrap_err();
            assert!(format!("{err}").contains(says), "{bad}: {err}");
        }
    }

    #[test]
    fn missing_design_is_an_error() {
        let err = parse("[inspect]\ntolerance = 0.003\n").unwrap_err();
        assert!(err.problems[0].contains("[design]: missing"), "{err}");
    }
}
