//! The agent's command line, without IPC: configuration checks.

use std::path::Path;
use std::process::{Command, Output};

const AGENT: &str = env!("CARGO_BIN_EXE_asbuilt-agent");

/// `asbuilt-agent --check-config --config CONFIG`, and its output as text.
fn check_config(config: &Path) -> (Output, String, String) {
    let out = Command::new(AGENT)
        .args(["--check-config", "--config"])
        .arg(config)
        .output()
        .unwrap();
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    (out, stdout, stderr)
}

#[test]
fn the_shipped_example_config_is_valid() {
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("agent.example.toml");
    let (out, stdout, stderr) = check_config(&example);
    assert!(out.status.success(), "{stdout}{stderr}");
    assert!(stdout.contains("valid"), "{stdout}");
    assert!(stdout.contains("methods c2m"), "{stdout}");
}

/// A design that is not there, a unit no one declares, and a tolerance of nothing.
const THREE_PROBLEMS: &str =
    "[design]\npath = \"nowhere.stl\"\nunits = \"feet\"\n[inspect]\ntolerance = 0\n";

#[test]
fn a_bad_config_lists_every_problem_and_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("agent.toml");
    std::fs::write(&path, THREE_PROBLEMS).unwrap();
    let (out, _, stderr) = check_config(&path);
    assert_eq!(out.status.code(), Some(2));
    let keys = ["design.path", "design.units", "inspect.tolerance"];
    assert!(stderr.contains("3 problem(s)"), "{stderr}");
    for key in keys {
        assert!(stderr.contains(key), "{key} not in:\n{stderr}");
    }
}
