//! `asbuilt report`: a recording inspected again offline, into the same `report.json` that
//! `inspect` writes and an HTML page that opens without a network.
//!
//! The design comes from the recording's attachment and the settings from its configuration,
//! so the review needs nothing but the file. Every station is recomputed from its recorded pose
//! and scan chunks with the same inspector the agent runs.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use asbuilt_core::frames::FrameChain;
use asbuilt_core::printed::PrintedDesigns;
use asbuilt_core::station::{InspectConfig, StationInspector, Tally};
use asbuilt_core::{C2mParams, Design, Units};
use asbuilt_protocol::recording::{self, Recorded};
use asbuilt_protocol::{PointDeviation, StationEventKind};
use clap::Args;

use crate::report::{DesignSection, Parameters, Report, Section, summary_table};

#[derive(Args)]
pub struct ReportArgs {
    /// The recording (from the agent's recorder or `asbuilt pack`).
    recording: PathBuf,
    /// Output folder for report.json and report.html.
    #[arg(long, default_value = "out/report")]
    out: PathBuf,
    /// Tolerance, metres; default the recording's configuration, else 0.005.
    #[arg(long)]
    tolerance: Option<f64>,
    /// Maximum distance, metres; default the recording's configuration, else 10 × tolerance.
    #[arg(long)]
    max_distance: Option<f64>,
}

struct Open {
    inspector: StationInspector,
    name: String,
    has_pose: bool,
    sigma: f64,
}

pub fn run(args: ReportArgs) -> Result<ExitCode> {
    write(
        &args.recording,
        &args.out,
        args.tolerance,
        args.max_distance,
    )?;
    Ok(ExitCode::SUCCESS)
}

/// Writes `out/report.json` and `out/report.html` for `recording`.
pub fn write(
    recording_path: &std::path::Path,
    out: &std::path::Path,
    tolerance: Option<f64>,
    max_distance: Option<f64>,
) -> Result<()> {
    let args = ReportArgs {
        recording: recording_path.to_path_buf(),
        out: out.to_path_buf(),
        tolerance,
        max_distance,
    };
    let bytes = crate::recording_file::map(&args.recording)?;
    let bad = |e| crate::recording_file::unreadable(&args.recording, e);
    let (meta, attachments) = recording::job(&bytes).map_err(bad)?;
    let meta = meta.with_context(|| {
        format!(
            "{} has no asbuilt.job metadata: it was not written by asbuilt",
            args.recording.display()
        )
    })?;
    let (name, design_bytes) = attachments
        .into_iter()
        .find(|(n, _)| n.starts_with(recording::ATTACHMENT_DESIGN))
        .with_context(|| format!("{} carries no design attachment", args.recording.display()))?;
    let units: Units = match meta.design_units.to_ascii_lowercase().as_str() {
        "m" | "metres" => Units::Metres,
        "mm" | "millimetres" => Units::Millimetres,
        other => bail!("the recording's design units {other:?} are not m or mm"),
    };
    // The design as it was, under its own name so its format is recognised.
    let tmp = tempfile::tempdir()?;
    let design_file = tmp
        .path()
        .join(name.rsplit('/').next().unwrap_or("design.stl"));
    std::fs::write(&design_file, &design_bytes)?;
    let design = Design::load(&design_file, units)?;

    let (frames, settings) = if meta.writer == "asbuilt-agent" {
        asbuilt_agent::config::recorded_settings(&meta.config)
            .map_err(|p| anyhow::anyhow!("the recording's configuration: {}", p.join("; ")))?
    } else {
        (FrameChain::default(), Default::default())
    };
    let tolerance = args.tolerance.unwrap_or(settings.tolerance);
    let max_distance = args
        .max_distance
        .unwrap_or_else(|| settings.max_distance.unwrap_or(10.0 * tolerance));
    if !(tolerance > 0.0 && max_distance > 0.0) {
        bail!("--tolerance and --max-distance must be positive metres");
    }
    // Stations scanned while printing were compared with the design as printed then.
    let mut designs = PrintedDesigns::new(
        design,
        C2mParams {
            max_distance,
            cell_size: settings.cell_size,
        },
    )?;
    let mut findings: BTreeMap<(u64, u64), asbuilt_protocol::StationFindings> = BTreeMap::new();
    let mut config = InspectConfig::with_tolerance(tolerance);
    config.max_range = settings.max_range;

    let mut open: BTreeMap<(u64, u32), Open> = BTreeMap::new();
    let mut done: Vec<((u64, u32), Section)> = Vec::new();
    let mut total = Tally::new(config.stats);
    let mut buffer: Vec<PointDeviation> = Vec::new();
    let close =
        |key: (u64, u32), o: Open, done: &mut Vec<((u64, u32), Section)>, total: &mut Tally| {
            let mut r = o.inspector.report(key.0, key.1, &o.name);
            r.position_sigma = o.sigma;
            total.merge(o.inspector.tally());
            done.push((key, Section::from_report(&r, None, 0)));
        };
    for m in recording::messages(&bytes).map_err(bad)? {
        let (_, m) = m.map_err(bad)?;
        match m {
            Recorded::Event(e) => {
                let key = (e.job, e.station);
                match e.kind() {
                    Some(StationEventKind::Begin) => {
                        let printed = designs.at(e.printed_height).unwrap_or_else(|err| {
                            eprintln!(
                                "warning: job {} station {}: printed height {} m: {err}; compared \
                                 with the whole design",
                                e.job, e.station, e.printed_height
                            );
                            designs.full().clone()
                        });
                        let o = open.entry(key).or_insert_with(|| Open {
                            inspector: StationInspector::new(
                                printed.clone(),
                                nalgebra::Isometry3::identity(),
                                config,
                            ),
                            name: String::new(),
                            has_pose: false,
                            sigma: 0.0,
                        });
                        o.name = e.name.as_str().to_string();
                    }
                    Some(StationEventKind::End) => {
                        if let Some(o) = open.remove(&key) {
                            close(key, o, &mut done, &mut total);
                        }
                    }
                    None => {}
                }
            }
            Recorded::Pose(p) => {
                let Some(o) = open.get_mut(&(p.job, p.station)) else {
                    continue;
                };
                match frames.t_design_scanner(&p) {
                    Ok(t) => {
                        o.inspector.set_pose(t);
                        o.has_pose = true;
                        o.sigma = p.position_sigma;
                    }
                    Err(e) => eprintln!(
                        "warning: job {} station {}: pose rejected: {e}",
                        p.job, p.station
                    ),
                }
            }
            Recorded::Chunk(h, pts) => {
                let key = (h.job, h.station);
                let Some(o) = open.get_mut(&key) else {
                    continue;
                };
                if !o.has_pose {
                    o.inspector.reject_without_pose(pts.len() as u64);
                } else {
                    buffer.resize(pts.len(), PointDeviation::default());
                    o.inspector.process(&pts, &mut buffer);
                }
                if h.last != 0
                    && let Some(o) = open.remove(&key)
                {
                    close(key, o, &mut done, &mut total);
                }
            }
            // The latest findings of each scan layer cover all its stations so far.
            Recorded::Findings(f) => {
                findings.insert((f.job, f.printed_height.to_bits()), *f);
            }
            _ => {}
        }
    }
    // Stations the recording never closed (the agent stopped, a publisher died).
    let unfinished = open.len();
    for (key, o) in std::mem::take(&mut open) {
        close(key, o, &mut done, &mut total);
    }
    done.sort_by_key(|(k, _)| *k);
    if done.is_empty() {
        bail!("{} holds no station", args.recording.display());
    }
    let ix = designs.full().index.stats();
    let design = designs.full().design();
    let mut warnings = design.report.warnings();
    if unfinished > 0 {
        warnings.push(format!(
            "{unfinished} station(s) have no end in the recording: reported as far as recorded"
        ));
    }
    let report = Report {
        asbuilt_version: env!("CARGO_PKG_VERSION"),
        design: DesignSection {
            path: meta.design_path.clone(),
            units: format!("{units:?}"),
            vertices: design.vertices.len(),
            triangles: design.triangles.len(),
            warnings: design.report.warnings(),
            index_cell_size_m: ix.cell_size,
            index_cells: ix.cells,
            index_bytes: ix.bytes,
        },
        parameters: Parameters {
            tolerance_m: tolerance,
            max_distance_m: max_distance,
            histogram_range_m: config.stats.histogram_range,
            spacing_m: 0.0,
            coverage_threshold_m: 0.0,
            projection_diameter_m: 0.0,
            max_depth_m: 0.0,
            printed_height_m: None,
            layer_height_m: None,
            reference: None,
        },
        methods: vec!["c2m"],
        stations: done.into_iter().map(|(_, s)| s).collect(),
        overall: Section::from_report(&total.report(0, u32::MAX, "overall"), None, 0),
        layers: None,
        m3c2_two_cloud: None,
        findings: {
            let mut f: Vec<_> = findings.into_values().collect();
            f.sort_by_key(|a| (a.job, a.layer));
            f
        },
        warnings,
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let json = args.out.join("report.json");
    std::fs::write(&json, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("cannot write {}", json.display()))?;
    let html = args.out.join("report.html");
    std::fs::write(
        &html,
        crate::html::page(&report, &args.recording.display().to_string()),
    )
    .with_context(|| format!("cannot write {}", html.display()))?;
    print!("{}", summary_table(&report));
    eprintln!("wrote {} and {}", json.display(), html.display());
    Ok(())
}
