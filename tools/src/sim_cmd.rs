//! `asbuilt sim`: a simulated print cell publishing a job to a running agent, and the parts of it
//! `asbuilt demo` shares: part and defect arguments, the truth file, the progress lines.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use asbuilt_protocol::ipc::{CellPorts, ServiceNames};
use asbuilt_protocol::{PoseMode, StationFindings, StationReport, StationStatus};
use asbuilt_sim::{JobSpec, PartSpec, SimEvent, SimJob, SimOutcome};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

/// What to print and how; shared by `sim` and `demo`.
#[derive(Args, Clone)]
pub struct JobArgs {
    /// The part: `wall` (the source study's 2 m shotcrete wall), `column` (a twisted
    /// elliptical column), or a design file (STL, OBJ, PLY) standing on z = 0.
    #[arg(long, default_value = "wall")]
    pub part: String,
    /// Units of a design file: m or mm.
    #[arg(long)]
    pub units: Option<String>,
    /// Layer height of a design file, metres (the built-in parts print in 20 mm layers).
    #[arg(long)]
    pub layer_height: Option<f64>,
    /// Layer counts after which the robot scans, e.g. 8,16,24.
    #[arg(long, value_delimiter = ',', default_value = "8,16,24,32,40,48")]
    pub scan_after: Vec<u32>,
    /// Stations per scan layer, on an ellipse around the part.
    #[arg(long, default_value_t = 4)]
    pub stations: u32,
    /// A defect, repeatable: KIND[:key=value,...]. Kinds: over-extrusion, under-extrusion
    /// (layers=A-B, width), height-drift (from, per-layer), lateral-shift (from, dx, dy), sag
    /// (layers, depth), missing-segment (layer, x, y, length, along=x|y), bulge (x, y, z,
    /// radius, height). Lengths in metres or with mm. Example: over-extrusion:layers=3-6,width=12mm
    #[arg(long = "defect")]
    pub defects: Vec<String>,
    /// Seed for pose noise and scanner noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Pose mode of the robot-mounted scanner: fixed (translation only, the Z+F mounting) or
    /// 6dof.
    #[arg(long, default_value = "fixed")]
    pub pose_mode: String,
    /// Pose error σ, metres.
    #[arg(long, default_value_t = 0.001)]
    pub pose_sigma: f64,
    /// Points per second the scanner sends, or `max`.
    #[arg(long, default_value = "1000000")]
    pub rate: String,
    /// Angle between rays, degrees (0.036: a Z+F IMAGER at "middle" resolution).
    #[arg(long, default_value_t = 0.036)]
    pub step_deg: f64,
    /// Job number.
    #[arg(long, default_value_t = 1)]
    pub job: u64,
    /// Tries at a station before the cell gives up on it: a station reported interrupted or
    /// unfinished, or whose sending fails (the agent stopped), is scanned and sent again.
    #[arg(long, default_value_t = 5)]
    pub attempts: u8,
    /// Close the loop: the printer applies the agent's latest advice (its [corrections] must be
    /// on) from the next layer it prints, against the height drift, extrusion and shift of the
    /// process; local defects (a missing segment, a bulge) are not corrected.
    #[arg(long)]
    pub closed_loop: bool,
}

impl JobArgs {
    /// The job the flags describe, as the simulator takes it: strings parsed, nothing checked
    /// that [`JobSpec::build`] checks.
    pub fn spec(&self) -> Result<JobSpec> {
        let part = match self.part.as_str() {
            "wall" => PartSpec::Wall,
            "column" => PartSpec::Column,
            file => PartSpec::File {
                path: PathBuf::from(file),
                units: self
                    .units
                    .as_deref()
                    .context(
                        "--units m|mm is required with a design file: units are never guessed",
                    )?
                    .parse()
                    .map_err(|e| anyhow::anyhow!("--units: {e}"))?,
                layer_height: self
                    .layer_height
                    .context("--layer-height METRES is required with a design file")?,
            },
        };
        Ok(JobSpec {
            part,
            scan_after: self.scan_after.clone(),
            stations: self.stations,
            defects: self.defects.clone(),
            seed: self.seed,
            pose_mode: match self.pose_mode.as_str() {
                "fixed" => PoseMode::FixedOrientation,
                "6dof" => PoseMode::SixDof,
                other => bail!("--pose-mode {other:?}: give fixed or 6dof"),
            },
            pose_sigma: self.pose_sigma,
            rate: crate::publish::parse_rate(&self.rate)?,
            step_deg: self.step_deg,
            job: self.job,
            attempts: self.attempts,
            closed_loop: self.closed_loop,
        })
    }

    /// The whole job the arguments describe: part, defects, scan layers, stations, scanner.
    pub fn job(&self) -> Result<SimJob> {
        Ok(self.spec()?.build()?)
    }
}

/// `asbuilt sim`'s arguments.
#[derive(Args)]
pub struct SimArgs {
    /// What to print and how.
    #[command(flatten)]
    pub job: JobArgs,
    /// Service prefix of the agent (its services.prefix).
    #[arg(long, default_value = "asbuilt")]
    pub prefix: String,
    /// Seconds to wait for the agent, and for the last report.
    #[arg(long, default_value_t = 30.0)]
    pub wait: f64,
    /// Write the injected defects and their truth per scan layer here (JSON).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    // The help text names agent.toml's section as it is written, not a Rust item.
    #[allow(rustdoc::broken_intra_doc_links)]
    /// Also wait for the agent's findings (its [findings] section must be on).
    #[arg(long)]
    pub findings: bool,
}

/// Sends the simulated job to a running agent and prints its reports and findings as they
/// come; exit code 1 when a station got no report.
pub fn run(args: SimArgs) -> Result<ExitCode> {
    let job = args.job.job()?;
    let names = ServiceNames::new(&args.prefix);
    let wait = Duration::from_secs_f64(args.wait);
    let (_node, ports) = crate::publish::connect(&names, job.chunk_points, wait)?;
    if let Some(p) = &args.truth {
        write_truth(p, &job, &[])?;
    }
    let outcome = run_with_progress(&job, &ports, args.findings, wait)?;
    if let Some(p) = &args.truth {
        // As built with what the printer applied.
        write_truth(p, &job, &outcome.settings)?;
    }
    Ok(verdict(&job, &outcome))
}

/// Runs the job with a progress bar and a line per station report.
pub fn run_with_progress(
    job: &SimJob,
    ports: &CellPorts,
    expect_findings: bool,
    wait: Duration,
) -> Result<SimOutcome> {
    let plan = job.plan();
    eprintln!(
        "simulating the {} ({} layers of {:.0} mm): {} station(s) after layers {:?}, {} defect(s), \
         rate {}",
        job.part.name,
        job.part.layers(),
        job.part.layer_height * 1e3,
        plan.len(),
        job.scan_after,
        job.defects.len(),
        job.rate
            .map_or("max".to_string(), |r| format!("{:.1} M points/s", r / 1e6))
    );
    let bar = ProgressBar::new(plan.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let outcome = asbuilt_sim::run(job, ports, expect_findings, wait, &mut |e| match e {
        SimEvent::Scanned {
            station,
            scan,
            seconds,
        } => bar.set_message(format!(
            "{}: scanned {} points in {:.2} s, sending",
            station.name,
            scan.points.len(),
            seconds
        )),
        SimEvent::Sent { .. } => bar.inc(1),
        SimEvent::Report(r) => say(&bar, report_line(r)),
        SimEvent::Findings(f) => say(&bar, findings_line(f)),
        SimEvent::Correction(_) => {}
        SimEvent::Printing { layers, advice } => say(&bar, printing_line(layers, advice)),
        SimEvent::Retry {
            station,
            attempt,
            why,
        } => {
            let next = if attempt < job.max_attempts {
                bar.inc_length(1);
                format!("sending it again as attempt {}", attempt + 1)
            } else {
                format!("giving up on it after {attempt} attempt(s)")
            };
            say(
                &bar,
                format!("  {:<10} attempt {attempt} {why}: {next}", station.name),
            )
        }
    })?;
    bar.finish_and_clear();
    eprintln!(
        "sent {} points in {:.1} s; {} report(s), {} findings",
        outcome.points_sent,
        outcome.seconds,
        outcome.reports.len(),
        outcome.findings.len()
    );
    if !outcome.retries.is_empty() {
        eprintln!("{}", interruptions_line(&plan, &outcome));
    }
    Ok(outcome)
}

/// The station attempts that did not end complete, in one line: "2 interruption(s): L016-S4
/// attempt 1 (reported Interrupted), …".
pub fn interruptions_line(plan: &[asbuilt_sim::PlannedStation], o: &SimOutcome) -> String {
    let items: Vec<String> = o
        .retries
        .iter()
        .map(|(station, attempt, why)| {
            let name = plan
                .iter()
                .find(|p| p.index == *station)
                .map_or_else(|| format!("station {station}"), |p| p.name.clone());
            format!("{name} attempt {attempt} ({why})")
        })
        .collect();
    format!("{} interruption(s): {}", items.len(), items.join(", "))
}

/// A line above the progress bar, or on stderr when there is no terminal to draw one on.
fn say(bar: &ProgressBar, line: String) {
    if bar.is_hidden() {
        eprintln!("{line}");
    } else {
        bar.println(line);
    }
}

/// One line for a station report, as `sim` and `demo` print it.
pub fn report_line(r: &StationReport) -> String {
    format!(
        "  {:<10} layer {:>3} {:?}: {:>8} points, median |d| {:.2} mm, p95 {:.2} mm, {:.1} % in \
         tolerance",
        r.name.as_str(),
        r.layer + 1,
        r.status().unwrap_or(StationStatus::Incomplete),
        r.points_received,
        r.stats.median_abs * 1e3,
        r.stats.p95_abs * 1e3,
        100.0 * r.stats.within as f64 / r.stats.count.max(1) as f64
    )
}

/// One line for the layers the closed-loop printer prints next, and the advice it applies.
pub fn printing_line(
    layers: (u32, u32),
    advice: Option<&asbuilt_protocol::LayerCorrection>,
) -> String {
    let what = match advice {
        None => "as designed (no advice came)".to_string(),
        Some(c) if c.is_neutral() => "as designed (advice: nothing to correct)".to_string(),
        Some(c) => advice_text(c),
    };
    format!(
        "  printing layers {}–{}: {what}",
        layers.0 + 1,
        layers.1 + 1
    )
}

/// Advice in a few words: the z offsets, the flow and the path.
pub fn advice_text(c: &asbuilt_protocol::LayerCorrection) -> String {
    let mut items = Vec::new();
    if c.z_first != 0.0 || c.z_then != 0.0 {
        if c.first_layers > 0 && c.z_first != c.z_then {
            items.push(format!(
                "z {:+.2} mm a layer for {} layers, then {:+.2}",
                c.z_first * 1e3,
                c.first_layers,
                c.z_then * 1e3
            ));
        } else {
            items.push(format!("z {:+.2} mm a layer", c.z_then * 1e3));
        }
    }
    if c.flow != 1.0 {
        items.push(format!("flow ×{:.3}", c.flow));
    }
    if c.path_offset != [0.0, 0.0] {
        items.push(format!(
            "path ({:+.1}, {:+.1}) mm",
            c.path_offset[0] * 1e3,
            c.path_offset[1] * 1e3
        ));
    }
    if items.is_empty() {
        "nothing to correct".into()
    } else {
        format!("advised {}", items.join(", "))
    }
}

/// One line for a scan layer's findings, as `sim` and `demo` print it.
pub fn findings_line(f: &StationFindings) -> String {
    let mut items = Vec::new();
    if f.top_height_deviation.abs() > f.tolerance {
        items.push(format!("top {:+.1} mm", f.top_height_deviation * 1e3));
    }
    for l in f.layers_out_of_tolerance() {
        let w = l.width_deviation;
        let s = l.shift[0].hypot(l.shift[1]);
        items.push(if w.abs() > f.tolerance {
            format!("layer {} width {:+.1} mm", l.layer, w * 1e3)
        } else {
            format!("layer {} shifted {:.1} mm", l.layer, s * 1e3)
        });
    }
    for g in f.missing.iter() {
        items.push(format!(
            "missing {:.0} cm² at ({:.2}, {:.2}, {:.2})",
            g.area_m2 * 1e4,
            g.centroid[0],
            g.centroid[1],
            g.centroid[2]
        ));
    }
    for g in f.regions.iter() {
        items.push(format!(
            "{} {:+.1} mm at ({:.2}, {:.2}, {:.2})",
            g.kind.as_str(),
            g.peak * 1e3,
            g.centroid[0],
            g.centroid[1],
            g.centroid[2]
        ));
    }
    // A line, not a table: the largest few; report.json and report.html have them all.
    const SHOWN: usize = 8;
    let more = items.len().saturating_sub(SHOWN);
    items.truncate(SHOWN);
    if more > 0 {
        items.push(format!("{more} more in the report"));
    }
    format!(
        "  findings after {} station(s) of layer {}: {}",
        f.stations,
        f.layer + 1,
        if items.is_empty() {
            "none beyond the tolerance".to_string()
        } else {
            items.join("; ")
        }
    )
}

fn verdict(job: &SimJob, o: &SimOutcome) -> ExitCode {
    let expected = job.plan().len();
    if o.reports.len() < expected {
        eprintln!(
            "error: {} of {expected} station(s) got no report",
            expected - o.reports.len()
        );
        return ExitCode::from(1);
    }
    let unfinished: Vec<String> = o
        .reports
        .iter()
        .filter(|r| r.status() != Some(StationStatus::Complete))
        .map(|r| format!("{} ({:?})", r.name.as_str(), r.status()))
        .collect();
    if !unfinished.is_empty() {
        eprintln!(
            "error: {} station(s) never ended complete in {} attempt(s): {}",
            unfinished.len(),
            job.max_attempts,
            unfinished.join(", ")
        );
        return ExitCode::from(1);
    }
    ExitCode::SUCCESS
}

/// Writes the job's truth.json: the injected defects, what the agent should find, and the
/// print as built with the `settings` the printer applied (none: as designed).
pub fn write_truth(
    path: &Path,
    job: &SimJob,
    settings: &[asbuilt_sim::LayerSettings],
) -> Result<()> {
    std::fs::write(
        path,
        serde_json::to_string_pretty(&job.truth_json(settings))?,
    )
    .with_context(|| format!("cannot write {}", path.display()))
}
