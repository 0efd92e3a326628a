//! Sustained throughput of the real agent process over iceoryx2 with C2M on the Stanford bunny
//! (69,451 triangles), and the delay from a station's last chunk to its report.
//!
//! `cargo bench -p asbuilt-agent --bench throughput` (add `-- --quick` for one round, or
//! `-- --recorder N` for only the recorder's alternating rounds, N of them: its cost is a few
//! per cent on a noisy machine, so it wants more rounds than the rest). `ASBUILT_AGENT=PATH`
//! runs another build of the agent (a saved copy of the one before a change) under the same
//! benchmark, so two builds can be run in turn in one sitting.
//!
//! - max rate: the publisher sends as fast as the agent takes chunks (it is held back when the
//!   agent's queue is full), so points / (report time - first send) is the agent's sustained rate.
//! - paced at 1 and 2 M points/s (the scanner's rate and twice it): the report delay is measured
//!   from the moment the last chunk was handed over (End follows at once), with the agent
//!   keeping up, so it includes processing that last chunk.
//!
//! - recorder on / off: a second agent with `[recorder]` on takes the same max-rate stations,
//!   alternating round by round with the first, so machine noise hits both; the ratio of their
//!   medians is the recorder's cost, and so is the median of each round's own ratio. The writer
//!   thread's CPU a point (from Linux's `/proc`) is printed too: noise moves it far less than
//!   the rates. So is each agent's CPU a point over the rounds, whole and for its event loop
//!   and writer: the agent at full rate keeps both cores busy, so what the recorder adds in CPU
//!   is most of its cost, and the rest is time the cores spent idle. Afterwards its recording
//!   is read back and its scan chunks counted against those sent.
//! - Foxglove channels: a third agent records with `foxglove = true` too (the design, frames,
//!   deviation-coloured points, JSON reports), in the same alternating rounds.
//!
//! Points: the bunny surface in scan-like order, plus Gaussian noise of σ 0.5 mm per axis, 65,536 per
//! chunk, 4 M per station. Every round checks that the report is complete and nothing was dropped.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use asbuilt_core::{Design, Units};
use asbuilt_protocol::ipc::{CellPorts, Ipc};
use asbuilt_protocol::{
    ChunkHeader, PoseMode, PoseSnapshot, ScanPoint, StationEvent, StationEventKind, StationReport,
    StationStatus,
};
use iceoryx2::prelude::*;

const STATION_POINTS: usize = 4 << 20;

#[path = "../../core/benches/support/points.rs"]
mod points;
mod support;
use support::{AgentProcess, AgentSetup, CHUNK, cell_ports, median};

fn surface_points(design: &Design, n: usize) -> Vec<ScanPoint> {
    points::noisy_surface_points(design, n)
        .iter()
        .map(|p| ScanPoint::new(p.x as f32, p.y as f32, p.z as f32))
        .collect()
}

/// Sends one station; returns (first send, last chunk handed over, report).
fn station(
    cell: &CellPorts,
    station: u32,
    points: &[ScanPoint],
    rate: Option<f64>,
) -> (Instant, Instant, Instant, StationReport) {
    let chunks = points.len().div_ceil(CHUNK);
    let mut begin = StationEvent::new(StationEventKind::Begin, 1, station);
    begin.expected_chunks = chunks as u32;
    cell.send_event(&begin).unwrap();
    cell.send_pose(&PoseSnapshot::new(1, station, PoseMode::DesignScanner))
        .unwrap();
    let start = Instant::now();
    let mut sent = 0usize;
    let mut last = start;
    for (seq, c) in points.chunks(CHUNK).enumerate() {
        let h = ChunkHeader::new(1, station, seq as u64, c.len() as u32);
        cell.send_chunk(&h, c).unwrap();
        last = Instant::now();
        sent += c.len();
        while let Ok(Some(_)) = cell.deviations.receive() {}
        if seq + 1 == chunks {
            break;
        }
        if let Some(rate) = rate {
            let due = start + Duration::from_secs_f64(sent as f64 / rate);
            while Instant::now() < due {
                while let Ok(Some(_)) = cell.deviations.receive() {}
                std::thread::sleep(Duration::from_micros(200));
            }
        }
    }
    let mut end = StationEvent::new(StationEventKind::End, 1, station);
    end.expected_chunks = chunks as u32;
    cell.send_event(&end).unwrap();
    loop {
        while let Ok(Some(_)) = cell.deviations.receive() {}
        if let Some(r) = cell.reports.receive().unwrap() {
            let r = *r.payload();
            if r.station == station {
                return (start, last, Instant::now(), r);
            }
        }
        let _ = cell.wait_for_output(Duration::from_millis(100));
    }
}

/// The agent, the same agent with the recorder on, and with Foxglove's channels too, on their
/// own prefixes.
fn start_agents(
    dir: &Path,
    mesh: &Path,
    prefix: &str,
    rec_prefix: &str,
    fox_prefix: &str,
) -> (AgentProcess, AgentProcess, AgentProcess) {
    let setup = AgentSetup {
        dir,
        design: mesh,
        max_distance: 0.005,
    };
    let status = "[status]\nperiod_s = 1.0\n";
    (
        setup.start("agent", prefix, status, false),
        setup.start(
            "agent-rec",
            rec_prefix,
            &format!("{status}[recorder]\ndir = \"recordings\"\n"),
            true,
        ),
        setup.start(
            "agent-fox",
            fox_prefix,
            &format!("{status}[recorder]\ndir = \"recordings-fox\"\nfoxglove = true\n"),
            true,
        ),
    )
}

/// The files a recording agent left in `dir`: how many, their bytes, and the scan and
/// deviation chunks they hold.
fn count_recorded(dir: &Path) -> (usize, u64, usize, usize) {
    let files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        // The folder also keeps the design index cache.
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    let mut chunks = 0usize;
    let mut deviations = 0usize;
    let mut bytes = 0u64;
    for f in &files {
        let b = std::fs::read(f).unwrap();
        bytes += b.len() as u64;
        for m in asbuilt_protocol::recording::messages(&b).unwrap() {
            match m.unwrap().1 {
                asbuilt_protocol::recording::Recorded::Chunk(..) => chunks += 1,
                asbuilt_protocol::recording::Recorded::Deviations(..) => deviations += 1,
                _ => {}
            }
        }
    }
    (files.len(), bytes, chunks, deviations)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    let recorder_rounds = args.iter().position(|a| a == "--recorder").map(|i| {
        match args.get(i + 1).and_then(|n| n.parse::<usize>().ok()) {
            Some(n) if n > 0 => n,
            _ => panic!("--recorder takes a number of rounds, such as --recorder 15"),
        }
    });
    let rounds = if quick { 1 } else { 5 };
    let recorder_rounds_n = recorder_rounds.unwrap_or(rounds);
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    let mesh = data.join("stanford-bunny/bun_zipper.ply");
    let design =
        asbuilt_io::read_design(&mesh, Units::Metres).expect("the bunny in ../shared/data");
    let points = surface_points(&design, STATION_POINTS);

    let dir = tempfile::tempdir().unwrap();
    let prefix = format!("asbuilt-bench/{}", std::process::id());
    let rec_prefix = format!("{prefix}-rec");
    let fox_prefix = format!("{prefix}-fox");
    let (agent, rec_agent, fox_agent) =
        start_agents(dir.path(), &mesh, &prefix, &rec_prefix, &fox_prefix);
    set_log_level_from_env_or(LogLevel::Error);
    let node = NodeBuilder::new().create::<Ipc>().unwrap();
    let cell = cell_ports(&node, &prefix);
    let rec_cell = cell_ports(&node, &rec_prefix);
    let fox_cell = cell_ports(&node, &fox_prefix);
    let mut next = 0u32;
    let mut run_on = |cell: &CellPorts, rate: Option<f64>| {
        let (start, last, done, r) = station(cell, next, &points, rate);
        next += 1;
        assert_eq!(r.status(), Some(StationStatus::Complete), "{r:?}");
        assert_eq!(r.points_received, points.len() as u64);
        (
            points.len() as f64 / done.duration_since(start).as_secs_f64(),
            done.duration_since(last).as_secs_f64() * 1e3,
        )
    };
    let mut run = |rate: Option<f64>| run_on(&cell, rate);
    run(None); // warm-up: page in the shared-memory pools

    println!(
        "agent throughput, bunny C2M, {} points per station, {} per chunk, {} round(s)",
        points.len(),
        CHUNK,
        recorder_rounds_n
    );
    let paced = [
        ("max rate", None),
        ("paced 1 M/s", Some(1e6)),
        ("paced 2 M/s", Some(2e6)),
    ];
    for (label, rate) in paced.into_iter().filter(|_| recorder_rounds.is_none()) {
        let results: Vec<(f64, f64)> = (0..rounds).map(|_| run(rate)).collect();
        let rate_med = median(results.iter().map(|r| r.0).collect());
        let delay_med = median(results.iter().map(|r| r.1).collect());
        let delay_max = results.iter().map(|r| r.1).fold(0.0, f64::max);
        println!(
            "{label:>12}: {:.2} M points/s end to end (median); report {:.1} ms after the last \
             chunk (median, max {:.1} ms)",
            rate_med / 1e6,
            delay_med,
            delay_max
        );
    }
    recorder_cost(
        &mut run_on,
        [&cell, &rec_cell, &fox_cell],
        agent.0.id(),
        [rec_agent, fox_agent],
        dir.path(),
        points.len(),
        recorder_rounds_n,
    );
    // Nothing dropped anywhere: the last status counts every input and output loss.
    print_last_status(&cell);
}

/// The same max-rate stations through the agent without a recorder, with one, and with
/// Foxglove's channels too, in alternating rounds; then what each recording kept.
fn recorder_cost(
    run_on: &mut impl FnMut(&CellPorts, Option<f64>) -> (f64, f64),
    [cell, rec_cell, fox_cell]: [&CellPorts; 3],
    off_pid: u32,
    [rec_agent, fox_agent]: [AgentProcess; 2],
    dir: &Path,
    station_points: usize,
    rounds: usize,
) {
    // Warm-up of the recording agents.
    run_on(rec_cell, None);
    run_on(fox_cell, None);
    let pids = [off_pid, rec_agent.0.id(), fox_agent.0.id()];
    let cpu_before = pids.map(cpu_s);
    let (mut off, mut on, mut fox) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..rounds {
        off.push(run_on(cell, None));
        on.push(run_on(rec_cell, None));
        fox.push(run_on(fox_cell, None));
    }
    print_cpu(cpu_before, pids.map(cpu_s), rounds * station_points);
    // The report's delay after the last chunk: a recording agent publishes a report once the
    // recorder has it on disk, so a writer that falls behind shows here.
    let delays = |r: &[(f64, f64)]| median(r.iter().map(|r| r.1).collect());
    println!(
        "report {:.1} ms after the last chunk without the recorder, {:.1} ms with it, {:.1} ms \
         with Foxglove's channels (medians)",
        delays(&off),
        delays(&on),
        delays(&fox)
    );
    // Each round's own cost too, against the same round's run without the recorder, just before:
    // the two share the machine's state of the moment, which a ratio of medians mixes.
    let paired = |with: &[(f64, f64)]| {
        let costs = off.iter().zip(with).map(|(o, w)| 100.0 * (1.0 - w.0 / o.0));
        median(costs.collect())
    };
    let (paired_on, paired_fox) = (paired(&on), paired(&fox));
    let rates = |r: Vec<(f64, f64)>| median(r.into_iter().map(|r| r.0).collect());
    let (off, on, fox) = (rates(off), rates(on), rates(fox));
    println!(
        "recorder off {:.2} M points/s, on {:.2} M points/s, with Foxglove's channels {:.2} M \
         points/s (medians, alternating rounds): the recorder costs {:.1} %, with Foxglove's \
         channels {:.1} %",
        off / 1e6,
        on / 1e6,
        fox / 1e6,
        100.0 * (1.0 - on / off),
        100.0 * (1.0 - fox / off)
    );
    println!(
        "round by round: the recorder costs {paired_on:.1} %, with Foxglove's channels \
         {paired_fox:.1} % (medians of each round's cost against its run without the recorder)"
    );
    let recorded_stations = rounds + 1;
    // Stop the recording agents so they close their files, then count what they kept.
    for (agent, sub) in [(rec_agent, "recordings"), (fox_agent, "recordings-fox")] {
        // Before the stop: the writer's CPU while the stations ran, which machine noise moves
        // far less than the rates.
        if let Some(cpu) = cpu_s(agent.0.id()).writer {
            println!(
                "{sub}: the writer thread used {:.1} ns of CPU a point",
                cpu * 1e9 / (recorded_stations * station_points) as f64
            );
        }
        let _ = Command::new("kill")
            .arg("-TERM")
            .arg(agent.0.id().to_string())
            .status();
        let mut agent = agent;
        let _ = agent.0.wait();
        let (files, bytes, chunks, deviations) = count_recorded(&dir.join(sub));
        let sent = recorded_stations * station_points.div_ceil(CHUNK);
        println!(
            "{sub}: {} file(s), {:.0} MB, {chunks} of {sent} scan chunks and {deviations} \
             deviation chunks kept",
            files,
            bytes as f64 / 1e6
        );
    }
}

/// An agent's CPU seconds so far (user and system), from Linux's `/proc`: the whole process,
/// its event loop (the main thread) and the recorder's writer (the thread named `recorder`).
#[derive(Debug, Clone, Copy, Default)]
struct Cpu {
    process: Option<f64>,
    event_loop: Option<f64>,
    writer: Option<f64>,
}

/// Seconds of CPU in a `/proc/.../stat` file's text; None elsewhere.
fn stat_cpu_s(stat: &str) -> Option<f64> {
    // Fields after the command's closing parenthesis: utime and stime are the 12th and 13th,
    // in clock ticks.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    // SAFETY: sysconf only reads a configuration value.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    Some(ticks / hz)
}

fn cpu_s(pid: u32) -> Cpu {
    let read = |path: std::path::PathBuf| std::fs::read_to_string(path).ok();
    let mut cpu = Cpu {
        process: read(format!("/proc/{pid}/stat").into()).and_then(|s| stat_cpu_s(&s)),
        event_loop: read(format!("/proc/{pid}/task/{pid}/stat").into())
            .and_then(|s| stat_cpu_s(&s)),
        writer: None,
    };
    for task in std::fs::read_dir(format!("/proc/{pid}/task"))
        .into_iter()
        .flatten()
        .flatten()
    {
        if read(task.path().join("comm")).is_some_and(|c| c.trim() == "recorder") {
            cpu.writer = read(task.path().join("stat")).and_then(|s| stat_cpu_s(&s));
        }
    }
    cpu
}

/// The CPU each agent spent a point over the alternating rounds, whole and by thread: beside
/// the rates, which the machine's noise moves by several per cent, a steadier measure of what
/// the recorder adds.
fn print_cpu(before: [Cpu; 3], after: [Cpu; 3], points: usize) {
    let ns = |a: Option<f64>, b: Option<f64>| Some((b? - a?) * 1e9 / points as f64);
    let show = |v: Option<f64>| v.map_or("?".to_string(), |v| format!("{v:.1} ns"));
    let mut whole = [None; 3];
    for (i, label) in [
        "no recorder",
        "recorder",
        "recorder with Foxglove's channels",
    ]
    .into_iter()
    .enumerate()
    {
        let (b, a) = (before[i], after[i]);
        whole[i] = ns(b.process, a.process);
        println!(
            "CPU a point, {label}: {} (event loop {}, writer {})",
            show(whole[i]),
            show(ns(b.event_loop, a.event_loop)),
            show(ns(b.writer, a.writer))
        );
    }
    if let [Some(off), Some(on), Some(fox)] = whole {
        println!(
            "the recorder adds {:.1} % of CPU, with Foxglove's channels {:.1} %",
            100.0 * (on / off - 1.0),
            100.0 * (fox / off - 1.0)
        );
    }
}

/// The agent's last status over three seconds, with what it dropped, if anything.
fn print_last_status(cell: &CellPorts) {
    let deadline = Instant::now() + Duration::from_secs(3);
    let mut status = None;
    while Instant::now() < deadline {
        while let Some(s) = cell.status.receive().unwrap() {
            status = Some(*s.payload());
        }
        while let Ok(Some(_)) = cell.deviations.receive() {}
        std::thread::sleep(Duration::from_millis(50));
    }
    let s = status.expect("the agent publishes its status");
    println!(
        "agent status: {} points, rejected {}, input drops {:?}, output drops {:?}",
        s.points_processed,
        s.rejected_points.total(),
        s.input,
        s.output
    );
}
