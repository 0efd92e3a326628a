//! `asbuilt publish`: streams scans with known poses into a running agent as stations, the way a
//! scanner on a robot would, and prints the reports that come back.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use asbuilt_protocol::ipc::{CellPorts, ServiceNames};
use asbuilt_protocol::{
    FixedText, Paced, PoseMode, PoseSnapshot, StationEvent, StationEventKind, StationReport,
    StationSender, StationStatus,
};
use clap::Args;

use asbuilt_io::stations::{self, Station};

/// `asbuilt publish`'s arguments.
#[derive(Args)]
pub struct PublishArgs {
    /// Stations file: [[station]] with id, scan, and a pose (translation, rotation_xyzw) unless
    /// the scan file holds one.
    /// With --ros2, the clouds of each station: [[station]] with id, from and to (seconds).
    #[arg(long, required_unless_present_any = ["files", "ros2"])]
    stations: Option<PathBuf>,
    /// A ROS 2 bag as the scans.
    #[command(flatten)]
    ros2: crate::ros2_args::Ros2Args,
    /// Scan files that hold their poses (E57, PTX, LAS): every scan in them is a station, in
    /// order, with the file's pose.
    files: Vec<PathBuf>,
    /// Service prefix of the agent (its services.prefix).
    #[arg(long, default_value = "asbuilt")]
    prefix: String,
    /// The job's number and start.
    #[command(flatten)]
    job: crate::job_args::JobIdentity,
    /// Points per scan chunk.
    #[arg(long, default_value_t = 16_384)]
    chunk_points: usize,
    /// Points per second to send (a Z+F IMAGER delivers about 1000000), or `max`.
    #[arg(long, default_value = "max")]
    rate: String,
    /// Seconds to wait for the agent to come up, and then for each report.
    #[arg(long, default_value_t = 30.0)]
    wait: f64,
    /// Tries at a station: one the agent reports interrupted (it was started again while the
    /// station was sending) is sent again, as its next attempt, up to this many times.
    #[arg(long, default_value_t = 5)]
    attempts: u8,
}

pub(crate) fn parse_rate(s: &str) -> Result<Option<f64>> {
    if s == "max" {
        return Ok(None);
    }
    let r: f64 = s
        .parse()
        .ok()
        .filter(|r: &f64| *r > 0.0 && r.is_finite())
        .with_context(|| format!("--rate {s:?}: give points per second (e.g. 1000000) or max"))?;
    Ok(Some(r))
}

/// The stations of a bag, a stations file or scan files, whichever was given.
fn stations_of(args: &PublishArgs) -> Result<Vec<Station>> {
    if !args.files.is_empty() && (args.stations.is_some() || args.ros2.ros2.is_some()) {
        bail!("give scan files, --stations FILE or --ros2 BAG, one of them");
    }
    let bag = args.ros2.stations(args.stations.as_deref())?;
    Ok(match (bag, &args.stations) {
        (Some(bag), _) => bag,
        (None, Some(path)) => stations::load(path)?,
        (None, None) => stations::from_files(&args.files)?,
    })
}

/// Streams the stations' scans into a running agent and waits for its reports.
pub fn run(mut args: PublishArgs) -> Result<ExitCode> {
    let rate = parse_rate(&args.rate)?;
    if args.chunk_points == 0 {
        bail!("--chunk-points must be at least 1");
    }
    let stations = stations_of(&args)?;
    // One start for the whole job, also for the stations sent again.
    args.job.job_started_ns = Some(args.job.started_ns());
    let number = args.job.number;
    let names = ServiceNames::new(&args.prefix);
    let wait = Duration::from_secs_f64(args.wait);
    let (_node, ports) = CellPorts::connect(&names, args.chunk_points, wait)?;
    eprintln!(
        "publishing {} stations to {}/… ({} points per chunk, rate {})",
        stations.len(),
        names.prefix,
        args.chunk_points,
        args.rate
    );

    if args.attempts == 0 {
        bail!("--attempts must be at least 1");
    }
    let started = Instant::now();
    let mut sent_points = 0u64;
    let mut reports = Vec::new();
    let job = Job {
        args: &args,
        stations: &stations,
        ports: &ports,
        rate,
        started,
    };
    let send = |station: u32, attempt: u8, sent_points: &mut u64| -> Result<()> {
        *sent_points += job.send(station, attempt, *sent_points)?;
        Ok(())
    };
    for station in 0..stations.len() as u32 {
        send(station, 1, &mut sent_points)?;
        collect_reports(&ports, number, &mut reports, Duration::ZERO)?;
    }
    let expected = stations.len();
    // The attempt of each station sent last: reports of earlier ones (published again by an
    // agent that resumed) no longer count.
    let mut sent = vec![1u8; expected];
    let mut deadline = Instant::now() + wait;
    let mut changed = Instant::now();
    loop {
        reports.retain(|r| {
            sent.get(r.station as usize)
                .is_some_and(|&a| r.attempt.max(1) >= a)
        });
        // A station reported interrupted goes again, as its next attempt.
        let again: Vec<(u32, u8)> = reports
            .iter()
            .filter(|r| r.status() == Some(StationStatus::Interrupted))
            .filter(|r| r.attempt.max(1) < args.attempts)
            .map(|r| (r.station, r.attempt.max(1) + 1))
            .collect();
        for &(station, attempt) in &again {
            eprintln!(
                "station {} attempt {} was interrupted: sending it again as attempt {attempt}",
                stations[station as usize].id,
                attempt - 1
            );
            reports.retain(|r| r.station != station);
            sent[station as usize] = attempt;
            send(station, attempt, &mut sent_points)?;
            deadline = Instant::now() + wait;
        }
        // A report that is not complete may be the history's, of a cell before this one: the
        // agent's report of this send follows it within a moment.
        let settled = reports
            .iter()
            .all(|r| r.status() == Some(StationStatus::Complete))
            || changed.elapsed() >= HISTORY_GRACE;
        if reports.len() >= expected && again.is_empty() && settled || Instant::now() >= deadline {
            break;
        }
        let before = reports.clone();
        collect_reports(&ports, number, &mut reports, Duration::from_millis(100))?;
        if reports != before {
            changed = Instant::now();
        }
    }
    tell_rate("sent", sent_points, started, reports.len(), expected);
    Ok(reports_verdict(expected, &reports, args.wait))
}

/// What sending a station needs: the command's arguments, the stations, the cell's ports and
/// the pace.
struct Job<'a> {
    args: &'a PublishArgs,
    stations: &'a [Station],
    ports: &'a CellPorts,
    rate: Option<f64>,
    started: Instant,
}

impl Job<'_> {
    /// Sends attempt `attempt` of `station` (`sent_before` points sent so far, for the pace);
    /// returns the points sent.
    fn send(&self, station: u32, attempt: u8, sent_before: u64) -> Result<u64> {
        let st = &self.stations[station as usize];
        let file = st.open_scan()?;
        if attempt == 1 {
            eprintln!("station {}: pose from {}", st.id, st.pose_source);
        }
        let declared = file.scans[st.scan_index].points;
        let chunks = declared.map_or(0, |n| n.div_ceil(self.args.chunk_points as u64));
        let mut begin = StationEvent::new(StationEventKind::Begin, self.args.job.number, station);
        begin.job_started_ns = self.args.job.started_ns();
        begin.name = FixedText::truncated(&st.id);
        begin.expected_chunks = chunks as u32;
        begin.expected_points = declared.unwrap_or(0);
        begin.attempt = attempt;
        let mut pose = PoseSnapshot::new(self.args.job.number, station, PoseMode::DesignScanner);
        pose.translation = st.translation;
        pose.rotation_xyzw = st.rotation_xyzw;
        pose.position_sigma = st.position_sigma;
        let mut sink = Paced::new(self.ports, self.rate, self.started, sent_before);
        let mut sender = StationSender::start(begin, pose, &mut sink)?;
        file.stream(st.scan_index, self.args.chunk_points, &mut |chunk| {
            Ok(sender.chunk(chunk, &mut sink)?)
        })?;
        let sent = sender.points_sent();
        sender.finish(&mut sink)?;
        Ok(sent)
    }
}

/// How long a station's report that is not complete is waited on for a newer one.
const HISTORY_GRACE: Duration = Duration::from_secs(1);

/// Prints how many points went out how fast, and how many stations have reported. Shared with
/// `replay`.
pub(crate) fn tell_rate(verb: &str, points: u64, started: Instant, back: usize, of: usize) {
    let secs = started.elapsed().as_secs_f64();
    eprintln!(
        "{verb} {points} points in {secs:.2} s ({:.2} M points/s); {back} of {of} reports back",
        points as f64 / secs / 1e6,
    );
}

/// Exit code 1, with what went wrong, when a station got no report within `wait` seconds or
/// reported incomplete; success otherwise. Shared with `replay`.
pub(crate) fn reports_verdict(expected: usize, reports: &[StationReport], wait: f64) -> ExitCode {
    if reports.len() < expected {
        eprintln!(
            "error: {} station(s) got no report within {wait:.0} s",
            expected - reports.len(),
        );
        return ExitCode::from(1);
    }
    let incomplete = reports
        .iter()
        .filter(|r| r.status() != Some(StationStatus::Complete))
        .count();
    if incomplete > 0 {
        eprintln!("error: {incomplete} station(s) reported incomplete");
        return ExitCode::from(1);
    }
    ExitCode::SUCCESS
}

/// Takes the reports of `job` that are news (see `CellPorts::take_reports`) and prints them.
pub(crate) fn collect_reports(
    ports: &CellPorts,
    job: u64,
    reports: &mut Vec<StationReport>,
    wait: Duration,
) -> Result<()> {
    for r in ports.take_reports(job, reports, wait)? {
        println!(
            "station {:<12} {:?}: {} points, {} matched, median |d| {:.3} mm, p95 {:.3} mm",
            r.name.as_str(),
            r.status().unwrap_or(StationStatus::Incomplete),
            r.points_received,
            r.stats.count,
            r.stats.median_abs * 1e3,
            r.stats.p95_abs * 1e3
        );
    }
    Ok(())
}
