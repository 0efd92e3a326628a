//! Scanning while printing, against the real agent over iceoryx2: the simulated line profiler
//! sends every layer of the column as a pass (the robot's mount poses and the profiles, the
//! profiler's clock 5 ms behind the robot's, as the agent's `[profiler]` says). Every profile
//! is placed, each layer is judged as it is laid, and a 5 mm lateral shift from layer 20 is
//! read in the layers printed after it and nowhere before; `asbuilt report` on the recording
//! judges the passes again from the recorded poses and profiles, the same.

use asbuilt_protocol::StationStatus;
use asbuilt_sim::{JobSpec, PartSpec, ProfilerSpec};
use asbuilt_tests::{Agent, Cell, unique_prefix};

const AGENT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt-agent");
const ASBUILT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt");

/// The robot's clock less the profiler's.
const CLOCK_OFFSET_NS: i64 = 5_000_000;

#[test]
fn every_layer_is_judged_as_it_is_laid_and_a_shift_is_read_from_where_it_began() {
    let layers = 24;
    let job = JobSpec {
        part: PartSpec::Column,
        defects: vec!["lateral-shift:from=20,dx=5mm,dy=0".into()],
        rate: None,
        profiler: Some(ProfilerSpec {
            // A coarse line keeps the test short; the placing and the judging are the same.
            points: 64,
            clock_offset_ns: CLOCK_OFFSET_NS,
            layers: Some(layers),
            ..ProfilerSpec::default()
        }),
        ..JobSpec::default()
    }
    .build()
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let stl = dir.path().join("design.stl");
    asbuilt_sim::write_stl(&stl, &job.part.design).unwrap();
    let recording = dir.path().join("recording");
    let config = format!(
        "[design]\npath = {:?}\nunits = \"m\"\n[inspect]\ntolerance = 0.005\n\
         max_distance = 0.03\n[limits]\nmax_points_per_chunk = {}\n[findings]\nenabled = true\n\
         layer_height = {}\n[profiler]\nclock_offset_ns = {CLOCK_OFFSET_NS}\n\
         [recorder]\ndir = {:?}\nmin_free_mb = 16\n",
        stl.display().to_string(),
        job.chunk_capacity(),
        job.part.layer_height,
        recording.display().to_string()
    );
    let prefix = unique_prefix("profiler");
    let mut agent = Agent::start_in(AGENT, &prefix, &config, dir);
    let cell = Cell::open(&prefix, job.chunk_capacity());
    let out = asbuilt_tests::send_job(&job, &agent, &cell, true);

    assert_eq!(out.reports.len(), layers as usize, "{}", agent.log());
    for r in &out.reports {
        assert_eq!(r.status(), Some(StationStatus::Complete), "{}", agent.log());
        // Every profile was placed: none refused for its pose, none in a rejected chunk.
        assert_eq!(
            r.rejected.total(),
            0,
            "pass {}: {:?}",
            r.station,
            r.rejected
        );
        assert!(r.points_received > 10_000, "pass {}", r.station);
        // Points on the as-built surface, placed by interpolated poses: 0.05 mm of noise.
        assert!(
            r.stats.median_abs < 0.5e-3,
            "pass {}: {:?}",
            r.station,
            r.stats
        );
    }
    let log = agent.log();
    assert!(log.contains("0 refused"), "{log}");
    let by_layer = out.findings_by_layer();
    assert_eq!(by_layer.len(), layers as usize);
    // Layers are 0-based here: the shift starts at layer 19 (the 20th).
    let (mut read, mut before) = (0, 0);
    for f in &by_layer {
        assert_eq!(f.stations, 1, "one pass a layer");
        for row in &f.layers {
            let shift = row.shift_xy().unwrap_or([f64::NAN; 2]);
            if row.layer >= 21 {
                let off = (shift[0] - 0.005).hypot(shift[1]);
                assert!(
                    off < 1e-3,
                    "pass {} reads layer {} shifted {shift:?}",
                    f.layer,
                    row.layer
                );
                read += 1;
            } else if row.layer < 17 && shift[0].is_finite() {
                assert!(
                    shift[0].hypot(shift[1]) < 1e-3,
                    "pass {} reads layer {} shifted {shift:?} before the shift",
                    f.layer,
                    row.layer
                );
                before += 1;
            }
        }
    }
    assert!(
        read >= 3 && before > 50,
        "{read} readings after, {before} before"
    );

    // The recording holds the poses and profiles: the report places and judges them again.
    agent.signal("TERM");
    agent.wait_exit(std::time::Duration::from_secs(30));
    let report_dir = tempfile::tempdir().unwrap();
    let report = asbuilt_tests::report_json(ASBUILT, &recording, report_dir.path());
    let stations = report["stations"].as_array().unwrap();
    assert_eq!(stations.len(), layers as usize);
    for (s, r) in stations.iter().zip(&out.reports) {
        assert_eq!(s["points"].as_u64(), Some(r.points_received), "{s}");
        assert_eq!(s["matched"].as_u64(), Some(r.stats.count), "{s}");
    }
}

/// The agent is killed in the middle of a pass and started again: a layer laid cannot be
/// scanned again, so the new agent takes the pass up from its recording and goes on with
/// what the cell sends; no pass is reported interrupted, every layer gets its findings. The
/// profiles sent while no agent ran are lost and counted (the pass ends incomplete, those
/// taken while no pose came refused for the gap).
#[test]
fn a_pass_cut_by_a_restart_is_taken_up_and_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let job = JobSpec {
        part: PartSpec::Column,
        profiler: Some(ProfilerSpec::default()),
        ..JobSpec::default()
    }
    .build()
    .unwrap();
    let stl = dir.path().join("design.stl");
    asbuilt_sim::write_stl(&stl, &job.part.design).unwrap();
    let config = format!(
        "[design]\npath = {:?}\nunits = \"m\"\n[inspect]\ntolerance = 0.005\n\
         max_distance = 0.03\n[limits]\nmax_points_per_chunk = 65536\n[findings]\n\
         enabled = true\nlayer_height = 0.02\n[recorder]\ndir = \"recording\"\n\
         min_free_mb = 16\n",
        stl.display().to_string()
    );
    let prefix = unique_prefix("profiler-restart");
    let mut agent = Agent::start_in(AGENT, &prefix, &config, dir);
    // In real time (a pass of the column's first layers takes 4 s), so the kill lands in a
    // pass: 64 points a profile, four layers.
    let sim = std::process::Command::new(ASBUILT)
        .args([
            "sim", "--prefix", &prefix, "--sensor", "profiler", "--part", "column",
        ])
        .args([
            "--layers",
            "4",
            "--profile-points",
            "64",
            "--rate",
            "1",
            "--findings",
        ])
        .args(["--wait", "60"])
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while !agent.log().contains("job 1 pass 0: profiles since start") {
        assert!(std::time::Instant::now() < deadline, "{}", agent.log());
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    // Pass 1 has begun; halfway through it, the power goes.
    std::thread::sleep(std::time::Duration::from_secs(2));
    agent.kill_and_restart(std::time::Duration::from_millis(300));
    let out = sim.wait_with_output().unwrap();
    let said = String::from_utf8_lossy(&out.stderr);
    let logs = agent.logs();
    assert!(logs.contains("pass 1: taken up from its"), "{logs}");
    for layer in 1..=4 {
        let line = said
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("L{layer:03}-pass")))
            .unwrap_or_else(|| panic!("no report of layer {layer}:\n{said}\n{logs}"));
        assert!(!line.contains("Interrupted"), "{line}\n{logs}");
        if layer != 2 {
            assert!(line.contains("Complete"), "{line}");
        }
    }
    assert!(said.contains("4 report(s), 4 findings"), "{said}");
}
