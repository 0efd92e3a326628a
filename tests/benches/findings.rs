//! What `[findings]` costs the agent: two agent processes on the study wall, one with findings
//! off and one with them on (10 mm design samples, 20 mm layers), take the same scan layer in
//! alternating rounds at full speed: the demo's four stations after 24 layers (simulated Z+F
//! scans, about 600 k points each). Reported: each agent's sustained points/s (median over
//! rounds), the ratio, and how long after a station's report its findings arrive.
//!
//! `cargo bench -p asbuilt-tests --bench findings` (add `-- --quick` for one round). It lives
//! here, beside the end-to-end tests' agent process and cell, because it needs the simulator,
//! which the agent's own crate does not depend on, not even for its benchmarks.

use std::time::{Duration, Instant};

use asbuilt_protocol::ipc::CellPorts;
use asbuilt_protocol::{
    PoseMode, PoseSnapshot, ScanPoint, StationEvent, StationEventKind, StationSender, StationStatus,
};
use asbuilt_sim::{Defect, Part, ScannerModel, as_built, scan, stations_around};
use asbuilt_tests::{Agent, Cell};
use nalgebra::Isometry3;

/// Points per chunk sent, at most.
const CHUNK: usize = 65_536;

const AGENT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt-agent");

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Sends one scan layer; returns points/s from the first send to the last report, and the
/// delays from each report to its findings (ms), when findings come.
fn scan_layer(
    cell: &CellPorts,
    first: u32,
    height: f64,
    stations: &[(Isometry3<f64>, Vec<ScanPoint>)],
    findings: bool,
) -> (f64, Vec<f64>) {
    let start = Instant::now();
    let mut points = 0usize;
    let mut delays = Vec::new();
    for (k, (pose, pts)) in stations.iter().enumerate() {
        let station = first + k as u32;
        let mut begin = StationEvent::new(StationEventKind::Begin, 1, station);
        begin.expected_chunks = pts.len().div_ceil(CHUNK) as u32;
        begin.printed_height = height;
        begin.layer = 23;
        let mut p = PoseSnapshot::new(1, station, PoseMode::DesignScanner);
        p.translation = pose.translation.vector.into();
        let mut sink = cell;
        let mut sender = StationSender::start(begin, p, &mut sink).unwrap();
        for c in pts.chunks(CHUNK) {
            sender.chunk(c, &mut sink).unwrap();
            while let Ok(Some(_)) = cell.deviations.receive() {}
        }
        sender.finish(&mut sink).unwrap();
        points += pts.len();
        // One station at a time, as the robot carries the scanner.
        let mut reported = None;
        loop {
            while let Ok(Some(_)) = cell.deviations.receive() {}
            while let Some(r) = cell.reports.receive().unwrap() {
                let r = *r.payload();
                if r.station == station {
                    assert_eq!(r.status(), Some(StationStatus::Complete), "{r:?}");
                    reported = Some(Instant::now());
                }
            }
            if let Some(at) = reported {
                if !findings {
                    break;
                }
                if let Some(f) = cell.findings.receive().unwrap()
                    && f.user_header().station == station
                {
                    delays.push(at.elapsed().as_secs_f64() * 1e3);
                    break;
                }
            }
            let _ = cell.wait_for_output(Duration::from_millis(20));
        }
    }
    (points as f64 / start.elapsed().as_secs_f64(), delays)
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let rounds = if quick { 1 } else { 5 };
    let part = Part::wall();
    let defects = [Defect::Extrusion {
        first: 2,
        last: 4,
        width: 0.012,
    }];
    let m = as_built(&part, &defects, 24).unwrap();
    let (lo, hi) = part.design.bounds();
    let stations: Vec<(Isometry3<f64>, Vec<ScanPoint>)> =
        stations_around(lo, hi, part.layer_span(23).1, 4, 1.2, 0.5)
            .into_iter()
            .enumerate()
            .map(|(k, pose)| {
                (
                    pose,
                    scan(&m, &pose, &ScannerModel::default(), k as u64).points,
                )
            })
            .collect();
    let total: usize = stations.iter().map(|s| s.1.len()).sum();

    let dir = tempfile::tempdir().unwrap();
    let stl = dir.path().join("wall.stl");
    asbuilt_sim::write_stl(&stl, &part.design).unwrap();
    let start_agent = |name: &str, extra: &str| {
        let prefix = asbuilt_tests::unique_prefix(&format!("bench-findings-{name}"));
        let config = format!(
            "[design]\npath = {:?}\nunits = \"m\"\n[inspect]\ntolerance = 0.005\n\
             max_distance = 0.03\n{extra}",
            stl.display().to_string()
        );
        let agent = Agent::start(AGENT, &prefix, &config);
        let cell = Cell::open(&prefix, CHUNK);
        (agent, cell)
    };
    let (_off_agent, off) = start_agent("off", "");
    let (_on_agent, on) = start_agent("on", "[findings]\nenabled = true\nlayer_height = 0.02\n");
    let (off, on) = (&off.ports, &on.ports);
    let h = part.layer_span(23).1;
    // Warm-up: page in the pools, build the cut and the findings state.
    scan_layer(off, 0, h, &stations, false);
    scan_layer(on, 0, h, &stations, true);
    println!(
        "findings cost, study wall after 24 layers, {} stations, {total} points per round, \
         {rounds} round(s)",
        stations.len()
    );
    let (mut r_off, mut r_on, mut delays) = (Vec::new(), Vec::new(), Vec::new());
    for round in 1..=rounds as u32 {
        let first = round * 10;
        r_off.push(scan_layer(off, first, h, &stations, false).0);
        let (rate, d) = scan_layer(on, first, h, &stations, true);
        r_on.push(rate);
        delays.extend(d);
    }
    let (a, b) = (median(r_off), median(r_on));
    println!(
        "findings off {:.2} M points/s, on {:.2} M points/s (medians, alternating rounds): on \
         runs at {:.0} % of off; findings arrive {:.0} ms after the report (median, max {:.0} ms)",
        a / 1e6,
        b / 1e6,
        100.0 * b / a,
        median(delays.clone()),
        delays.iter().cloned().fold(0.0, f64::max)
    );
}
