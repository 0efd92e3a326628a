//! What the agent benchmarks share: a child agent process that dies with the benchmark, the
//! cell's ports to it, and the median they report.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use asbuilt_protocol::ipc::{CellPorts, Ipc, ServiceNames};
use iceoryx2::prelude::*;

/// Points per chunk the benchmarks send, at most.
pub const CHUNK: usize = 65_536;

pub struct AgentProcess(pub Child);

impl AgentProcess {
    /// Starts the agent binary on `config`, its log going to `log` (or nowhere). The binary is
    /// this build's, or `$ASBUILT_AGENT` when set: another build run in the same sitting (a
    /// saved copy of the one before a change) is the fair comparison on a noisy machine.
    pub fn start(config: &Path, log: Option<&Path>) -> Self {
        let stderr = match log {
            Some(p) => Stdio::from(std::fs::File::create(p).unwrap()),
            None => Stdio::null(),
        };
        AgentProcess(
            Command::new(
                std::env::var_os("ASBUILT_AGENT")
                    .unwrap_or_else(|| env!("CARGO_BIN_EXE_asbuilt-agent").into()),
            )
            .arg("--config")
            .arg(config)
            .stderr(stderr)
            .spawn()
            .unwrap(),
        )
    }
}

/// How a benchmark's agent is set up: its configuration is written to `dir/NAME.toml`.
pub struct AgentSetup<'a> {
    pub dir: &'a Path,
    /// The design, in metres.
    pub design: &'a Path,
    /// `[inspect] max_distance`, metres.
    pub max_distance: f64,
}

impl AgentSetup<'_> {
    /// Starts an agent named `name` on services under `prefix`, with `extra` appended to its
    /// configuration; its log goes to `dir/NAME.log` when `log` is set.
    pub fn start(&self, name: &str, prefix: &str, extra: &str, log: bool) -> AgentProcess {
        let config = self.dir.join(format!("{name}.toml"));
        std::fs::write(
            &config,
            format!(
                "[design]\npath = {:?}\nunits = \"m\"\n[inspect]\ntolerance = 0.005\n\
                 max_distance = {}\n[services]\nprefix = \"{prefix}\"\n{extra}",
                self.design.display().to_string(),
                self.max_distance,
            ),
        )
        .unwrap();
        let log = log.then(|| self.dir.join(format!("{name}.log")));
        AgentProcess::start(&config, log.as_deref())
    }
}

/// The cell's ports to the agent under `prefix`.
pub fn cell_ports(node: &Node<Ipc>, prefix: &str) -> CellPorts {
    CellPorts::open(
        node,
        &ServiceNames::new(prefix),
        CHUNK,
        Duration::from_secs(60),
    )
    .unwrap()
}

impl Drop for AgentProcess {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
