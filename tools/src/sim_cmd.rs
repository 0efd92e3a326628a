//! `asbuilt sim`: a simulated print cell publishing a job to a running agent, and the parts of it
//! `asbuilt demo` shares: part and defect arguments, the truth file, the progress lines.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use asbuilt_protocol::PoseMode;
use asbuilt_protocol::ipc::{CellPorts, ServiceNames};
use asbuilt_sim::lines::{findings_line, interruptions_line, printing_line, report_line};
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
    /// Points per second the scanner sends, or `max` (default 1000000; a profiler's: max).
    #[arg(long)]
    pub rate: Option<String>,
    /// `tls` (a scanner carried to stations) or `profiler` (a line profiler on the nozzle).
    #[arg(long, default_value = "tls")]
    pub sensor: String,
    /// With --sensor profiler: points per profile (default 2048; the demo's is 256).
    #[arg(long)]
    pub profile_points: Option<usize>,
    /// With --sensor profiler: the layers printed, each a pass (default: all of the part).
    #[arg(long)]
    pub layers: Option<u32>,
    /// With --sensor profiler: profiles per second.
    #[arg(long, default_value_t = 2000.0)]
    pub profile_rate: f64,
    /// With --sensor profiler: the robot's poses per second.
    #[arg(long, default_value_t = 250.0)]
    pub pose_rate: f64,
    /// With --sensor profiler: the robot's clock less the profiler's, ns (the agent's too).
    #[arg(long, default_value_t = 0, allow_hyphen_values = true)]
    pub clock_offset: i64,
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
    /// With --closed-loop: the share of each advice the printer applies, 0 to 1 (the cell
    /// decides; it tells the agent what it applied, layer by layer).
    #[arg(long, default_value_t = 1.0, requires = "closed_loop")]
    pub apply: f64,
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
        let profiler = match self.sensor.as_str() {
            "tls" => None,
            "profiler" => Some(asbuilt_sim::ProfilerSpec {
                points: self.profile_points.unwrap_or(2048),
                rate_hz: self.profile_rate,
                pose_rate_hz: self.pose_rate,
                clock_offset_ns: self.clock_offset,
                layers: self.layers,
            }),
            other => bail!("--sensor {other:?}: give tls or profiler"),
        };
        let rate = self.rate.as_deref().unwrap_or(match profiler {
            Some(_) => "max",
            None => "1000000",
        });
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
            rate: crate::publish::parse_rate(rate)?,
            step_deg: self.step_deg,
            job: self.job,
            attempts: self.attempts,
            closed_loop: self.closed_loop,
            apply: self.apply,
            profiler,
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
    let (_node, ports) =
        asbuilt_protocol::ipc::CellPorts::connect(&names, job.chunk_capacity(), wait)?;
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
    eprintln!("{}", asbuilt_sim::lines::job_line(job));
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

/// A line above the progress bar, or on stderr when there is no terminal to draw one on.
fn say(bar: &ProgressBar, line: String) {
    if bar.is_hidden() {
        eprintln!("{line}");
    } else {
        bar.println(line);
    }
}

fn verdict(job: &SimJob, o: &SimOutcome) -> ExitCode {
    match o.unfinished(job) {
        Some(problem) => {
            eprintln!("error: {problem}");
            ExitCode::from(1)
        }
        None => ExitCode::SUCCESS,
    }
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
