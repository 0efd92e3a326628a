//! What the agent benchmarks share: a child agent process that dies with the benchmark, and the
//! median they report.

use std::path::Path;
use std::process::{Child, Command, Stdio};

pub struct AgentProcess(pub Child);

impl AgentProcess {
    /// Starts the agent binary on `config`, its log going to `log` (or nowhere).
    pub fn start(config: &Path, log: Option<&Path>) -> Self {
        let stderr = match log {
            Some(p) => Stdio::from(std::fs::File::create(p).unwrap()),
            None => Stdio::null(),
        };
        AgentProcess(
            Command::new(env!("CARGO_BIN_EXE_asbuilt-agent"))
                .arg("--config")
                .arg(config)
                .stderr(stderr)
                .spawn()
                .unwrap(),
        )
    }
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
