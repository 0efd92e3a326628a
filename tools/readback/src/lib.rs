//! A recording read back: the job's design and settings from the recording itself, every
//! station fed through the agent's own lifecycle in the order the agent took its inputs, and
//! what that gives (report.json's content, each station's inputs and outputs). `asbuilt report`
//! writes it out; the Python package hands it to its caller.

use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::time::{Duration, Instant};

mod error;
pub mod files;
mod judging;

pub use error::ReadBackError;
pub use judging::Judging;

type Result<T, E = ReadBackError> = std::result::Result<T, E>;
use asbuilt_agent::findings::FindingsStage;
use asbuilt_agent::lifecycle::{Lifecycle, Outputs};
use asbuilt_core::frames::FrameChain;
use asbuilt_core::printed::PrintedDesigns;
use asbuilt_core::scan_layer::SampleState;
use asbuilt_core::station::{InspectParams, Tally};
use asbuilt_core::{C2mParams, Units};
use asbuilt_protocol::recording::{self, Recorded};
use asbuilt_protocol::{
    ChunkHeader, LayerCorrection, PointDeviation, PoseSnapshot, ScanPoint, StationEvent,
    StationEventKind, StationFindings, StationReport, StationStatus,
};
use asbuilt_report::flatness::FlatnessCollector;
use asbuilt_report::maps::{MapCollector, ScanLayerMaps};
use asbuilt_report::{DesignSection, Parameters, Report, Section};

/// What the station lifecycle hands out while a recording is read back: each station's
/// section, and every station's statistics merged.
struct Collected {
    /// Every station's inputs and outputs, for [`read_back`]; `None` for the command.
    kept: Option<BTreeMap<(u64, u32), Kept>>,
    /// Every station attempt's section, as reported.
    done: Vec<((u64, u32), Section)>,
    total: Tally,
    /// The tally of the station closing now, until its report says whether it counts.
    closing: Option<Tally>,
    /// Each station's tally, of its latest attempt that was not interrupted: a station counts
    /// once in the overall section, however often it was tried.
    tallies: BTreeMap<(u64, u32), Tally>,
    /// Station attempts reported interrupted: (job, station, attempt, name).
    interrupted: Vec<(u64, u32, u8, String)>,
    buffer: Vec<PointDeviation>,
    /// The latest findings of each scan layer (by job and printed height).
    findings: BTreeMap<(u64, u64), StationFindings>,
    /// The latest advice after each scan layer (by job and layer).
    corrections: BTreeMap<(u64, u32), LayerCorrection>,
    maps: MapCollector,
    /// The faces' points of the latest scan layer, with a flatness standard.
    flatness: Option<FlatnessCollector>,
    /// Each station's printed height, from its Begin (for the flatness).
    heights: BTreeMap<(u64, u32), f64>,
    /// Each station's scanner position, from its pose through the job's frames, and its pose
    /// σ (for the flatness).
    origins: BTreeMap<(u64, u32), (nalgebra::Point3<f64>, f64)>,
    frames: Option<FrameChain>,
}

impl Collected {
    fn new(stats: asbuilt_core::stats::StatsConfig, maps: MapCollector) -> Self {
        Self {
            kept: None,
            done: Vec::new(),
            total: Tally::new(stats),
            closing: None,
            tallies: BTreeMap::new(),
            interrupted: Vec::new(),
            buffer: Vec::new(),
            findings: BTreeMap::new(),
            corrections: BTreeMap::new(),
            maps,
            flatness: None,
            heights: BTreeMap::new(),
            origins: BTreeMap::new(),
            frames: None,
        }
    }
}

impl Collected {
    /// With [`read_back`], a station's recorded inputs: its Begin, pose and scan chunks.
    fn keep_input(&mut self, m: &Recorded) {
        if self.flatness.is_some() {
            match m {
                Recorded::Event(e) if e.kind() == Some(StationEventKind::Begin) => {
                    self.heights.insert((e.job, e.station), e.printed_height);
                }
                Recorded::Pose(p) => {
                    if let Some(t) = self
                        .frames
                        .as_ref()
                        .and_then(|f| f.t_design_scanner(p).ok())
                    {
                        let origin = nalgebra::Point3::from(t.translation.vector);
                        self.origins
                            .insert((p.job, p.station), (origin, p.position_sigma));
                    }
                }
                _ => {}
            }
        }
        let Some(k) = &mut self.kept else { return };
        match m {
            Recorded::Event(e) if e.kind() == Some(StationEventKind::Begin) => {
                k.entry((e.job, e.station)).or_default().begin = Some(*e);
            }
            Recorded::Pose(p) => k.entry((p.job, p.station)).or_default().pose = Some(*p),
            Recorded::Chunk(h, pts) => {
                let s = k.entry((h.job, h.station)).or_default();
                s.chunks.insert(h.sequence, pts.clone());
            }
            _ => {}
        }
    }
}

impl Outputs for Collected {
    fn deviations(
        &mut self,
        n: usize,
        fill: &mut dyn FnMut(&mut [PointDeviation]) -> asbuilt_protocol::DeviationHeader,
    ) {
        self.buffer.resize(n, PointDeviation::default());
        let h = fill(&mut self.buffer);
        self.maps.points((h.job, h.station), &self.buffer);
        if let Some(f) = &mut self.flatness {
            let key = (h.job, h.station);
            let height = self.heights.get(&key).copied().unwrap_or(f64::NAN);
            let seen = self.origins.get(&key).copied();
            let view = asbuilt_core::flatness::StationView {
                key,
                origin: seen.map(|s| s.0),
                position_sigma: seen.map_or(f64::NAN, |s| s.1),
            };
            f.points(h.job, height, &view, &self.buffer);
        }
        if let Some(k) = &mut self.kept {
            let s = k.entry((h.job, h.station)).or_default();
            s.deviations.insert(h.sequence, self.buffer.clone());
        }
    }

    fn tally(&mut self, tally: &Tally) {
        self.closing = Some(tally.clone());
    }

    fn report(&mut self, r: &StationReport) {
        let key = (r.job, r.station);
        let status = r.status();
        let closing = self.closing.take();
        if status == Some(StationStatus::Interrupted) {
            // Its next attempt sends the station again: what this one sent counts nowhere.
            self.maps.station_dropped(key);
            self.interrupted
                .push((r.job, r.station, r.attempt, r.name.as_str().to_string()));
        } else {
            self.maps.station_done(key, r.printed_height);
            if let Some(t) = closing {
                self.tallies.insert(key, t);
            }
        }
        if let Some(k) = &mut self.kept {
            k.entry(key).or_default().report = Some(*r);
        }
        let mut section = Section::from_report(r, None, 0);
        section.attempt = (r.attempt > 1).then_some(r.attempt);
        section.status = status
            .filter(|s| *s != StationStatus::Complete)
            .map(|s| format!("{s:?}"));
        self.done.push((key, section));
    }

    fn findings(&mut self, f: &StationFindings) {
        if let Some(k) = &mut self.kept {
            k.entry((f.job, f.station)).or_default().findings = Some(f.clone());
        }
        self.findings
            .insert((f.job, f.printed_height.to_bits()), f.clone());
    }

    fn correction(&mut self, c: &LayerCorrection) {
        self.corrections.insert((c.job, c.layer), *c);
    }

    fn samples(&mut self, f: &StationFindings, samples: &[SampleState]) {
        self.maps.samples(f.job, f.printed_height, samples);
    }
}

/// What the command line sets over the recording's configuration.
#[derive(Default)]
pub struct Overrides {
    /// The tolerance to judge with instead of the recorded one, metres.
    pub tolerance: Option<f64>,
    /// The maximum distance instead of the recorded one, metres.
    pub max_distance: Option<f64>,
    /// With a recording folder, the job to read instead of the newest.
    pub job: Option<u64>,
    /// Limits and standards instead of the recorded ones, and the maps as PNG files.
    pub judging: Judging,
}

/// One station of a recording as the report reads it back: what came in and what the agent's
/// lifecycle made of it.
#[derive(Default)]
pub struct StationReadBack {
    /// The job the station belongs to.
    pub job: u64,
    /// The station's number within the job.
    pub station: u32,
    /// The station's Begin as recorded (name, layer, printed height).
    pub begin: Option<StationEvent>,
    /// The pose the station's points were placed with (the last recorded).
    pub pose: Option<PoseSnapshot>,
    /// The recorded scan chunks, scanner frame, by sequence number.
    pub chunks: BTreeMap<u64, Vec<ScanPoint>>,
    /// The deviations of each inspected chunk, by sequence number: entry i is chunk point i's.
    pub deviations: BTreeMap<u64, Vec<PointDeviation>>,
    /// The agent's report of the station, as recorded.
    pub report: Option<StationReport>,
    /// The findings of the station's scan layer drawn after this station.
    pub findings: Option<StationFindings>,
}

type Kept = StationReadBack;

/// A recording read back as `asbuilt report` reads it: report.json's content and every station's
/// inputs and outputs, in (job, station) order.
pub fn read_back(
    recording_path: &std::path::Path,
    overrides: Overrides,
) -> Result<(Report, Vec<StationReadBack>)> {
    let files = files::job_files(&[recording_path.to_path_buf()], overrides.job)?;
    read(&files, overrides, true)
}

/// report.json's content for the job `recordings` name (one job's files in any order, or the
/// agent's folder), as `asbuilt report` draws it, without keeping any station's points; and
/// when the job started: the first station event's time in its first file (Unix ns), if any.
pub fn report(recordings: &[PathBuf], overrides: Overrides) -> Result<(Report, Option<u64>)> {
    let files = files::job_files(recordings, overrides.job)?;
    let (report, _) = read(&files, overrides, false)?;
    Ok((report, started_ns(&files[0])))
}

/// The time of the first station event of a recording, when it has one.
fn started_ns(path: &std::path::Path) -> Option<u64> {
    let bytes = files::map(path).ok()?;
    let mut events = recording::messages_on(&bytes, &[recording::Channel::StationEvents]).ok()?;
    events.find_map(|m| m.ok()).map(|(log_time, _)| log_time)
}

/// The job of `files` (oldest first), read back: its settings and design from the first file,
/// its stations from all of them in turn.
pub fn read(
    files: &[PathBuf],
    overrides: Overrides,
    keep: bool,
) -> Result<(Report, Vec<StationReadBack>)> {
    let first = &files[0];
    let bytes = files::map(first)?;
    let (job, designs) = RecordedJob::read(first, &bytes, overrides)?;
    same_design(files, &bytes)?;
    drop(bytes);
    let mut replayed = replay_stations(files, &job, designs, keep)?;
    let kept = std::mem::take(&mut replayed.kept);
    let stations = kept
        .into_iter()
        .map(|((job, station), mut s)| {
            s.job = job;
            s.station = station;
            s
        })
        .collect();
    Ok((job.report(replayed), stations))
}

/// What a recording says of its job: the design as attached, the agent's settings and limits
/// as recorded (or the defaults), and the tolerance and maximum distance to use.
struct RecordedJob {
    design_path: String,
    units: Units,
    /// The whole design and its index, for the report's design section.
    full: std::sync::Arc<asbuilt_core::printed::PrintedDesign>,
    frames: FrameChain,
    params: InspectParams,
    limits: asbuilt_agent::config::Limits,
    /// The agent's `[findings]` when it drew findings: the report draws them again.
    findings: Option<asbuilt_agent::config::FindingsConfig>,
    /// The agent's `[corrections]` when it advised: the report advises again.
    corrections: Option<asbuilt_agent::config::CorrectionsConfig>,
    /// The agent's `[profiler]`: its passes' profiles are placed again as it placed them.
    profiler: asbuilt_agent::config::ProfilerConfig,
    /// What the verdicts hold the findings to.
    verdict_limits: asbuilt_core::verdict::Limits,
    /// The standard the faces' flatness is judged by, if any.
    flatness: Option<asbuilt_core::flatness::FlatnessStandard>,
    /// The standard the dimensions and plumb are judged by, if any.
    dimensions: Option<asbuilt_core::flatness::DimensionsStandard>,
    /// How the standards' verdicts weigh the uncertainty.
    rule: asbuilt_core::verdict::DecisionRule,
    tolerance: f64,
    max_distance: f64,
}

impl RecordedJob {
    fn read(
        path: &std::path::Path,
        bytes: &[u8],
        overrides: Overrides,
    ) -> Result<(Self, PrintedDesigns)> {
        let bad = |e| ReadBackError::unreadable(path, e);
        let (meta, attachments) = recording::job(bytes).map_err(bad)?;
        let meta = meta.ok_or_else(|| ReadBackError::NotAsbuilt(path.to_path_buf()))?;
        let (name, design_bytes) = attachments
            .into_iter()
            .find(|(n, _)| n.starts_with(recording::ATTACHMENT_DESIGN))
            .ok_or_else(|| ReadBackError::NoDesign(path.to_path_buf()))?;
        // "m" or "mm"; older recordings wrote "Metres" or "Millimetres".
        let units: Units = meta
            .design_units
            .to_ascii_lowercase()
            .parse()
            .map_err(ReadBackError::Units)?;
        // The design as it was, read from the recording's bytes; its name gives the format.
        let design =
            asbuilt_io::read_design_bytes(&design_bytes, &name, units).map_err(|source| {
                ReadBackError::Design {
                    path: path.to_path_buf(),
                    source,
                }
            })?;
        let RecordedConfig {
            frames,
            settings,
            limits,
            findings,
            tolerances,
            corrections,
            profiler,
        } = RecordedConfig::read(&meta)?;
        let tolerance = overrides.tolerance.unwrap_or(settings.tolerance);
        let max_distance = overrides
            .max_distance
            .unwrap_or_else(|| settings.max_distance.unwrap_or(10.0 * tolerance));
        let mut verdict_limits = tolerances
            .limits_with(tolerance, &overrides.judging.limits)
            .map_err(|e| ReadBackError::Limits(e.to_string()))?;
        let recorded = |e: &dyn std::fmt::Display| ReadBackError::Tolerances(e.to_string());
        let flatness = match overrides.judging.flatness {
            Some(f) => Some(f),
            None => tolerances.flatness().map_err(|e| recorded(&e))?,
        };
        let dimensions = match overrides.judging.dimensions {
            Some(d) => Some(d),
            None => tolerances.dimensions().map_err(|e| recorded(&e))?,
        };
        let rule = match overrides.judging.decision_rule {
            Some(r) => r,
            None => tolerances.decision_rule().map_err(|e| recorded(&e))?,
        };
        verdict_limits.rule = rule;
        if !(tolerance > 0.0 && max_distance > 0.0) {
            return Err(ReadBackError::NotPositive);
        }
        // Stations scanned while printing were compared with the design as printed then.
        let designs = PrintedDesigns::new(
            design,
            C2mParams {
                max_distance,
                cell_size: settings.cell_size,
            },
        )?;
        let mut params = InspectParams::with_tolerance(tolerance);
        params.max_range = settings.max_range;
        let job = Self {
            design_path: meta.design_path,
            units,
            full: designs.full().clone(),
            frames,
            params,
            limits,
            findings,
            corrections,
            profiler,
            verdict_limits,
            flatness,
            dimensions,
            rule,
            tolerance,
            max_distance,
        };
        Ok((job, designs))
    }

    /// report.json's content: the stations as replayed, the agent's recorded findings.
    fn report(self, replayed: Replayed) -> Report {
        let ix = self.full.index.stats();
        let design = self.full.design();
        let mut warnings = design.report.warnings();
        if replayed.findings_differ {
            warnings.push(
                "the findings drawn from the recorded chunks differ from those the agent \
                 recorded: a --tolerance or --max-distance given here, or another asbuilt \
                 version than the agent's"
                    .to_string(),
            );
        }
        if replayed.corrections_differ {
            warnings.push(
                "the advice drawn again from the recorded chunks differs from the advice the \
                 agent recorded: a --tolerance or --max-distance given here, or another asbuilt \
                 version than the agent's"
                    .to_string(),
            );
        }
        warnings.extend(replayed.cut.iter().cloned());
        if !replayed.interrupted.is_empty() {
            let names: Vec<String> = replayed
                .interrupted
                .iter()
                .map(|(_, station, attempt, name)| {
                    let name = if name.is_empty() {
                        format!("station {station}")
                    } else {
                        name.clone()
                    };
                    format!("{name} attempt {attempt}")
                })
                .collect();
            warnings.push(format!(
                "{} station attempt(s) were interrupted (the agent stopped, or started while they \
                 were sending) and count nowhere; each station counts its latest attempt: {}",
                names.len(),
                names.join(", ")
            ));
        }
        if replayed.unfinished > 0 {
            warnings.push(format!(
                "{} station(s) have no end in the recording: reported as far as recorded",
                replayed.unfinished
            ));
        }
        let mut findings: Vec<_> = replayed.findings.into_values().collect();
        findings.sort_by_key(|a| (a.job, a.layer));
        let mut report = Report {
            asbuilt_version: env!("CARGO_PKG_VERSION"),
            design: DesignSection::new(
                self.design_path,
                self.units,
                (design.vertices.len(), design.triangles.len()),
                design.report.warnings(),
                &ix,
            ),
            parameters: Parameters {
                tolerance_m: self.tolerance,
                max_distance_m: self.max_distance,
                histogram_range_m: self.params.stats.histogram_range,
                spacing_m: 0.0,
                coverage_threshold_m: 0.0,
                coverage_spacing: String::new(),
                projection_diameter_m: 0.0,
                max_depth_m: 0.0,
                printed_height_m: None,
                layer_height_m: None,
                reference: None,
            },
            methods: vec!["c2m"],
            stations: replayed.stations,
            overall: Section::from_report(&replayed.total.report(0, u32::MAX, "overall"), None, 0),
            layers: None,
            m3c2_two_cloud: None,
            findings,
            corrections: replayed.corrections,
            flatness: replayed.judged.0,
            dimensions: replayed.judged.1,
            assessment: None,
            warnings,
            maps: replayed.maps,
        };
        report.assess(&self.verdict_limits);
        report
    }
}

/// A scan layer's key (job, printed height's bits): its latest findings cover all its stations.
fn scan_layer_of(f: &StationFindings) -> (u64, u64) {
    (f.job, f.printed_height.to_bits())
}

/// The stations as the agent's lifecycle gives them back from the recording.
struct Replayed {
    stations: Vec<Section>,
    total: Tally,
    /// The latest findings of each scan layer (by job and printed height).
    findings: BTreeMap<(u64, u64), StationFindings>,
    /// The findings drawn again differ from those the agent recorded.
    findings_differ: bool,
    /// The latest advice after each scan layer, drawn again.
    corrections: Vec<LayerCorrection>,
    /// The advice drawn again differs from what the agent recorded.
    corrections_differ: bool,
    /// The faces' flatness, and the dimensions and plumb, with their standards.
    judged: (
        Option<asbuilt_report::flatness::FlatnessSection>,
        Option<asbuilt_report::flatness::DimensionsSection>,
    ),
    unfinished: usize,
    /// Station attempts the agent reported interrupted: (job, station, attempt, name).
    interrupted: Vec<(u64, u32, u8, String)>,
    /// Files of the job read only as far as they go.
    cut: Vec<String>,
    maps: Vec<ScanLayerMaps>,
    kept: BTreeMap<(u64, u32), Kept>,
}

/// What an agent's configuration, recorded with its job, says; the defaults for a file another
/// writer made (`asbuilt pack`).
#[derive(Default)]
struct RecordedConfig {
    frames: FrameChain,
    settings: asbuilt_agent::config::InspectConfig,
    limits: asbuilt_agent::config::Limits,
    /// `[findings]`, when on.
    findings: Option<asbuilt_agent::config::FindingsConfig>,
    tolerances: asbuilt_agent::config::TolerancesConfig,
    /// `[corrections]`, when on.
    corrections: Option<asbuilt_agent::config::CorrectionsConfig>,
    /// `[profiler]`.
    profiler: asbuilt_agent::config::ProfilerConfig,
}

impl RecordedConfig {
    fn read(meta: &recording::JobMetadata) -> Result<Self> {
        use asbuilt_agent::config::{
            recorded_corrections, recorded_findings, recorded_limits, recorded_profiler,
            recorded_settings, recorded_tolerances,
        };
        if meta.writer != "asbuilt-agent" {
            return Ok(Self::default());
        }
        let problems = ReadBackError::Config;
        let (frames, settings) = recorded_settings(&meta.config).map_err(problems)?;
        let findings = recorded_findings(&meta.config).map_err(problems)?;
        let corrections = recorded_corrections(&meta.config).map_err(problems)?;
        Ok(Self {
            frames,
            settings,
            limits: recorded_limits(&meta.config).map_err(problems)?,
            findings: findings.enabled.then_some(findings),
            tolerances: recorded_tolerances(&meta.config).map_err(problems)?,
            corrections: corrections.enabled.then_some(corrections),
            profiler: recorded_profiler(&meta.config).map_err(problems)?,
        })
    }
}

/// Every file of a job was recorded against the design of the first: an agent started again
/// with another design file cannot go on with the same job.
fn same_design(files: &[PathBuf], first: &[u8]) -> Result<()> {
    let sha = |path: &std::path::Path, bytes: &[u8]| -> Result<String> {
        let (meta, _) = recording::job(bytes).map_err(|e| ReadBackError::unreadable(path, e))?;
        Ok(meta.map(|m| m.design_sha256).unwrap_or_default())
    };
    let expected = sha(&files[0], first)?;
    for f in &files[1..] {
        // A later file whose writer died is read as far as it goes (and said so) below.
        let Ok(found) = sha(f, &files::map(f)?) else {
            continue;
        };
        if found != expected {
            return Err(ReadBackError::OtherDesign {
                file: f.clone(),
                found,
                first: files[0].clone(),
                expected,
            });
        }
    }
    Ok(())
}

impl RecordedJob {
    /// The agent's station lifecycle with its settings and, when it drew findings, its
    /// findings stage as the agent ran it: the findings are drawn again from the recorded
    /// chunks, not copied from the recording.
    fn lifecycle(&self, designs: PrintedDesigns) -> Lifecycle<(ChunkHeader, Vec<ScanPoint>)> {
        let lifecycle = Lifecycle::new(
            designs,
            self.frames.clone(),
            self.params,
            asbuilt_agent::lifecycle::LifecycleLimits::from(&self.limits),
        )
        .with_profiler(self.profiler.clone());
        let lifecycle = match &self.findings {
            Some(f) => lifecycle.with_findings(
                FindingsStage::new(
                    f.clone(),
                    self.tolerance,
                    self.max_distance,
                    self.limits.max_points_per_chunk,
                )
                .judged_by(self.verdict_limits.clone())
                .keeping_samples(),
            ),
            None => lifecycle,
        };
        match &self.corrections {
            Some(c) => lifecycle.with_corrections(c.limits()),
            None => lifecycle,
        }
    }
}

/// Messages decoded ahead of the replay: enough to keep the decoder busy while a chunk is
/// measured, few enough that memory stays a few chunks' worth.
const DECODED_AHEAD: usize = 8;

/// Hands `each` the items of `items`, made on a thread of its own up to [`DECODED_AHEAD`]
/// ahead, until `each` breaks with what to return. Decoding a recording (chunks decompressed,
/// records parsed, points copied out) on the replay's own thread left both cores idle between
/// one chunk's parallel work and the next; on its own thread it overlaps that work.
fn read_ahead<T: Send>(
    items: impl Iterator<Item = T> + Send,
    mut each: impl FnMut(T) -> ControlFlow<Result<()>>,
) -> Result<()> {
    std::thread::scope(|scope| {
        let (ahead, rx) = std::sync::mpsc::sync_channel(DECODED_AHEAD);
        scope.spawn(move || {
            for item in items {
                // The reader stopped (an error, or a damaged file read as far as it goes).
                if ahead.send(item).is_err() {
                    break;
                }
            }
        });
        for item in rx {
            if let ControlFlow::Break(r) = each(item) {
                return r;
            }
        }
        Ok(())
    })
}

impl RecordedJob {
    /// What gathers the faces' points for the standards, if any are asked for: only those of
    /// the scan layer judged ([`judged_scan_layer`]).
    fn flatness_collector(&self, files: &[PathBuf]) -> Option<FlatnessCollector> {
        let f = FlatnessCollector::new(
            self.full.design(),
            self.flatness,
            self.dimensions,
            self.rule,
        )?;
        Some(match judged_scan_layer(files) {
            Some((job, height)) => f.only(job, height),
            None => f,
        })
    }
}

/// The scan layer the standards judge, from the station Begins alone (the scan chunks are
/// not decoded): the last job's latest, as [`FlatnessCollector`] keeps it, so that the points
/// of every earlier scan layer are never gathered. `None` when the files have no Begin or
/// cannot be read (the replay then says why).
fn judged_scan_layer(files: &[PathBuf]) -> Option<(u64, f64)> {
    let mut layer: Option<(u64, f64)> = None;
    for path in files {
        let bytes = files::map(path).ok()?;
        let events = recording::messages_on(&bytes, &[recording::Channel::StationEvents]).ok()?;
        for (_, m) in events.map_while(Result::ok) {
            let Recorded::Event(e) = m else { continue };
            if e.kind() != Some(StationEventKind::Begin) {
                continue;
            }
            let height = FlatnessCollector::height_of(e.printed_height);
            layer = match layer {
                Some((j, h)) if j == e.job && h >= height => Some((j, h)),
                _ => Some((e.job, height)),
            };
        }
    }
    layer
}

/// Findings or standards' judgements an older release recorded: the report draws them again
/// from the chunks, so they are left out, not the job. `Some` line for a file's warning (the
/// same for each of its messages, so that the report warns once a file): which messages, which
/// version, which this build writes; `None` for any other error.
fn older_note(e: &recording::ReadError) -> Option<String> {
    let recording::ReadError::Decode {
        topic,
        source:
            asbuilt_protocol::codec::DecodeError::VersionMismatch {
                message,
                found,
                expected,
                ..
            },
        ..
    } = e
    else {
        return None;
    };
    matches!(
        recording::Channel::from_topic(topic),
        Some(recording::Channel::Findings | recording::Channel::Surface)
    )
    .then(|| {
        format!(
            "its {message} on {topic} are version {found}, an older release's (this build \
             writes {expected}): the report draws them again from the chunks"
        )
    })
}

/// What the agent recorded of its own results while the files are fed, and what cut them short.
struct Fed {
    /// The latest findings of each scan layer, as recorded.
    findings: BTreeMap<(u64, u64), StationFindings>,
    /// The latest advice after each scan layer, as recorded.
    advice: BTreeMap<(u64, u32), LayerCorrection>,
    /// Files read only as far as they go, and why.
    cut: Vec<String>,
}

/// Feeds the files' inputs to `lifecycle` in the agent's order, on the recording's clock.
fn feed_files(
    files: &[PathBuf],
    lifecycle: &mut Lifecycle<(ChunkHeader, Vec<ScanPoint>)>,
    out: &mut Collected,
) -> Result<Fed> {
    let mut recorded = BTreeMap::new();
    let mut advised = BTreeMap::new();
    let mut first_time = None;
    let start = Instant::now();
    let mut cut = Vec::new();
    for path in files {
        let bytes = files::map(path)?;
        let bad = |e| ReadBackError::unreadable(path, e);
        let messages = recording::messages_in_agent_order(&bytes).map_err(bad)?;
        read_ahead(messages, |m| {
            // Of a job in several files, one whose writer died (an agent killed and not started
            // again, which would have recovered it) is read as far as it goes.
            let (log_time, m) = match m {
                Ok(m) => m,
                Err(e) if older_note(&e).is_some() => {
                    let note =
                        format!("{}: {}", path.display(), older_note(&e).unwrap_or_default());
                    (!cut.contains(&note)).then(|| cut.push(note));
                    return ControlFlow::Continue(());
                }
                Err(e) if files.len() > 1 => {
                    cut.push(format!(
                        "{} ends damaged ({e}): read as far as it goes; `asbuilt recover` \
                         rewrites it",
                        path.display()
                    ));
                    return ControlFlow::Break(Ok(()));
                }
                Err(e) => return ControlFlow::Break(Err(bad(e))),
            };
            // The recording's clock, so that a chunk's wait for its pose is measured as it was.
            let t0 = *first_time.get_or_insert(log_time);
            let now = start + Duration::from_nanos(log_time.saturating_sub(t0));
            out.keep_input(&m);
            match m {
                // The latest findings of each scan layer cover all its stations so far.
                Recorded::Findings(f) => {
                    recorded.insert(scan_layer_of(&f), *f);
                }
                Recorded::Correction(c) => {
                    advised.insert((c.job, c.layer), *c);
                }
                m => asbuilt_agent::replay::feed(lifecycle, m, now, out),
            }
            ControlFlow::Continue(())
        })?;
    }
    Ok(Fed {
        findings: recorded,
        advice: advised,
        cut,
    })
}

/// The agent's own station lifecycle, fed in the order the agent processed the inputs: a
/// recording read back gives what the live agent gave, whatever order its file holds. The
/// files of a job are read in turn, as the agents that wrote them took their inputs.
fn replay_stations(
    files: &[PathBuf],
    job: &RecordedJob,
    designs: PrintedDesigns,
    keep: bool,
) -> Result<Replayed> {
    let mut lifecycle = job.lifecycle(designs);
    let spacing = job
        .findings
        .as_ref()
        .map_or(asbuilt_core::scan_layer::defaults::SPACING, |f| f.spacing);
    let maps = MapCollector::new(job.full.design(), job.tolerance, spacing);
    let mut out = Collected::new(job.params.stats, maps);
    out.flatness = job.flatness_collector(files);
    out.frames = Some(job.frames.clone());
    if keep {
        out.kept = Some(BTreeMap::new());
    }
    let fed = feed_files(files, &mut lifecycle, &mut out)?;
    lifecycle.wait_designs(Instant::now(), &mut out);
    // The file is over: stations that said they were done close as the idle agent closes them,
    // the others (the agent stopped, a publisher died) as far as recorded.
    lifecycle.on_idle(
        Instant::now() + asbuilt_agent::lifecycle::END_GRACE,
        &mut out,
    );
    let unfinished = lifecycle.stations_open();
    lifecycle.shutdown(&mut out);
    let Collected {
        done,
        mut total,
        tallies,
        interrupted,
        findings: drawn,
        corrections: drawn_advice,
        maps,
        kept,
        flatness,
        ..
    } = out;
    // A station counts once: its latest attempt (attempts are reported in order).
    let done: BTreeMap<(u64, u32), Section> = done.into_iter().collect();
    for t in tallies.values() {
        total.merge(t);
    }
    if done.is_empty() {
        return Err(ReadBackError::NoStation(files[0].clone()));
    }
    let (findings, findings_differ) =
        drawn_or_recorded(job.findings.is_some(), drawn, fed.findings);
    let (corrections, corrections_differ) =
        drawn_or_recorded(job.corrections.is_some(), drawn_advice, fed.advice);
    Ok(Replayed {
        maps: maps.finish(),
        stations: done.into_values().collect(),
        total,
        findings,
        findings_differ,
        corrections: corrections.into_values().collect(),
        corrections_differ,
        judged: flatness.map(FlatnessCollector::finish).unwrap_or_default(),
        unfinished,
        interrupted,
        cut: fed.cut,
        kept: kept.unwrap_or_default(),
    })
}

/// What the lifecycle drew again when it `drew` (and whether it differs from what the agent
/// recorded), else what was recorded.
fn drawn_or_recorded<K: Ord, M: asbuilt_protocol::Message>(
    drew: bool,
    drawn: BTreeMap<K, M>,
    recorded: BTreeMap<K, M>,
) -> (BTreeMap<K, M>, bool) {
    if !drew {
        return (recorded, false);
    }
    // Bytes, not floats: NaN fields compare equal as bytes.
    let bytes = |m: &BTreeMap<K, M>| -> Vec<Vec<u8>> {
        m.values().map(asbuilt_protocol::codec::encode).collect()
    };
    let differ = bytes(&drawn) != bytes(&recorded);
    (drawn, differ)
}

#[cfg(test)]
mod tests {
    use super::*;
    use asbuilt_protocol::codec::DecodeError;

    fn mismatch(topic: &str) -> recording::ReadError {
        recording::ReadError::Decode {
            index: 40,
            topic: topic.into(),
            source: DecodeError::VersionMismatch {
                message: "asbuilt.StationFindings.v2",
                found: 1,
                expected: 2,
                oldest: 2,
            },
        }
    }

    /// An older release's findings are drawn again, one line a file; an older pose is not
    /// (the job cannot be replayed without it).
    #[test]
    fn older_findings_are_drawn_again_and_said_once() {
        let a = older_note(&mismatch("/agent/findings")).unwrap();
        assert_eq!(a, older_note(&mismatch("/agent/findings")).unwrap());
        assert!(
            a.contains("version 1") && a.contains("draws them again"),
            "{a}"
        );
        assert!(older_note(&mismatch("/agent/surface")).is_some());
        assert!(older_note(&mismatch("/robot/poses")).is_none());
    }
}
