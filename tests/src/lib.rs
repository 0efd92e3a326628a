//! Harness for the end-to-end tests in `tests/`: a real `asbuilt-agent` process on services
//! named for one test, and the cell's side of those services in the test process.
//!
//! Cargo hands an integration test only the binaries of its own package, so this package
//! builds the shipped `main.rs` files of the agent and the command line again under the names
//! `e2e-asbuilt-agent` and `e2e-asbuilt` (see Cargo.toml): the same source, not a stand-in.

#![warn(missing_docs)]

pub mod fuzz;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use asbuilt_protocol::ipc::{CellPorts, Ipc, ServiceNames};
use asbuilt_protocol::{AgentStatus, StationReport};
use iceoryx2::prelude::*;

/// A service prefix no other test or run uses.
pub fn unique_prefix(test: &str) -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    format!("asbuilt-e2e/{test}-{}-{nanos}", std::process::id())
}

/// The real third-party data beside the repository (`../shared/data`).
pub fn shared_data() -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    assert!(p.is_dir(), "test data not found at {}", p.display());
    p
}

/// Writes a closed axis-aligned box as ASCII STL, in metres, outward normals.
pub fn write_box_stl(path: &Path, min: [f64; 3], max: [f64; 3]) {
    let c = |i: usize| {
        [
            if i & 1 == 0 { min[0] } else { max[0] },
            if i & 2 == 0 { min[1] } else { max[1] },
            if i & 4 == 0 { min[2] } else { max[2] },
        ]
    };
    // Each face as two triangles, counter-clockwise seen from outside.
    let faces = [
        [0, 2, 3, 1], // z-
        [4, 5, 7, 6], // z+
        [0, 1, 5, 4], // y-
        [2, 6, 7, 3], // y+
        [0, 4, 6, 2], // x-
        [1, 3, 7, 5], // x+
    ];
    let mut s = String::from("solid box\n");
    for f in faces {
        for t in [[f[0], f[1], f[2]], [f[0], f[2], f[3]]] {
            s.push_str(" facet normal 0 0 0\n  outer loop\n");
            for v in t {
                let p = c(v);
                s.push_str(&format!("   vertex {} {} {}\n", p[0], p[1], p[2]));
            }
            s.push_str("  endloop\n endfacet\n");
        }
    }
    s.push_str("endsolid box\n");
    std::fs::write(path, s).unwrap();
}

/// A running agent; killed when dropped.
pub struct Agent {
    /// The agent's process.
    pub child: Child,
    /// The service prefix it serves under.
    pub prefix: String,
    /// Its folder: the configuration, the log, the recordings.
    pub dir: tempfile::TempDir,
    log: PathBuf,
    exe: String,
}

impl Agent {
    /// Starts `exe` on a configuration made of `config` plus a `[services]` section for `prefix`.
    pub fn start(exe: &str, prefix: &str, config: &str) -> Agent {
        let dir = tempfile::tempdir().unwrap();
        Self::start_in(exe, prefix, config, dir)
    }

    /// [`Agent::start`] in a folder the test made.
    pub fn start_in(exe: &str, prefix: &str, config: &str, dir: tempfile::TempDir) -> Agent {
        let path = dir.path().join("agent.toml");
        std::fs::write(
            &path,
            format!("{config}\n[services]\nprefix = \"{prefix}\"\n"),
        )
        .unwrap();
        let (child, log) = spawn(exe, dir.path());
        Agent {
            child,
            prefix: prefix.to_string(),
            dir,
            log,
            exe: exe.to_string(),
        }
    }

    /// Kills the agent with SIGKILL, as a power loss or the OOM killer would, waits `pause` and
    /// starts it again in its folder on the same configuration, logging to a new file.
    pub fn kill_and_restart(&mut self, pause: Duration) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        std::thread::sleep(pause);
        let (child, log) = spawn(&self.exe, self.dir.path());
        self.child = child;
        self.log = log;
    }

    /// Every log of this agent's folder (one per start), oldest first.
    pub fn logs(&self) -> String {
        let mut logs: Vec<PathBuf> = std::fs::read_dir(self.dir.path())
            .unwrap()
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with("agent-"))
            })
            .collect();
        logs.sort_by_key(|p| std::fs::metadata(p).and_then(|m| m.modified()).ok());
        logs.iter()
            .map(|p| {
                format!(
                    "==> {} <==\n{}",
                    p.display(),
                    std::fs::read_to_string(p).unwrap_or_default()
                )
            })
            .collect()
    }

    /// The agent's process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Everything the agent has logged so far.
    pub fn log(&self) -> String {
        let mut s = String::new();
        std::fs::File::open(&self.log)
            .unwrap()
            .read_to_string(&mut s)
            .unwrap();
        s
    }

    /// Asserts that a command which fed this agent (`asbuilt publish`, `replay`...) succeeded;
    /// if not, shows its standard error and the agent's log.
    pub fn assert_fed(&self, command: &std::process::Output) {
        assert!(
            command.status.success(),
            "{}\nagent log:\n{}",
            String::from_utf8_lossy(&command.stderr),
            self.log()
        );
    }

    /// Sends the agent a signal (`TERM`, `INT`, `KILL`...) and asserts it was delivered.
    pub fn signal(&self, signal: &str) {
        let ok = Command::new("kill")
            .arg(format!("-{signal}"))
            .arg(self.pid().to_string())
            .status()
            .unwrap()
            .success();
        assert!(ok, "kill -{signal} failed");
    }

    /// Waits for the process to exit on its own.
    pub fn wait_exit(&mut self, timeout: Duration) -> ExitStatus {
        let start = Instant::now();
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                return s;
            }
            assert!(
                start.elapsed() < timeout,
                "agent did not exit within {timeout:?}; log:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Agent {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts the agent `exe` on `dir`'s agent.toml, logging to a new file there.
fn spawn(exe: &str, dir: &Path) -> (Child, PathBuf) {
    let log = dir.join(format!("agent-{}.log", rand_suffix()));
    let child = Command::new(exe)
        .arg("--config")
        .arg(dir.join("agent.toml"))
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    (child, log)
}

fn rand_suffix() -> u32 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos()
}

/// The cell's side of an agent's services, in the test process.
pub struct Cell {
    /// The cell's ports on the agent's services.
    pub ports: CellPorts,
    _node: Node<Ipc>,
}

impl Cell {
    /// Opens the agent's services, waiting for it to come up (design loading included).
    pub fn open(prefix: &str, max_points_per_chunk: usize) -> Cell {
        set_log_level_from_env_or(LogLevel::Error);
        let node = NodeBuilder::new().create::<Ipc>().unwrap();
        let ports = CellPorts::open(
            &node,
            &ServiceNames::new(prefix),
            max_points_per_chunk,
            Duration::from_secs(60),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        Cell { ports, _node: node }
    }

    /// Collects reports until `n` have arrived or `timeout` passes.
    pub fn reports(&self, n: usize, timeout: Duration) -> Vec<StationReport> {
        let start = Instant::now();
        let mut out = Vec::new();
        while out.len() < n && start.elapsed() < timeout {
            while let Some(r) = self.ports.reports.receive().unwrap() {
                out.push(*r.payload());
            }
            self.drain_deviations();
            if out.len() < n {
                let _ = self.ports.wait_for_output(Duration::from_millis(50));
            }
        }
        out
    }

    /// Receives every deviation chunk waiting; returns their points.
    pub fn drain_deviations(&self) -> usize {
        let mut n = 0;
        while let Ok(Some(d)) = self.ports.deviations.receive() {
            n += d.payload().len();
        }
        n
    }

    /// The newest status that satisfies `pred`, waiting up to `timeout`.
    pub fn status_where(
        &self,
        timeout: Duration,
        pred: impl Fn(&AgentStatus) -> bool,
    ) -> Option<AgentStatus> {
        let start = Instant::now();
        while start.elapsed() < timeout {
            while let Some(s) = self.ports.status.receive().unwrap() {
                if pred(s.payload()) {
                    return Some(*s.payload());
                }
            }
            self.drain_deviations();
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }
}

/// Resident memory of a process from /proc, in KiB: (VmRSS, RssAnon, VmHWM).
pub fn memory_kib(pid: u32) -> (u64, u64, u64) {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let field = |k: &str| {
        s.lines()
            .find(|l| l.starts_with(k))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(0)
    };
    (field("VmRSS:"), field("RssAnon:"), field("VmHWM:"))
}

/// A `[recorder]` section writing into `dir`, beside the agent's configuration. Its
/// `min_free_mb` is the tests' own: their recordings take a few MB, and what they check must
/// not hang on the free space of the machine that runs them. The agent's default keeps 1 GB
/// free for a print that runs for hours, and a CI machine may have less: one had 648 MB.
pub fn recorder_section(dir: &str) -> String {
    format!("[recorder]\ndir = {dir:?}\nmin_free_mb = 16\n")
}

/// An agent configuration for the Stanford bunny at 5 mm tolerance and maximum distance, with
/// `extra` sections appended.
pub fn bunny_agent_config(extra: &str) -> String {
    let design = shared_data().join("stanford-bunny/bun_zipper.ply");
    format!(
        "[design]\npath = {:?}\nunits = \"m\"\n[inspect]\ntolerance = 0.005\n\
         max_distance = 0.005\n{extra}",
        design.display().to_string()
    )
}

/// The repository's root.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The bunny job's stations file (tools/examples/bunny).
pub fn bunny_stations() -> PathBuf {
    repo().join("tools/examples/bunny/stations.toml")
}

/// `asbuilt publish` (`asbuilt` is the command to run) of a stations file to the agent under
/// `prefix`; the caller adds its own options.
pub fn publish_command(asbuilt: &str, stations: &Path, prefix: &str) -> Command {
    let mut c = Command::new(asbuilt);
    c.arg("publish")
        .arg("--stations")
        .arg(stations)
        .args(["--prefix", prefix]);
    c
}

/// `asbuilt publish` of the ten bunny stations to `prefix`, 10,000 points per chunk.
pub fn publish_bunny(asbuilt: &str, prefix: &str) -> std::process::Output {
    publish_command(asbuilt, &bunny_stations(), prefix)
        .args(["--chunk-points", "10000"])
        .output()
        .unwrap()
}

/// An agent (`agent_exe`) run over the whole bunny job: started with the bunny's configuration
/// and the sections `extra` ([`bunny_agent_config`]) under a prefix named for `test`, fed by
/// [`publish_bunny`] through `asbuilt`, then stopped with SIGTERM. Returns it once it has
/// exited cleanly; its folder holds what it wrote.
pub fn agent_after_bunny_job(agent_exe: &str, asbuilt: &str, test: &str, extra: &str) -> Agent {
    let prefix = unique_prefix(test);
    let mut agent = Agent::start(agent_exe, &prefix, &bunny_agent_config(extra));
    agent.assert_fed(&publish_bunny(asbuilt, &prefix));
    agent.signal("TERM");
    assert!(
        agent.wait_exit(Duration::from_secs(30)).success(),
        "agent:\n{}",
        agent.log()
    );
    agent
}

/// A small demo (two scan layers of two stations, one over-extruded band) into `out`, as the
/// end-to-end tests of the demo and of its view run it.
pub fn small_demo(asbuilt: &str, out: &Path) -> std::process::Output {
    Command::new(asbuilt)
        .args([
            "demo",
            "--scan-after",
            "6,12",
            "--stations",
            "2",
            "--step-deg",
            "0.1",
        ])
        .args([
            "--rate",
            "max",
            "--defect",
            "over-extrusion:layers=2-3,width=12mm",
        ])
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

/// Asserts that a station of a report.json says exactly what the agent's report `r` says: its
/// points, its signed distances (equal as numbers, so to the bit but for the sign of a zero)
/// and its histogram. `what` names the station in a failure.
pub fn assert_section_matches(section: &serde_json::Value, r: &StationReport, what: &str) {
    use serde_json::json;
    let s = &r.stats;
    let expected = json!({
        "points": r.points_received, "matched": s.count, "no_match": r.no_match,
        "within_tolerance": s.within, "above_tolerance": s.above, "below_tolerance": s.below,
        "mean": s.mean, "std": s.std, "rms": s.rms, "min": s.min, "max": s.max,
        "median_abs": s.median_abs, "p95_abs": s.p95_abs,
    });
    for (key, v) in expected.as_object().unwrap() {
        assert_eq!(
            section[key], *v,
            "{what} {key}: report.json, then the agent"
        );
    }
    let bins = &section["histogram"]["bins"];
    assert_eq!(
        *bins,
        json!(r.histogram.bins.as_slice()),
        "{what} histogram"
    );
}

/// Sends `job` from `cell` to `agent` and collects what comes back (findings awaited when
/// `expect_findings`); a failure shows the agent's logs.
pub fn send_job(
    job: &asbuilt_sim::SimJob,
    agent: &Agent,
    cell: &Cell,
    expect_findings: bool,
) -> asbuilt_sim::SimOutcome {
    asbuilt_sim::run(
        job,
        &cell.ports,
        expect_findings,
        Duration::from_secs(60),
        &mut |_| {},
    )
    .unwrap_or_else(|e| panic!("{e}\nagent logs:\n{}", agent.logs()))
}

/// report.json of `asbuilt report` (`asbuilt` is the command) over the recording folder
/// `recording`, written into `out`.
pub fn report_json(asbuilt: &str, recording: &Path, out: &Path) -> serde_json::Value {
    let run = Command::new(asbuilt)
        .arg("report")
        .arg(recording)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}
