//! `asbuilt demo`: the whole system with one command and no hardware. An agent in its own
//! process (this executable's `agent` subcommand) with the recorder, the rerun view and findings
//! on; the simulated print cell in this process, talking to it over real iceoryx2 services; then
//! the report of the recording, and where to look.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use asbuilt_protocol::ipc::{CellPorts, Ipc, ServiceNames};
use asbuilt_sim::{SimJob, SimOutcome};
use clap::Args;
use iceoryx2::prelude::*;

use crate::sim_cmd::{self, JobArgs};

#[derive(Args)]
pub struct DemoArgs {
    #[command(flatten)]
    job: JobArgs,
    /// Where the recording, the .rrd, report.json and the HTML report go.
    #[arg(long, default_value = "out/demo")]
    out: PathBuf,
    /// Print without defects (without --defect, the demo injects over-extrusion, a bulge, a
    /// missing segment and height drift).
    #[arg(long)]
    no_defects: bool,
    /// Also stream the view to a running rerun viewer: rerun+http://HOST:PORT/proxy.
    #[arg(long)]
    rerun_url: Option<String>,
    /// Tolerance, metres.
    #[arg(long, default_value_t = 0.005)]
    tolerance: f64,
}

/// The demo's defects on the wall; on other parts the kinds alone, placed by default. With a
/// profiler, the process engineer's case: the print walks off by 5 mm, and a bulge.
fn default_defects(part: &str, profiler: bool) -> Vec<String> {
    if profiler {
        vec!["lateral-shift:from=20,dx=5mm,dy=0".into(), "bulge".into()]
    } else if part == "wall" {
        vec![
            "over-extrusion:layers=2-4,width=12mm".into(),
            "bulge:x=-0.5,y=-0.0867,z=0.25,radius=0.1,height=15mm".into(),
            "missing-segment:layer=18,x=0.45,y=0,length=0.25".into(),
            "height-drift:from=20,per-layer=0.5mm".into(),
        ]
    } else {
        vec![
            "over-extrusion:layers=2-4,width=12mm".into(),
            "bulge".into(),
            "missing-segment:layer=18,length=0.1".into(),
        ]
    }
}

pub fn run(mut args: DemoArgs) -> Result<ExitCode> {
    let profiler = args.job.sensor == "profiler";
    if args.job.defects.is_empty() && !args.no_defects {
        args.job.defects = default_defects(&args.job.part, profiler);
    }
    if profiler {
        // 256 points a profile, 0.4 mm apart, keep the demo short; 2048 is the full line.
        args.job.profile_points.get_or_insert(256);
    }
    let job = args.job.job()?;
    if !(args.tolerance > 0.0 && args.tolerance < 0.1) {
        bail!("--tolerance {}: give metres in (0, 0.1)", args.tolerance);
    }
    let out = &args.out;
    prepare(out)?;
    check_room(out, &job)?;
    let design = out.join("design.stl");
    asbuilt_sim::write_stl(&design, &job.part.design)?;
    let prefix = format!("asbuilt-demo-{}", std::process::id());
    let config = out.join("agent.toml");
    std::fs::write(&config, agent_config(&job, &prefix, &args))
        .with_context(|| format!("cannot write {}", config.display()))?;
    sim_cmd::write_truth(&out.join("truth.json"), &job, &[])?;

    let log = out.join("agent.log");
    let mut agent = start_agent(&config, &log)?;
    let outcome = talk_to_agent(&job, &prefix, &mut agent, &log);
    stop_agent(&mut agent)?;
    let outcome = outcome?;
    // As built with what the printer applied (the same as before, open loop).
    sim_cmd::write_truth(&out.join("truth.json"), &job, &outcome.settings)?;

    let recording = newest_mcap(&out.join("recording"))?;
    let report = crate::report_cmd::write(&[out.join("recording")], out, Default::default())?;
    summary(&job, &outcome, out, &recording);
    let short = report.short_of_live(&outcome.reports);
    if !short.is_empty() {
        eprintln!(
            "\nThe recording lacks points the agent reported, so report.json and report.html \
             lack them too (the agent's own reports above are whole). Its recorder leaves scan \
             chunks out when the disk is nearly full or its writer falls behind; {} says which \
             and when.",
            log.display()
        );
        for (station, recorded, reported) in &short {
            eprintln!("  {station}: {recorded} of {reported} points recorded");
        }
    }
    Ok(
        if outcome.reports.len() == job.plan().len() && short.is_empty() {
            ExitCode::SUCCESS
        } else {
            ExitCode::from(1)
        },
    )
}

/// Points a station of the default demo gives at the default scanner step (24 stations and
/// 15.4 M points, rounded up), and the bytes a point takes in its recording and its view
/// (11.7 and 4.2): the room the demo needs, roughly, before it starts.
const POINTS_A_STATION: f64 = 650_000.0;
const DEFAULT_STEP_DEG: f64 = 0.036;
const BYTES_A_POINT: f64 = 16.0;

/// The MB the demo's recording and view take for `job`, roughly (see [`POINTS_A_STATION`]).
fn writes_mb(job: &SimJob) -> u64 {
    if let Some(points) = job.profiler_points() {
        return (points * 10.0 / 1e6).ceil() as u64; // 10 B a point: 9.2 measured
    }
    let points = job.plan().len() as f64
        * POINTS_A_STATION
        * (DEFAULT_STEP_DEG / job.scanner.step_deg).powi(2);
    (points * BYTES_A_POINT / 1e6).ceil() as u64
}

/// Free space the demo's recorder keeps before it leaves scans out, MB. The agent's default
/// (1,024) guards a print that runs for hours; the demo's job is bounded, and [`check_room`]
/// looks for its room before it starts.
const MIN_FREE_MB: u64 = 64;

/// Refuses to start when `out`'s disk lacks the room the demo's files need, rather than
/// leaving a recording without its scans.
fn check_room(out: &Path, job: &SimJob) -> Result<()> {
    let writes = writes_mb(job);
    match asbuilt_agent::recorder::free_bytes(out) {
        Some(free) if free / 1_000_000 < writes + MIN_FREE_MB => bail!(
            "{} has {} MB free: the demo writes about {writes} MB there (its recording and \
             view) and its recorder keeps {MIN_FREE_MB} MB free. Free some space, or give --out \
             a folder on a disk with room",
            out.display(),
            free / 1_000_000
        ),
        _ => Ok(()),
    }
}

/// Creates `out`, removing what an earlier demo left there (and nothing else).
fn prepare(out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    for f in [
        "demo.rrd",
        "report.json",
        "report.html",
        "agent.log",
        "agent.toml",
        "truth.json",
        "design.stl",
    ] {
        let _ = std::fs::remove_file(out.join(f));
    }
    let _ = std::fs::remove_dir_all(out.join("recording"));
    Ok(())
}

fn agent_config(job: &SimJob, prefix: &str, args: &DemoArgs) -> String {
    let corrections = if job.closed_loop {
        format!(
            "\n[corrections]\n# The loop is closed (--closed-loop): the simulated printer applies \
             this advice.\nenabled = true\nbead_width = {}\n",
            job.part.bead_width().unwrap_or(0.1)
        )
    } else {
        String::new()
    };
    let profiler = job.profiler.map_or(String::new(), |m| {
        format!(
            "\n[profiler]\n# The simulated profiler's clock runs this far behind the robot's.\n\
             clock_offset_ns = {}\n",
            m.clock_offset_ns
        )
    });
    // A pass is one layer's band: 20,000 points draw it at about a point a mm², and the view
    // of 60 passes stays a 30 MB file instead of the 200,000 a scanner's station is given.
    let pass_points = if job.profiler.is_some() {
        "max_points_per_station = 20000\n"
    } else {
        ""
    };
    let url = args
        .rerun_url
        .as_ref()
        .map(|u| format!("url = {u:?}\n"))
        .unwrap_or_default();
    format!(
        "# Written by `asbuilt demo`: the agent the demo ran, as agent/agent.example.toml explains.\n\
         [design]\npath = \"design.stl\"\nunits = \"m\"\n\n\
         [inspect]\ntolerance = {tol}\nmax_distance = 0.03\n\n\
         [services]\nprefix = \"{prefix}\"\n\n\
         [limits]\nmax_points_per_chunk = {chunk}\n\n\
         [status]\nperiod_s = 5.0\n\n\
         [recorder]\ndir = \"recording\"\nfoxglove = true\n\
         # The demo's job is bounded and checked for room before it starts; an agent beside a\n\
         # printer keeps the default, 1024.\nmin_free_mb = {min_free}\n\n\
         [viewer]\nrrd = \"demo.rrd\"\n{pass_points}{url}\n\
         [findings]\nenabled = true\nlayer_height = {h}\n\n\
         [tolerances]\n# The report's verdicts: each kind's limit (metres, m² for missing material).\n\
         width = {tol}\ntop_height = {tol}\nposition = {tol}\nsurface = {tol}\n\
         missing_area_m2 = 0.002\ncreep = {tol}\n{corrections}{profiler}",
        tol = args.tolerance,
        chunk = job.chunk_capacity(),
        h = job.part.layer_height,
        min_free = MIN_FREE_MB,
    )
}

fn start_agent(config: &Path, log: &Path) -> Result<Child> {
    let exe = std::env::current_exe().context("cannot find this executable to start the agent")?;
    let log_file =
        std::fs::File::create(log).with_context(|| format!("cannot write {}", log.display()))?;
    Command::new(exe)
        .arg("agent")
        .arg("--config")
        .arg(config)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(log_file)
        .spawn()
        .context("cannot start the agent")
}

fn talk_to_agent(job: &SimJob, prefix: &str, agent: &mut Child, log: &Path) -> Result<SimOutcome> {
    set_log_level_from_env_or(LogLevel::Error);
    let node = NodeBuilder::new()
        .create::<Ipc>()
        .map_err(|e| anyhow::anyhow!("cannot create an iceoryx2 node: {e:?}"))?;
    let names = ServiceNames::new(prefix);
    let started = Instant::now();
    let ports = loop {
        match CellPorts::open(
            &node,
            &names,
            job.chunk_capacity(),
            Duration::from_millis(500),
        ) {
            Ok(p) => break p,
            Err(e) => {
                if let Some(status) = agent.try_wait()? {
                    bail!(
                        "the agent stopped ({status}) before it served; its log ({}):\n{}",
                        log.display(),
                        tail(log)
                    );
                }
                if started.elapsed() > Duration::from_secs(60) {
                    return Err(
                        anyhow::Error::new(e).context("the agent did not come up within 60 s")
                    );
                }
            }
        }
    };
    eprintln!(
        "agent up (pid {}, services {prefix}/…, log {})",
        agent.id(),
        log.display()
    );
    sim_cmd::run_with_progress(job, &ports, true, Duration::from_secs(60))
}

fn stop_agent(agent: &mut Child) -> Result<()> {
    if agent.try_wait()?.is_some() {
        return Ok(());
    }
    // SIGTERM: the agent closes its stations, the recorder and the view, then exits.
    // SAFETY: kill with a pid of our own child and a valid signal number.
    unsafe {
        libc::kill(agent.id() as libc::pid_t, libc::SIGTERM);
    }
    let deadline = Instant::now() + Duration::from_secs(60);
    while Instant::now() < deadline {
        if agent.try_wait()?.is_some() {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    agent.kill().ok();
    bail!("the agent did not stop within 60 s of SIGTERM; killed")
}

fn newest_mcap(dir: &Path) -> Result<PathBuf> {
    let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("the agent wrote no recording in {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    found.sort();
    found
        .pop()
        .with_context(|| format!("the agent wrote no recording in {}", dir.display()))
}

fn tail(log: &Path) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(20)..].join("\n")
}

/// Injected against found, and where to look.
fn summary(job: &SimJob, o: &SimOutcome, out: &Path, recording: &Path) {
    eprintln!("\ninjected (truth.json) and what the agent reported, per scan layer:");
    for line in asbuilt_sim::lines::truth_and_findings(job, o) {
        eprintln!("{line}");
    }
    eprintln!(
        "\n{} in {:.0} s. Look at it:\n  rerun {}          # pip install rerun-sdk==0.36.*\n  \
         open {}\n  {}\n  asbuilt replay {} --prefix asbuilt   # into your own agent",
        if o.reports.len() == job.plan().len() {
            "done"
        } else {
            "INCOMPLETE"
        },
        o.seconds,
        out.join("demo.rrd").display(),
        out.join("report.html").display(),
        out.join("report.json").display(),
        recording.display()
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        demo: DemoArgs,
    }

    fn job(args: &[&str]) -> SimJob {
        let mut cli = Cli::parse_from(std::iter::once("demo").chain(args.iter().copied()));
        cli.demo.job.defects = default_defects(&cli.demo.job.part, false);
        cli.demo.job.job().unwrap()
    }

    /// The default demo wrote 250 MB (a 180 MB recording, a 65 MB view): the estimate covers
    /// it without asking for twice the room; a coarser scan of fewer stations asks for little.
    #[test]
    fn the_room_asked_for_covers_what_the_default_demo_writes() {
        let default = writes_mb(&job(&[]));
        assert!((250..=300).contains(&default), "{default} MB");
        let coarse: Vec<&str> = "--scan-after 8 --stations 2 --step-deg 0.1"
            .split(' ')
            .collect();
        let small = writes_mb(&job(&coarse));
        assert!(small < 10, "{small} MB");
    }
}
