//! The real agent in its own process, fed over iceoryx2 by this test process or by
//! `asbuilt publish` in a third one. Every test uses its own service prefix.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use asbuilt_protocol::{
    ChunkHeader, FixedText, PoseMode, PoseSnapshot, ScanPoint, ScanPointFlags, StationEvent,
    StationEventKind, StationReport, StationSender, StationStatus,
};
use asbuilt_tests::{
    Agent, Cell, assert_section_matches, bunny_agent_config, bunny_stations, memory_kib,
    publish_bunny, publish_command, shared_data, unique_prefix, write_box_stl,
};

const AGENT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt-agent");
const ASBUILT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt");
const LONG: Duration = Duration::from_secs(60);

/// A 1 m box from the origin; the scanner frame is the design frame (pose mode 2, identity).
fn box_config(dir: &Path, extra: &str) -> String {
    let stl = dir.join("box.stl");
    write_box_stl(&stl, [0.0; 3], [1.0; 3]);
    format!(
        "[design]\npath = {:?}\nunits = \"m\"\n[inspect]\ntolerance = 0.005\n{extra}",
        stl.display().to_string()
    )
}

/// `n` points 1 mm above the box's top face.
fn top_points(n: usize) -> Vec<ScanPoint> {
    (0..n)
        .map(|i| {
            let u = (i % 997) as f32 / 997.0;
            let v = (i / 997 % 991) as f32 / 991.0;
            ScanPoint::new(0.05 + 0.9 * u, 0.05 + 0.9 * v, 1.001)
        })
        .collect()
}

fn begin(job: u64, station: u32, chunks: u32) -> StationEvent {
    let mut e = StationEvent::new(StationEventKind::Begin, job, station);
    e.name = FixedText::truncated(&format!("s{station}"));
    e.expected_chunks = chunks;
    e
}

fn end(job: u64, station: u32, chunks: u32) -> StationEvent {
    let mut e = StationEvent::new(StationEventKind::End, job, station);
    e.expected_chunks = chunks;
    e
}

fn pose(job: u64, station: u32) -> PoseSnapshot {
    PoseSnapshot::new(job, station, PoseMode::DesignScanner)
}

/// Begin, pose, `chunks` chunks of `points` each, End.
/// A station as a cell sends it: Begin, pose, `chunks` chunks of `points` (the last flagged),
/// End.
fn clean_station(cell: &Cell, job: u64, station: u32, chunks: u32, points: &[ScanPoint]) {
    let mut ports = &cell.ports;
    let mut sender =
        StationSender::start(begin(job, station, chunks), pose(job, station), &mut ports).unwrap();
    for _ in 0..chunks {
        sender.chunk(points, &mut ports).unwrap();
    }
    sender.finish(&mut ports).unwrap();
}

fn report_of(reports: &[StationReport], job: u64, station: u32) -> StationReport {
    *reports
        .iter()
        .find(|r| r.job == job && r.station == station)
        .unwrap_or_else(|| panic!("no report for job {job} station {station} in {reports:?}"))
}

#[test]
fn a_clean_bunny_job_reports_what_inspect_reports_bit_for_bit() {
    let design = shared_data().join("stanford-bunny/bun_zipper.ply");
    let stations = bunny_stations();
    let prefix = unique_prefix("bunny");
    let agent = Agent::start(AGENT, &prefix, &bunny_agent_config(""));
    let cell = Cell::open(&prefix, 16);
    agent.assert_fed(&publish_bunny(ASBUILT, &prefix));
    let reports = cell.reports(10, LONG);
    assert_eq!(reports.len(), 10, "agent log:\n{}", agent.log());

    let out = tempfile::tempdir().unwrap();
    let inspect = Command::new(ASBUILT)
        .arg("inspect")
        .arg("--design")
        .arg(&design)
        .args(["--units", "m", "--max-distance", "0.005"])
        .arg("--stations")
        .arg(&stations)
        .arg("--out")
        .arg(out.path())
        .output()
        .unwrap();
    assert!(inspect.status.success());
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("report.json")).unwrap()).unwrap();
    let sections = json["stations"].as_array().unwrap();
    assert_eq!(sections.len(), 10);
    for (i, st) in sections.iter().enumerate() {
        let r = report_of(&reports, 1, i as u32);
        assert_eq!(r.status(), Some(StationStatus::Complete));
        assert_eq!(st["id"].as_str().unwrap(), r.name.as_str());
        assert_section_matches(st, &r, &format!("station {}", r.name.as_str()));
        assert_eq!(r.chunks.missing, 0);
    }
}

/// A second agent on the same services refuses to start and leaves the first alone.
fn a_second_agent_is_refused(prefix: &str, config: &str, cell: &Cell) {
    let mut second = Agent::start(AGENT, prefix, config);
    let code = second.wait_exit(LONG);
    assert_eq!(code.code(), Some(1));
    assert!(
        second
            .log()
            .contains("another asbuilt-agent is already serving"),
        "{}",
        second.log()
    );
    clean_station(cell, 1, 4, 1, &top_points(100));
    let after = report_of(&cell.reports(1, LONG), 1, 4);
    assert_eq!(after.status(), Some(StationStatus::Complete));
}

#[test]
fn every_bad_input_is_counted_logged_and_survived() {
    let dir = tempfile::tempdir().unwrap();
    let config = box_config(
        dir.path(),
        "[limits]\nmax_points_per_chunk = 1000\npending_chunks = 4\nstation_timeout_s = 1.0\n\
         [status]\nperiod_s = 0.2\n",
    );
    let prefix = unique_prefix("bad-input");
    let agent = Agent::start_in(AGENT, &prefix, &config, dir);
    let cell = Cell::open(&prefix, 2000);
    let p = &cell.ports;

    // Station 1: one chunk of each kind of trouble, and good chunks around them.
    p.send_event(&begin(1, 1, 0)).unwrap();
    p.send_pose(&pose(1, 1)).unwrap();
    let mut messy = top_points(100);
    messy[0].xyz[1] = f32::NAN;
    messy[1].xyz = [1e7, 0.0, 0.0];
    messy[2].flags = ScanPointFlags(ScanPointFlags::INVALID);
    p.send_chunk(&ChunkHeader::new(1, 1, 0, 100), &messy)
        .unwrap();
    p.send_chunk(&ChunkHeader::new(1, 1, 0, 100), &messy)
        .unwrap(); // repeated
    p.send_chunk(&ChunkHeader::new(1, 1, 1, 0), &[]).unwrap(); // empty
    p.send_chunk(&ChunkHeader::new(1, 1, 2, 1500), &top_points(1500))
        .unwrap(); // oversized
    p.send_chunk(&ChunkHeader::new(1, 1, 3, 50), &top_points(40))
        .unwrap(); // header lies
    let mut future = ChunkHeader::new(1, 1, 4, 100);
    future.version = 9;
    p.send_chunk(&future, &top_points(100)).unwrap();
    p.send_chunk(&ChunkHeader::new(1, 1, 5, 100), &top_points(100))
        .unwrap();
    p.send_event(&end(1, 1, 6)).unwrap();

    // A pose that is not a rotation, an End and an event kind nobody knows, a chunk for a
    // station that never begins.
    let mut bad_pose = pose(1, 2);
    bad_pose.rotation_xyzw = [0.0, 0.0, 0.0, 2.0];
    p.send_pose(&bad_pose).unwrap();
    p.send_event(&end(1, 88, 1)).unwrap();
    let mut odd = begin(1, 89, 0);
    odd.kind = 7;
    p.send_event(&odd).unwrap();
    p.send_chunk(&ChunkHeader::new(1, 77, 0, 10), &top_points(10))
        .unwrap();

    let messy_report = report_of(&cell.reports(1, LONG), 1, 1);
    assert_eq!(messy_report.status(), Some(StationStatus::Incomplete));
    let rej = messy_report.rejected;
    assert_eq!(
        (rej.non_finite, rej.out_of_range, rej.scanner_invalid),
        (1, 1, 1)
    );
    assert_eq!(rej.in_rejected_chunks, 100 + 1500 + 40);
    assert_eq!(messy_report.stats.count, 97 + 100, "every good point kept");
    assert_eq!(messy_report.chunks.missing, 1, "the unreadable chunk 4");
    assert_eq!(
        (messy_report.chunks.empty, messy_report.chunks.oversized),
        (1, 1)
    );
    assert!((messy_report.stats.mean - 0.001).abs() < 1e-6);

    // After the station timeout the stray chunk is given up; the agent still serves.
    let status = cell
        .status_where(LONG, |s| s.input.chunks_unknown_station == 1)
        .unwrap_or_else(|| panic!("no status counted the stray chunk; log:\n{}", agent.log()));
    let i = status.input;
    assert_eq!(
        (
            i.chunks_duplicate,
            i.chunks_empty,
            i.chunks_oversized,
            i.chunks_malformed,
            i.version_mismatch,
            i.poses_invalid,
            i.events_invalid,
        ),
        (1, 1, 1, 1, 1, 1, 2)
    );
    clean_station(&cell, 1, 3, 2, &top_points(100));
    let good = report_of(&cell.reports(1, LONG), 1, 3);
    assert_eq!(good.status(), Some(StationStatus::Complete));
    assert_eq!(good.stats.count, 200);

    a_second_agent_is_refused(&prefix, &config, &cell);

    let log = agent.log();
    for line in [
        "declares 50 points but carries 40",
        "chunk 0 repeated",
        "more than limits.max_points_per_chunk",
        "ChunkHeader.v2 version 9 cannot be read",
        "pose rejected",
        "End for a station that is not open",
        "unknown kind 7",
        "station 77: chunk 0 dropped, the station never began",
    ] {
        assert!(log.contains(line), "log lacks {line:?}:\n{log}");
    }
    assert!(!log.contains("panicked"), "{log}");
}

/// A stations file with one scan of `n` points on the box top, scanner frame = design frame.
fn box_station_file(dir: &Path, n: usize) -> PathBuf {
    let scan = dir.join("top.xyz");
    let text: String = top_points(n)
        .iter()
        .map(|p| format!("{} {} {}\n", p.xyz[0], p.xyz[1], p.xyz[2]))
        .collect();
    std::fs::write(&scan, text).unwrap();
    let stations = dir.join("stations.toml");
    std::fs::write(
        &stations,
        "[[station]]\nid = \"top\"\nscan = \"top.xyz\"\ntranslation = [0.0, 0.0, 0.0]\n\
         rotation_xyzw = [0.0, 0.0, 0.0, 1.0]\n",
    )
    .unwrap();
    stations
}

#[test]
fn a_killed_publisher_times_out_and_a_restarted_one_is_served() {
    let dir = tempfile::tempdir().unwrap();
    let config = box_config(
        dir.path(),
        "[limits]\nstation_timeout_s = 1.0\n[status]\nperiod_s = 0.2\n",
    );
    let stations = box_station_file(dir.path(), 100_000);
    let prefix = unique_prefix("killed-publisher");
    let agent = Agent::start_in(AGENT, &prefix, &config, dir);
    let cell = Cell::open(&prefix, 16);

    let mut slow = publish_command(ASBUILT, &stations, &prefix)
        .args(["--chunk-points", "1000", "--rate", "20000", "--job", "1"])
        .stderr(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Let it get some chunks through, then kill it mid-station.
    let start = Instant::now();
    let mut seen = 0;
    while seen < 5000 && start.elapsed() < LONG {
        seen += cell.drain_deviations();
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(
        seen >= 5000,
        "publisher never got going; log:\n{}",
        agent.log()
    );
    slow.kill().unwrap();
    slow.wait().unwrap();

    let partial = report_of(&cell.reports(1, LONG), 1, 0);
    assert_eq!(partial.status(), Some(StationStatus::TimedOut));
    assert!(partial.stats.count >= 5000 && partial.stats.count < 100_000);
    assert_eq!(partial.stats.count, partial.points_received);

    // A new cell process continues the same job: it sends the station anew (as its first
    // attempt, knowing nothing of the dead one's), and the agent serves it again.
    let again = publish_command(ASBUILT, &stations, &prefix)
        .args(["--job", "1"])
        .output()
        .unwrap();
    agent.assert_fed(&again);
    let full = report_of(&cell.reports(1, LONG), 1, 0);
    assert_eq!(full.status(), Some(StationStatus::Complete));
    assert_eq!(full.stats.count, 100_000);
    // Any agent cleans up every dead node it finds: one of another test's agents, started at
    // the same time, may have done it first; then no dead node is left.
    let no_dead_node = || {
        use iceoryx2::prelude::*;
        let mut dead = 0;
        Node::<asbuilt_protocol::ipc::Ipc>::list(Config::global_config(), |n| {
            dead += usize::from(matches!(n, NodeState::Dead(_)));
            CallbackProgression::Continue
        })
        .unwrap();
        dead == 0
    };
    let start = Instant::now();
    let mut cleaned = false;
    while !cleaned && start.elapsed() < LONG {
        cleaned = cell
            .status_where(Duration::from_millis(500), |s| s.dead_nodes_cleaned >= 1)
            .is_some()
            || no_dead_node();
    }
    assert!(
        cleaned,
        "the dead publisher's node was never cleaned up; log:\n{}",
        agent.log()
    );
}

#[test]
fn sigterm_mid_station_sends_a_partial_report_and_a_new_agent_takes_over() {
    let dir = tempfile::tempdir().unwrap();
    let config = box_config(dir.path(), "");
    let prefix = unique_prefix("sigterm");
    let mut agent = Agent::start_in(AGENT, &prefix, &config, dir);
    let cell = Cell::open(&prefix, 1000);
    let p = &cell.ports;
    p.send_event(&begin(1, 0, 10)).unwrap();
    p.send_pose(&pose(1, 0)).unwrap();
    for s in 0..5 {
        p.send_chunk(&ChunkHeader::new(1, 0, s, 100), &top_points(100))
            .unwrap();
    }
    let start = Instant::now();
    let mut seen = 0;
    while seen < 500 && start.elapsed() < LONG {
        seen += cell.drain_deviations();
    }
    assert_eq!(seen, 500);
    agent.signal("TERM");
    let status = agent.wait_exit(LONG);
    assert!(status.success(), "exit {status:?}; log:\n{}", agent.log());
    let r = report_of(&cell.reports(1, LONG), 1, 0);
    assert_eq!(r.status(), Some(StationStatus::Partial));
    assert_eq!(r.stats.count, 500);
    assert!(agent.log().contains("stop requested"), "{}", agent.log());

    // A new agent on the same services serves new stations; so does one after a crash.
    for crash in [false, true] {
        let config = box_config(agent.dir.path(), "");
        let mut next = Agent::start(AGENT, &prefix, &config);
        let cell = Cell::open(&prefix, 1000);
        let station = 1 + u32::from(crash);
        clean_station(&cell, 1, station, 2, &top_points(100));
        let r = report_of(&cell.reports(1, LONG), 1, station);
        assert_eq!(r.status(), Some(StationStatus::Complete));
        if crash {
            next.signal("KILL");
            next.wait_exit(LONG);
            let after_crash = Agent::start(AGENT, &prefix, &config);
            let cell = Cell::open(&prefix, 1000);
            clean_station(&cell, 1, 9, 1, &top_points(100));
            let r = report_of(&cell.reports(1, LONG), 1, 9);
            assert_eq!(
                r.status(),
                Some(StationStatus::Complete),
                "{}",
                after_crash.log()
            );
        } else {
            next.signal("TERM");
            assert!(next.wait_exit(LONG).success());
        }
    }
}

#[test]
fn memory_stays_flat_over_twenty_million_points() {
    const STATIONS: u32 = 20;
    const CHUNK: usize = 50_000;
    const CHUNKS: u32 = 20; // 1 M points per station
    let dir = tempfile::tempdir().unwrap();
    let config = box_config(
        dir.path(),
        "[limits]\nmax_points_per_chunk = 50000\nchunk_queue = 8\npending_chunks = 4\n",
    );
    let prefix = unique_prefix("memory");
    let agent = Agent::start_in(AGENT, &prefix, &config, dir);
    let cell = Cell::open(&prefix, CHUNK);
    let points = top_points(CHUNK);

    let mut after_first = None;
    let mut peak_rss = 0;
    for station in 0..STATIONS {
        clean_station(&cell, 1, station, CHUNKS, &points);
        let r = report_of(&cell.reports(1, LONG), 1, station);
        assert_eq!(
            r.status(),
            Some(StationStatus::Complete),
            "station {station}: {r:?}\nlog:\n{}",
            agent.log()
        );
        assert_eq!(r.stats.count, CHUNK as u64 * CHUNKS as u64);
        let (rss, _, _) = memory_kib(agent.pid());
        peak_rss = peak_rss.max(rss);
        if station == 0 {
            after_first = Some(memory_kib(agent.pid()));
        }
    }
    let (rss1, anon1, hwm1) = after_first.unwrap();
    let (rss, anon, hwm) = memory_kib(agent.pid());
    eprintln!(
        "agent memory after station 1: RSS {rss1} KiB (anon {anon1}), peak {hwm1} KiB; after {} M \
         points: RSS {rss} KiB (anon {anon}), peak {hwm} KiB",
        STATIONS as usize * CHUNK * CHUNKS as usize / 1_000_000
    );
    // The heap must not grow at all beyond noise. Total RSS may still rise by the shared-memory
    // pool pages (chunk and deviation samples) that the first station did not happen to touch:
    // those pools are fixed by the configuration, not by the points.
    assert!(
        anon <= anon1 + 1024,
        "heap grew from {anon1} KiB to {anon} KiB"
    );
    let few_mib = 8 * 1024;
    assert!(
        hwm <= hwm1.max(rss1) + few_mib,
        "peak RSS grew from {hwm1} KiB to {hwm} KiB"
    );
}

/// One station of the print started at `started`: Begin, pose, one chunk, End; its report.
fn station_of_print(cell: &Cell, started: u64, station: u32, n: usize) -> StationReport {
    let mut ports = &cell.ports;
    let mut b = begin(1, station, 1);
    b.job_started_ns = started;
    let mut sender = StationSender::start(b, pose(1, station), &mut ports).unwrap();
    sender.chunk(&top_points(n), &mut ports).unwrap();
    sender.finish(&mut ports).unwrap();
    // A restarted agent publishes its reports again: the one of this station is awaited.
    let deadline = Instant::now() + LONG;
    while Instant::now() < deadline {
        let got = cell.reports(1, Duration::from_millis(200));
        if let Some(r) = got
            .into_iter()
            .find(|r| r.station == station && r.points_received == n as u64)
        {
            return r;
        }
    }
    panic!("no report for station {station} of print {started}");
}

/// A cell that starts a new print under job 1 (it restarted, its counter began again) is
/// served afresh, not told that its stations were reported already; the recording keeps each
/// print in its own files, a killed agent resumes the newest print, and `asbuilt report` on the
/// folder reads the newest print alone.
#[test]
fn a_new_print_under_a_used_job_number_is_served_afresh_and_recorded_apart() {
    let dir = tempfile::tempdir().unwrap();
    let config = box_config(dir.path(), &asbuilt_tests::recorder_section("rec"));
    let prefix = unique_prefix("prints");
    let mut agent = Agent::start_in(AGENT, &prefix, &config, dir);
    let cell = Cell::open(&prefix, 1000);
    for station in 0..2 {
        let r = station_of_print(&cell, 1_000, station, 500);
        assert_eq!(r.status(), Some(StationStatus::Complete));
    }
    // The new print's station 0 has the old one's number and attempt: served all the same.
    let r = station_of_print(&cell, 2_000, 0, 700);
    assert_eq!(r.status(), Some(StationStatus::Complete), "{}", agent.log());
    assert_eq!(r.points_received, 700);
    // Killed and started again: the newest print is resumed (its station 0 is over, its
    // station 1 is not), and the new print's files go on from where they were.
    agent.kill_and_restart(Duration::from_millis(100));
    let deadline = Instant::now() + LONG;
    while !agent.log().contains("serving") && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    let again = station_of_print(&cell, 2_000, 1, 900);
    assert_eq!(
        again.status(),
        Some(StationStatus::Complete),
        "{}",
        agent.logs()
    );
    assert!(
        agent
            .logs()
            .contains("a new print under the same number (started at 2000 ns"),
        "{}",
        agent.logs()
    );
    agent.signal("TERM");
    agent.wait_exit(LONG);

    let rec = agent.dir.path().join("rec");
    let mut names: Vec<String> = std::fs::read_dir(&rec)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".mcap"))
        .collect();
    names.sort();
    assert_eq!(names.len(), 3, "{names:?}\n{}", agent.logs());
    assert!(names[2].ends_with("-part2.mcap"), "{names:?}");
    let out = agent.dir.path().join("report");
    let report = Command::new(ASBUILT)
        .arg("report")
        .arg(&rec)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(report.status.success(), "{report:?}");
    let stderr = String::from_utf8_lossy(&report.stderr);
    assert!(stderr.contains("holds 2 prints of job 1"), "{stderr}");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let points: Vec<u64> = json["stations"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["points"].as_u64().unwrap())
        .collect();
    assert_eq!(points, vec![700, 900], "{json:#}");
}

/// A station the cell begins while its agent lies dead (killed, not yet replaced) waits for the
/// agent that replaces it and arrives whole: the dead agent's queues, which iceoryx2 would
/// still deliver to, are removed before the Begin.
#[test]
fn a_station_begun_while_the_agent_is_dead_reaches_its_replacement_whole() {
    let dir = tempfile::tempdir().unwrap();
    let config = box_config(dir.path(), "");
    let prefix = unique_prefix("dead-agent");
    let mut agent = Agent::start_in(AGENT, &prefix, &config, dir);
    let cell = Cell::open(&prefix, 1000);
    clean_station(&cell, 1, 0, 3, &top_points(1000));
    assert_eq!(cell.reports(1, LONG).len(), 1, "{}", agent.log());
    let _ = agent.child.kill();
    let _ = agent.child.wait();
    // The replacement starts while the cell already sends.
    let restart = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(300));
        agent.kill_and_restart(Duration::ZERO);
        agent
    });
    clean_station(&cell, 1, 1, 3, &top_points(1000));
    let agent = restart.join().unwrap();
    let r = report_of(&cell.reports(1, LONG), 1, 1);
    assert_eq!(
        r.status(),
        Some(StationStatus::Complete),
        "{}",
        agent.logs()
    );
    assert_eq!((r.chunks.received, r.chunks.missing), (3, 0));
}
