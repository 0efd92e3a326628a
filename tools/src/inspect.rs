//! `asbuilt inspect`: offline inspection of scans with known poses against a design.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use asbuilt_core::station::{InspectParams, StationInspector, Tally};
use asbuilt_core::{C2mIndex, C2mParams, Design, Units};
use asbuilt_protocol::{DeviationFlags, PointDeviation};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Point3;

use asbuilt_io::DeviationsPly;
use asbuilt_io::scan::ScanFile;
use asbuilt_io::stations::{self, Station};
use asbuilt_report::flatness::FlatnessCollector;
use asbuilt_report::maps::MapCollector;
use asbuilt_report::suite::{self, Methods, Suite, SuiteConfig, SuiteOptions};
use asbuilt_report::{DesignSection, Report, Section, summary_table};
use asbuilt_viewer::{self as viewer, View, Viewer, ViewerParams};

/// Points per processing chunk. The per-point buffers are chunks, reused for every chunk: two
/// of deviations (one being measured, one being written), and the scan's chunks in flight from
/// the reader ([`READ_AHEAD`] + 2).
const CHUNK: usize = 1 << 16;
/// Chunks the reader thread parses ahead of the one being inspected.
const READ_AHEAD: usize = 2;

/// `asbuilt inspect`'s arguments. The command line fills them through clap; the Python package
/// fills the same fields from keywords, over [`InspectArgs::new`]'s defaults.
#[derive(Args)]
pub struct InspectArgs {
    /// The design model: STL (binary or ASCII), OBJ or PLY triangle mesh.
    #[arg(long)]
    pub design: PathBuf,
    /// Units the design file is written in (m or mm). Never guessed.
    #[arg(long)]
    pub units: Units,
    /// Stations file: [[station]] with id, scan, translation, rotation_xyzw. With --ros2, the
    /// clouds of each station: [[station]] with id, from and to (seconds of the bag's clock).
    #[arg(long, conflicts_with = "scan", required_unless_present_any = ["scan", "ros2"])]
    pub stations: Option<PathBuf>,
    /// A single scan file instead of a stations file: E57, LAS/LAZ, PTX, PLY or XYZ (metres).
    /// A file that holds poses (E57, PTX, LAS) needs no --translation/--rotation-xyzw; every
    /// scan in it becomes a station.
    #[arg(long, conflicts_with = "ros2")]
    pub scan: Option<PathBuf>,
    /// A ROS 2 bag as the scans.
    #[command(flatten)]
    pub ros2: crate::ros2_args::Ros2Args,
    /// With --scan: x,y,z of the scanner in the design frame, metres.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub translation: Option<Vec<f64>>,
    /// With --scan: the scanner's rotation as a unit quaternion x,y,z,w.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub rotation_xyzw: Option<Vec<f64>>,
    /// Tolerance band, metres: |d| <= tolerance is within tolerance.
    #[arg(long, default_value_t = DEFAULT_TOLERANCE)]
    pub tolerance: f64,
    /// Verdict limits, standards and the maps as PNG files.
    #[command(flatten)]
    pub judging: asbuilt_readback::Judging,
    /// Points farther than this from the design have no match (flagged, never clamped).
    /// Metres; default 10 × tolerance.
    #[arg(long)]
    pub max_distance: Option<f64>,
    /// Output folder for report.json, deviations.ply, and with coverage or M3C2, missing.ply
    /// and m3c2.ply.
    #[arg(long, default_value = DEFAULT_OUT)]
    pub out: PathBuf,
    /// Comparisons to run: any of c2m, c2c, coverage, m3c2 (comma-separated), or all. C2M
    /// always runs: it places and validates every point.
    #[arg(long, default_value = DEFAULT_METHODS, value_parser = suite::parse_methods)]
    pub method: Methods,
    /// Design sampling for coverage, M3C2 core points and C2C without a reference, metres.
    /// Default 0.01, as the agent's [findings].
    #[arg(long, default_value_t = asbuilt_core::scan_layer::defaults::SPACING)]
    pub spacing: f64,
    /// M3C2 cylinder diameter, metres. Default, as the agent's: twice the spacing, at most half
    /// the layer height.
    #[arg(long)]
    pub projection_diameter: Option<f64>,
    /// M3C2 cylinder half-length: the largest deviation it can measure. Metres; default the
    /// maximum distance.
    #[arg(long)]
    pub max_depth: Option<f64>,
    /// Normal scale (diameter) for two-cloud M3C2 against --reference. Metres; default the
    /// projection diameter.
    #[arg(long)]
    pub normal_diameter: Option<f64>,
    /// A design sample with no scan point this close, that a station should have seen, is
    /// missing. Metres; default 3 × the default pose σ (1 mm), at least the tolerance / 2,
    /// raised to the scan's point spacing where that is wider (measured per station, or from
    /// --scanner-step). Given here, it is used as it is.
    #[arg(long)]
    pub coverage_threshold: Option<f64>,
    /// The scanner's angular step, milliradians (0.31 for a Z+F IMAGER at "high"): coverage
    /// expects points step × range apart instead of measuring the spacing.
    #[arg(long)]
    pub scanner_step_mrad: Option<f64>,
    /// Compare with the design as printed so far: cut at this height (design frame z,
    /// metres) and capped. Points above it count as excess.
    #[arg(long)]
    pub printed_height: Option<f64>,
    /// Statistics per layer band of this height (metres), from the design's lowest point.
    #[arg(long)]
    pub layer_height: Option<f64>,
    /// A reference cloud in the design frame (PLY, LAS, XYZ; metres) for C2C and two-cloud
    /// M3C2. Without it C2C measures to design samples.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Write the rerun view to this .rrd file (`rerun FILE.rrd` opens it).
    #[arg(long)]
    pub rerun: Option<PathBuf>,
    /// Stream the rerun view to a viewer: rerun+http://HOST:PORT/proxy.
    #[arg(long)]
    pub rerun_url: Option<String>,
    /// Points shown per station in the rerun view, at most (decimated evenly).
    #[arg(long, default_value_t = DEFAULT_RERUN_POINTS)]
    pub rerun_points: usize,
    /// Also write deviations.txt: the same points as ASCII with a header line.
    #[arg(long)]
    pub ascii: bool,
    /// Leave the deviation maps out of report.html. On 2 M shuffled bunny points they take
    /// about 5 % of inspect's time (tools/bench/maps_cost.sh).
    #[arg(long, conflicts_with = "png")]
    pub no_maps: bool,
    /// C2C local model: a least-squares plane through this many nearest reference points (the
    /// smaller of the plane and nearest-point distances is kept). 0 for nearest point only.
    /// Default 6 against design samples, 0 against --reference.
    #[arg(long)]
    pub local_plane: Option<usize>,
}

/// `--tolerance` unless given, metres.
pub const DEFAULT_TOLERANCE: f64 = 0.005;
/// `--out` unless given.
pub const DEFAULT_OUT: &str = "out/inspect";
/// `--method` unless given.
pub const DEFAULT_METHODS: &str = "c2m";
/// `--rerun-points` unless given.
pub const DEFAULT_RERUN_POINTS: usize = 200_000;

impl InspectArgs {
    /// `design` in `units` with every other argument at the command line's default (a
    /// stations file or a scan still to name).
    pub fn new(design: PathBuf, units: Units) -> Self {
        Self {
            design,
            units,
            stations: None,
            scan: None,
            ros2: Default::default(),
            translation: None,
            rotation_xyzw: None,
            tolerance: DEFAULT_TOLERANCE,
            judging: Default::default(),
            max_distance: None,
            out: DEFAULT_OUT.into(),
            method: suite::parse_methods(DEFAULT_METHODS).expect("the default methods parse"),
            spacing: asbuilt_core::scan_layer::defaults::SPACING,
            projection_diameter: None,
            max_depth: None,
            normal_diameter: None,
            coverage_threshold: None,
            scanner_step_mrad: None,
            printed_height: None,
            layer_height: None,
            reference: None,
            rerun: None,
            rerun_url: None,
            rerun_points: DEFAULT_RERUN_POINTS,
            ascii: false,
            no_maps: false,
            local_plane: None,
        }
    }
}

/// `asbuilt inspect`: the arguments checked into a plan, then the job's steps in order.
pub fn run(args: InspectArgs) -> Result<ExitCode> {
    let plan = Plan::check(args)?;
    let started = Instant::now();
    let (design, mut warnings) = load_design(&plan.args)?;
    let mut job = Job::start(&plan, design, started)?;
    for (n, station) in plan.stations.iter().enumerate() {
        job.station(&plan, n, station, &mut warnings);
    }
    let (report, written, failed) = job.finish(&plan, warnings)?;
    write_report(&plan, &report, written, &failed, started)
}

/// What the arguments ask for, checked, with the defaults that depend on each other resolved.
struct Plan {
    args: InspectArgs,
    /// The verdicts' limits: --tolerance for every kind, then each --limit.
    limits: asbuilt_core::verdict::Limits,
    /// The methods and their parameters, defaults resolved as the Python package resolves them.
    suite: SuiteConfig,
    stations: Vec<Station>,
}

impl Plan {
    fn check(args: InspectArgs) -> Result<Self> {
        let suite = SuiteOptions {
            methods: args.method.0.clone(),
            tolerance: args.tolerance,
            max_distance: args.max_distance,
            spacing: args.spacing,
            projection_diameter: args.projection_diameter,
            max_depth: args.max_depth,
            normal_diameter: args.normal_diameter,
            coverage_threshold: args.coverage_threshold,
            scanner_step_mrad: args.scanner_step_mrad,
            layer_height: args.layer_height,
            printed_height: args.printed_height,
            reference: args.reference.clone(),
            local_plane: args.local_plane,
        }
        .resolve()?;
        let bag = args.ros2.stations(args.stations.as_deref())?;
        let stations = match (&args.stations, &args.scan) {
            _ if bag.is_some() => bag.expect("checked"),
            (Some(_), Some(_)) => bail!("give --stations FILE or --scan FILE, not both"),
            (Some(path), None) => stations::load(path)?,
            (None, Some(scan)) => single_station(&args, scan)?,
            (None, None) => bail!("give --stations FILE, --scan FILE or --ros2 BAG"),
        };
        if args.no_maps && args.judging.png {
            bail!("--png writes the maps that --no-maps leaves out: give one of them");
        }
        let mut limits = asbuilt_core::verdict::Limits::from_tolerance(args.tolerance);
        limits.rule = args.judging.decision_rule.unwrap_or_default();
        for l in &args.judging.limits {
            limits.set(*l);
        }
        limits
            .check()
            .map_err(|e| anyhow::anyhow!("--limit: {e}"))?;
        Ok(Self {
            limits,
            suite,
            stations,
            args,
        })
    }
}

/// The design as compared with: the whole model, or with --printed-height the part cut there
/// and capped. Warnings about the cut are returned for the report.
fn load_design(args: &InspectArgs) -> Result<(LoadedDesign, Vec<String>)> {
    let full = asbuilt_io::read_design(&args.design, args.units)?;
    let mut warnings = Vec::new();
    let design_warnings = full.report.warnings();
    for w in &design_warnings {
        eprintln!("warning: design: {w}");
    }
    let design = match args.printed_height {
        Some(h) => {
            let (cut, report) =
                asbuilt_core::layers::cut_at(&full, h).context("--printed-height")?;
            eprintln!(
                "design cut at {h} m: {} triangles, cap of {} triangles over {} outlines",
                cut.triangles.len(),
                report.cap_triangles,
                report.loops
            );
            if report.open_chains > 0 {
                let w = format!(
                    "the cut at {h} m crosses {} open outline(s) of the design (it has holes): \
                     those are not capped, so points on the printed top there measure to the walls",
                    report.open_chains
                );
                eprintln!("warning: {w}");
                warnings.push(w);
            }
            cut
        }
        None => full,
    };
    Ok((
        LoadedDesign {
            design,
            warnings: design_warnings,
        },
        warnings,
    ))
}

struct LoadedDesign {
    design: Design,
    warnings: Vec<String>,
}

/// What the report says of the design, kept once the index has taken the design over.
struct DesignFacts {
    section: DesignSection,
    lowest: f64,
    size: f64,
}

/// The job under way: the index, the methods beside C2M, the outputs, and what the stations
/// have given so far.
struct Job {
    index: C2mIndex,
    facts: DesignFacts,
    suite: Suite,
    viewer: Option<Viewer>,
    ply: DeviationsPly,
    params: InspectParams,
    sections: Vec<Section>,
    total: Tally,
    total_malformed: u64,
    failed: Vec<String>,
    buffer: Vec<PointDeviation>,
    /// The deviation maps of report.html (one scan layer: the job's printed height).
    maps: MapCollector,
    /// The faces' points for the straightedge, with --flatness.
    flatness: Option<FlatnessCollector>,
    /// --printed-height; NaN without.
    printed_height: f64,
}

impl Job {
    fn start(plan: &Plan, loaded: LoadedDesign, started: Instant) -> Result<Self> {
        let args = &plan.args;
        let LoadedDesign { design, warnings } = loaded;
        std::fs::create_dir_all(&args.out)
            .with_context(|| format!("cannot create output folder {}", args.out.display()))?;
        let ply = DeviationsPly::create(&args.out.join("deviations.ply"), args.ascii)?;
        let (lo, hi) = design.bounds();
        let suite = Suite::new(&design, plan.suite.clone())?;
        let viewer = start_viewer(args, &plan.limits, &design)?;
        // The design's counts are all the report needs of it from here: the index takes it over.
        let counts = (design.vertices.len(), design.triangles.len());
        let maps = MapCollector::new(&design, args.tolerance, args.spacing);
        let maps = if args.no_maps { maps.off() } else { maps };
        let flatness =
            FlatnessCollector::new(&design, args.judging.flatness, args.judging.dimensions, {
                args.judging.decision_rule.unwrap_or_default()
            });
        let index = C2mIndex::from_design(design, C2mParams::within(plan.suite.reach))?;
        let ix = index.stats();
        eprintln!(
            "design {}: {} triangles, index {} cells of {:.2} mm, {:.0} MB, built in {:.1} s",
            args.design.display(),
            ix.triangles,
            ix.cells,
            ix.cell_size * 1e3,
            ix.bytes as f64 / 1e6,
            started.elapsed().as_secs_f64()
        );
        let params = InspectParams::with_tolerance(args.tolerance);
        Ok(Self {
            index,
            facts: DesignFacts {
                section: DesignSection::new(
                    args.design.display().to_string(),
                    args.units,
                    counts,
                    warnings,
                    &ix,
                ),
                lowest: lo.z,
                size: (hi - lo).norm(),
            },
            suite,
            viewer,
            ply,
            total: Tally::new(params.stats),
            params,
            sections: Vec::new(),
            total_malformed: 0,
            failed: Vec::new(),
            buffer: vec![PointDeviation::default(); CHUNK],
            maps,
            flatness,
            printed_height: args.printed_height.unwrap_or(f64::NAN),
        })
    }

    /// A station whose scan cannot be read: said, counted as failed, and named in the report's
    /// warnings, so that a reader of report.json knows what was not judged.
    fn not_inspected(&mut self, station: &Station, why: &str, warnings: &mut Vec<String>) {
        eprintln!("error: station {}: {why}", station.id);
        warnings.push(format!("station {} was not inspected: {why}", station.id));
        self.failed.push(station.id.clone());
    }

    /// Inspects station `n`; a station whose scan cannot be read is counted as failed and the
    /// job goes on.
    fn station(&mut self, plan: &Plan, n: usize, station: &Station, warnings: &mut Vec<String>) {
        let t0 = Instant::now();
        let file = match station.open_scan() {
            Ok(f) => f,
            Err(e) => {
                self.not_inspected(station, &crate::error_message(&e), warnings);
                return;
            }
        };
        eprintln!("station {}: pose from {}", station.id, station.pose_source);
        let mut inspector =
            StationInspector::new(&self.index, station.t_design_scanner, self.params);
        self.suite.begin_station();
        if let Some(v) = &self.viewer {
            v.show(View::Station {
                index: n as u32,
                name: station.id.clone(),
                layer: 0,
                pose: station.t_design_scanner,
                time_ns: asbuilt_protocol::unix_time_ns(),
            });
        }
        let read = stream_station(
            &file,
            station,
            n,
            plan.args.rerun_points,
            &mut inspector,
            StationOutputs {
                buffer: &mut self.buffer,
                ply: &mut self.ply,
                suite: &mut self.suite,
                maps: &mut self.maps,
                flatness: self.flatness.as_mut(),
                viewer: self.viewer.as_ref(),
            },
        );
        let (notes, bounds) = match read {
            Ok(r) => r,
            Err(e) => {
                self.not_inspected(station, &crate::error_message(e.as_ref()), warnings);
                return;
            }
        };
        if notes.malformed_lines > 0 {
            let w = format!(
                "station {}: {} unreadable lines skipped (first at line {})",
                station.id,
                notes.malformed_lines,
                notes.first_malformed_line.unwrap_or(0)
            );
            eprintln!("warning: {w}");
            warnings.push(w);
        }
        if let Some(w) = station.size_mismatch(self.facts.size, bounds) {
            eprintln!("warning: {w}");
            warnings.push(w);
        }
        let mut report = inspector.report(0, n as u32, &station.id);
        report.position_sigma = station.position_sigma;
        self.total.merge(inspector.tally());
        self.close_station(n, station, report, notes.malformed_lines, t0);
    }

    /// The station's report to the view and its section, with the methods beside C2M.
    fn close_station(
        &mut self,
        n: usize,
        station: &Station,
        report: asbuilt_protocol::StationReport,
        malformed: u64,
        t0: Instant,
    ) {
        if let Some(v) = &self.viewer {
            v.show(View::Report {
                index: n as u32,
                name: station.id.clone(),
                report: Box::new(report),
            });
        }
        self.total_malformed += malformed;
        self.maps.station_done((0, n as u32), self.printed_height);
        let mut section =
            Section::from_report(&report, Some(station.scan.display().to_string()), malformed);
        section.suite = self.suite.end_station(
            Point3::from(station.t_design_scanner.translation.vector),
            station.position_sigma,
            &self.index,
        );
        eprintln!(
            "station {:<10} {:>8} points  median |d| {} mm  ({:.2} s)",
            station.id,
            section.points,
            asbuilt_report::mm(section.distances.median_abs, "-"),
            t0.elapsed().as_secs_f64()
        );
        let extra = section.suite.methods_line();
        if !extra.is_empty() {
            eprintln!("        {:<10} {extra}", "");
        }
        self.sections.push(section);
    }

    /// Closes the outputs and puts the report together; returns it with the points written and
    /// the stations that could not be read.
    fn finish(self, plan: &Plan, mut warnings: Vec<String>) -> Result<(Report, u64, Vec<String>)> {
        let args = &plan.args;
        // Closing deviations.ply flushes its last block and renames it over the old one, which
        // on ext4 waits for the new file's blocks (29 to 34 ms of the bunny M3C2 job's 1 s): on
        // a thread of its own, beside the suite's closing sums and files.
        let (written, totals) = std::thread::scope(|scope| {
            let ply = scope.spawn(move || self.ply.finish());
            let totals = self.suite.finish(&self.index, &args.out);
            let written = ply
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            (written, totals)
        });
        let (written, mut totals) = (written?, totals?);
        let findings: Vec<_> = totals
            .findings
            .take()
            .map(|(f, stations)| findings_message(plan, self.facts.lowest, &f, stations))
            .into_iter()
            .collect();
        if let Some(v) = self.viewer {
            finish_viewer(v, &totals, &findings, args);
        }
        let mut maps = self.maps;
        if !totals.samples.is_empty() {
            maps.samples(0, self.printed_height, &totals.samples);
        }
        let mut overall = Section::from_report(
            &self.total.report(0, u32::MAX, "overall"),
            None,
            self.total_malformed,
        );
        overall.suite = totals.section;
        if overall.distances.matched == 0 {
            warnings.push(format!(
                "no point matched the design within {} m: check the poses, --units and \
                 --max-distance",
                plan.suite.reach
            ));
        }
        let (flatness, dimensions) = self
            .flatness
            .map(FlatnessCollector::finish)
            .unwrap_or_default();
        let mut report = Report {
            asbuilt_version: env!("CARGO_PKG_VERSION"),
            design: self.facts.section,
            parameters: plan.suite.parameters(self.params.stats.histogram_range),
            methods: plan.suite.methods.iter().map(|m| m.name()).collect(),
            stations: self.sections,
            overall,
            layers: totals.layers,
            m3c2_two_cloud: totals.m3c2_two_cloud,
            findings,
            corrections: Vec::new(),
            flatness,
            dimensions,
            assessment: None,
            warnings,
            maps: maps.finish(),
        };
        report.assess(&plan.limits);
        Ok((report, written, self.failed))
    }
}

/// The lowest and highest corner of the points that reached the design frame.
type Bounds = (Point3<f64>, Point3<f64>);

/// Where a station's deviations go besides the statistics.
struct StationOutputs<'a> {
    buffer: &'a mut Vec<PointDeviation>,
    ply: &'a mut DeviationsPly,
    suite: &'a mut Suite,
    maps: &'a mut MapCollector,
    flatness: Option<&'a mut FlatnessCollector>,
    viewer: Option<&'a Viewer>,
}

/// Streams station `n`'s scan through its inspector into the outputs, with a progress bar.
/// Returns what the reader noted and the bounds of the points that reached the design frame.
///
/// Three stages run at once: the reader parses chunks ahead, the inspector measures one chunk
/// on every core, and the output stage writes the chunk before (deviations.ply, the suite, the
/// maps, the viewer) on a thread of its own, so the cores are not left idle while a chunk is
/// written. The outputs see the chunks in file order, as before; two deviation buffers go
/// back and forth between the inspector and the output stage.
fn stream_station(
    file: &ScanFile,
    station: &Station,
    n: usize,
    rerun_points: usize,
    inspector: &mut StationInspector<&C2mIndex>,
    out: StationOutputs<'_>,
) -> Result<(asbuilt_io::ReadNotes, Bounds)> {
    let declared = file.scans[station.scan_index].points;
    let bar = progress_bar(declared, &station.id);
    let StationOutputs {
        buffer,
        ply,
        suite,
        maps,
        flatness,
        viewer,
    } = out;
    let stage = OutputStage {
        ply,
        suite,
        maps,
        flatness,
        viewer,
        origin: Point3::from(station.t_design_scanner.translation.vector),
        position_sigma: station.position_sigma,
        station: n,
        name: &station.id,
        view_step: viewer::stride(declared.unwrap_or(1_000_000) as usize, rerun_points),
        bar: &bar,
    };
    let (full_tx, full_rx) = std::sync::mpsc::sync_channel::<Vec<PointDeviation>>(1);
    let (empty_tx, empty_rx) = std::sync::mpsc::channel::<Vec<PointDeviation>>();
    for b in [std::mem::take(buffer), Vec::with_capacity(CHUNK)] {
        empty_tx.send(b).expect("the receiver is here");
    }
    let (read, written) = std::thread::scope(|scope| {
        let writer = scope.spawn(move || stage.run(full_rx, empty_tx));
        let read = file.stream_ahead(station.scan_index, CHUNK, READ_AHEAD, &mut |chunk| {
            // Gone only when the output stage failed; its error is the one reported.
            let stopped = || anyhow::anyhow!("the output stage stopped");
            let mut devs = empty_rx.recv().map_err(|_| stopped())?;
            // Every deviation is written by the inspector: only a longer chunk adds any.
            devs.resize(chunk.len(), PointDeviation::default());
            inspector.process(chunk, &mut devs);
            Ok(full_tx.send(devs).map_err(|_| stopped())?)
        });
        drop(full_tx);
        let written = writer.join();
        (read, written)
    });
    bar.finish_and_clear();
    let bounds = match written {
        Ok(w) => w?,
        Err(panic) => std::panic::resume_unwind(panic),
    };
    // A buffer the next station can use without allocating again.
    *buffer = empty_rx.try_iter().last().unwrap_or_default();
    Ok((read?, bounds))
}

/// The outputs of a station's deviations, fed chunk by chunk on a thread of their own.
struct OutputStage<'a> {
    ply: &'a mut DeviationsPly,
    suite: &'a mut Suite,
    maps: &'a mut MapCollector,
    flatness: Option<&'a mut FlatnessCollector>,
    viewer: Option<&'a Viewer>,
    /// The scanner's position, design frame.
    origin: Point3<f64>,
    /// The station's pose σ per axis, metres.
    position_sigma: f64,
    station: usize,
    name: &'a str,
    view_step: usize,
    bar: &'a ProgressBar,
}

impl OutputStage<'_> {
    /// Writes every chunk that comes on `full` and hands its buffer back on `empty`; returns
    /// the bounds of the points that reached the design frame.
    fn run(
        mut self,
        full: std::sync::mpsc::Receiver<Vec<PointDeviation>>,
        empty: std::sync::mpsc::Sender<Vec<PointDeviation>>,
    ) -> Result<Bounds> {
        let n = self.station;
        let mut bounds = (
            Point3::from([f64::INFINITY; 3]),
            Point3::from([f64::NEG_INFINITY; 3]),
        );
        for (part, devs) in full.into_iter().enumerate() {
            for d in devs
                .iter()
                .filter(|d| !d.flags.contains(DeviationFlags::REJECTED))
            {
                let p = Point3::from(d.position);
                bounds = (bounds.0.inf(&p), bounds.1.sup(&p));
            }
            self.ply.write(n as u16, &devs)?;
            self.suite.chunk(&devs);
            self.maps.points((0, n as u32), &devs);
            if let Some(f) = self.flatness.as_deref_mut() {
                // One scan set: every station is the same scan layer.
                let view = asbuilt_core::flatness::StationView {
                    key: (0, n as u32),
                    origin: Some(self.origin),
                    position_sigma: self.position_sigma,
                };
                f.points(0, f64::NAN, &view, &devs);
            }
            if let Some(v) = self.viewer {
                let (positions, distances) = viewer::decimate(&devs, self.view_step);
                v.show(View::Points {
                    index: n as u32,
                    name: self.name.to_string(),
                    part: part as u32,
                    positions,
                    distances,
                });
            }
            self.bar.inc(devs.len() as u64);
            // The receiver outlives this stage.
            let _ = empty.send(devs);
        }
        Ok(bounds)
    }
}

fn progress_bar(declared: Option<u64>, name: &str) -> ProgressBar {
    let bar = match declared {
        Some(n) => ProgressBar::new(n).with_style(
            ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} points ({per_sec})")
                .expect("valid template")
                .progress_chars("=> "),
        ),
        None => ProgressBar::no_length().with_style(
            ProgressStyle::with_template("{msg:>12} {spinner} {pos} points ({per_sec})")
                .expect("valid template"),
        ),
    };
    bar.set_message(name.to_string());
    bar
}

fn start_viewer(
    args: &InspectArgs,
    limits: &asbuilt_core::verdict::Limits,
    design: &Design,
) -> Result<Option<Viewer>> {
    if args.rerun.is_none() && args.rerun_url.is_none() {
        return Ok(None);
    }
    let v = Viewer::start(ViewerParams {
        rrd: args.rerun.clone(),
        footer: true,
        url: args.rerun_url.clone(),
        max_points_per_station: args.rerun_points,
        // Offline nothing waits on the view: a deep queue keeps every item.
        queue: 4096,
        tolerance: args.tolerance,
        warn: |args| eprintln!("warning: {args}"),
        job: asbuilt_viewer::Job::Survey {
            layer_bands: args.layer_height.is_some(),
        },
        limits: Some(limits.clone()),
    })?;
    v.show(View::Design {
        vertices: design.vertices.clone(),
        triangles: design.triangles.clone(),
    });
    Ok(Some(v))
}

/// The job's findings, drawn as the agent draws a scan layer's: offline there is one.
fn findings_message(
    plan: &Plan,
    lowest: f64,
    f: &asbuilt_core::findings::Findings,
    stations: u32,
) -> asbuilt_protocol::StationFindings {
    eprintln!(
        "findings: {} region(s) out of tolerance, {} missing area(s){}",
        f.regions.len(),
        f.missing.len(),
        if f.layers.is_empty() {
            ""
        } else {
            ", a row per layer band"
        }
    );
    let args = &plan.args;
    suite::findings_message(
        f,
        stations,
        (args.tolerance, &plan.limits),
        (args.printed_height, args.layer_height),
        lowest,
    )
}

/// The job-level layers of the view, then the view closed.
fn finish_viewer(
    mut v: Viewer,
    totals: &asbuilt_report::SuiteTotals,
    findings: &[asbuilt_protocol::StationFindings],
    args: &InspectArgs,
) {
    v.show_totals(totals, findings);
    v.finish();
    if let Some(p) = &args.rerun {
        eprintln!(
            "wrote {} (open it with `rerun {}`)",
            p.display(),
            p.display()
        );
    }
}

/// report.json and the summary table; the exit code says whether every station was read and
/// anything matched.
fn write_report(
    plan: &Plan,
    report: &Report,
    written: u64,
    failed: &[String],
    started: Instant,
) -> Result<ExitCode> {
    let args = &plan.args;
    let json_path = args.out.join("report.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(report)?)
        .with_context(|| format!("cannot write {}", json_path.display()))?;
    let html_path = args.out.join("report.html");
    let source = format!("Inspection of {} station(s)", report.stations.len());
    std::fs::write(&html_path, asbuilt_report::html::page(report, &source))
        .with_context(|| format!("cannot write {}", html_path.display()))?;

    print!("{}", summary_table(report));
    print!("{}", asbuilt_report::verdict_text(report));
    if args.judging.png {
        crate::maps_png::write(report, &args.out)?;
    }
    eprintln!(
        "wrote {}, {} and {} ({} points) in {:.1} s",
        json_path.display(),
        html_path.display(),
        args.out.join("deviations.ply").display(),
        written,
        started.elapsed().as_secs_f64()
    );
    if !failed.is_empty() {
        eprintln!(
            "error: {} station(s) could not be read: {}",
            failed.len(),
            failed.join(", ")
        );
        return Ok(ExitCode::from(1));
    }
    if report.overall.distances.matched == 0 {
        eprintln!("error: {}", report.warnings.last().expect("pushed above"));
        return Ok(ExitCode::from(1));
    }
    Ok(ExitCode::SUCCESS)
}

/// The stations of --scan, at the pose of --translation and --rotation-xyzw when given.
fn single_station(args: &InspectArgs, scan: &std::path::Path) -> Result<Vec<Station>> {
    let pose = match (args.translation.as_deref(), args.rotation_xyzw.as_deref()) {
        (None, None) => None,
        (Some(&[x, y, z]), Some(&[i, j, k, w])) => Some(([x, y, z], [i, j, k, w])),
        (Some(t), Some(r)) => bail!(
            "--translation takes three numbers x,y,z (metres) and --rotation-xyzw four x,y,z,w; \
             got {} and {}",
            t.len(),
            r.len()
        ),
        _ => bail!(
            "give both --translation x,y,z and --rotation-xyzw x,y,z,w, or neither to use the \
             pose the scan file holds"
        ),
    };
    Ok(stations::of_scan(scan, pose)?)
}
