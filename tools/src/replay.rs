//! `asbuilt replay`: a recording's inputs (station events, poses, scan chunks) sent again to a
//! running agent over iceoryx2, with the recorded timing or as fast as the agent takes them.
//! A recording replayed into a fresh agent gives the same station reports.

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use asbuilt_protocol::StationReport;
use asbuilt_protocol::ipc::ServiceNames;
use asbuilt_protocol::recording::{self, Recorded};
use clap::Args;

use crate::publish::collect_reports;
use asbuilt_report::Section;

#[derive(Args)]
pub struct ReplayArgs {
    /// The recording (from the agent's recorder or `asbuilt pack`); several files of one job
    /// (a job the agent resumed after a stop, or rotated into parts); or the agent's recording
    /// folder, for its newest job.
    #[arg(required = true, value_name = "RECORDING")]
    recordings: Vec<PathBuf>,
    /// With a folder: the job to replay instead of the newest.
    #[arg(long)]
    job: Option<u64>,
    /// 1.0 keeps the recorded timing, 2.0 twice as fast; `max` sends as fast as the agent takes.
    #[arg(long, default_value = "max")]
    speed: String,
    /// Service prefix of the agent (its services.prefix).
    #[arg(long, default_value = "asbuilt")]
    prefix: String,
    /// Seconds to wait for the agent to come up, and for the last report.
    #[arg(long, default_value_t = 30.0)]
    wait: f64,
    /// Also write the reports that came back as DIR/replay.json.
    #[arg(long)]
    out: Option<PathBuf>,
}

pub fn run(args: ReplayArgs) -> Result<ExitCode> {
    let speed = match args.speed.as_str() {
        "max" => None,
        s => Some(
            s.parse::<f64>()
                .ok()
                .filter(|v| *v > 0.0 && v.is_finite())
                .with_context(|| format!("--speed {s:?}: give a factor such as 1.0, or max"))?,
        ),
    };
    let files = asbuilt_readback::files::job_files(&args.recordings, args.job)?;
    let (mut stations, mut max_points, mut inputs) = (BTreeSet::new(), 1, 0);
    for f in &files {
        let bytes = asbuilt_readback::files::map(f)?;
        let (s, m, i) =
            survey(&bytes).map_err(|e| asbuilt_readback::ReadBackError::unreadable(f, e))?;
        stations.extend(s);
        max_points = max_points.max(m);
        inputs += i;
    }
    let shown = match files.as_slice() {
        [one] => one.display().to_string(),
        many => format!("{} files of one job", many.len()),
    };
    if inputs == 0 {
        bail!("{shown} holds no input to replay");
    }
    let names = ServiceNames::new(&args.prefix);
    let wait = Duration::from_secs_f64(args.wait);
    let (_node, ports) = asbuilt_protocol::ipc::CellPorts::connect(&names, max_points, wait)?;
    eprintln!(
        "replaying {} inputs of {} stations from {} to {}/… at speed {}",
        inputs,
        stations.len(),
        shown,
        names.prefix,
        args.speed
    );
    let started = Instant::now();
    let mut first: Option<u64> = None;
    let mut reports: Vec<StationReport> = Vec::new();
    let jobs: BTreeSet<u64> = stations.iter().map(|s| s.0).collect();
    let mut points = 0u64;
    // In the order the agent processed them: an End recorded ahead of its chunks follows them;
    // the files of a job one after the other.
    for f in &files {
        let bytes = asbuilt_readback::files::map(f)?;
        let bad = |e| asbuilt_readback::ReadBackError::unreadable(f, e);
        for m in recording::messages_in_agent_order(&bytes).map_err(bad)? {
            let (log_time, m) = m.map_err(bad)?;
            if !m.channel().is_input() {
                continue;
            }
            if let Some(speed) = speed {
                let t0 = *first.get_or_insert(log_time);
                let due = Duration::from_secs_f64(log_time.saturating_sub(t0) as f64 / 1e9 / speed);
                if let Some(ahead) = due.checked_sub(started.elapsed()) {
                    std::thread::sleep(ahead);
                }
            }
            match &m {
                Recorded::Event(e) => ports.send_event(e)?,
                Recorded::Pose(p) => ports.send_pose(p)?,
                Recorded::MountPose(m) => ports.send_mount_pose(m)?,
                Recorded::Chunk(h, p) => {
                    ports.send_chunk(h, p)?;
                    points += p.len() as u64;
                }
                Recorded::Profiles(h, p) => {
                    ports.send_profiles(h, p)?;
                    points += p.len() as u64;
                }
                _ => {}
            }
            for &job in &jobs {
                collect_reports(&ports, job, &mut reports, Duration::ZERO)?;
            }
        }
    }
    let deadline = Instant::now() + wait;
    while reports.len() < stations.len() && Instant::now() < deadline {
        for &job in &jobs {
            collect_reports(&ports, job, &mut reports, Duration::from_millis(50))?;
        }
    }
    crate::publish::tell_rate("replayed", points, started, reports.len(), stations.len());
    if let Some(dir) = &args.out {
        write_reports(dir, &mut reports)?;
    }
    Ok(crate::publish::reports_verdict(
        stations.len(),
        &reports,
        args.wait,
    ))
}

/// What a first pass over a recording finds: the stations to expect (job, station), the largest
/// chunk's points and the number of inputs.
type Survey = (BTreeSet<(u64, u32)>, usize, u64);

/// First pass over a recording, keeping no message.
fn survey(bytes: &[u8]) -> Result<Survey, recording::ReadError> {
    let mut stations = BTreeSet::new();
    let mut max_points = 1usize;
    let mut inputs = 0u64;
    for m in recording::messages(bytes)? {
        let (_, m) = m?;
        match &m {
            Recorded::Event(e) => {
                stations.insert((e.job, e.station));
            }
            Recorded::Chunk(h, p) => {
                stations.insert((h.job, h.station));
                max_points = max_points.max(p.len());
            }
            Recorded::Profiles(h, p) => {
                stations.insert((h.job, h.pass));
                max_points = max_points.max(p.len());
            }
            _ => {}
        }
        inputs += m.channel().is_input() as u64;
    }
    Ok((stations, max_points, inputs))
}

/// The reports that came back, by job and station, as DIR/replay.json.
fn write_reports(dir: &std::path::Path, reports: &mut [StationReport]) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    reports.sort_by_key(|r| (r.job, r.station));
    let sections: Vec<Section> = reports
        .iter()
        .map(|r| Section::from_report(r, None, 0))
        .collect();
    let path = dir.join("replay.json");
    std::fs::write(&path, serde_json::to_string_pretty(&sections)?)
        .with_context(|| format!("cannot write {}", path.display()))
}
