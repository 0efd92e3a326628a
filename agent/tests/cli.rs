//! The agent's command line, without IPC: configuration checks.

use std::process::Command;

const AGENT: &str = env!("CARGO_BIN_EXE_asbuilt-agent");

#[test]
fn the_shipped_example_config_is_valid() {
    let example = concat!(env!("CARGO_MANIFEST_DIR"), "/agent.example.toml");
    let out = Command::new(AGENT)
        .args(["--check-config", "--config", example])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("valid"), "{stdout}");
    assert!(stdout.contains("methods c2m"), "{stdout}");
}

#[test]
fn a_bad_config_lists_every_problem_and_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("agent.toml");
    std::fs::write(
        &path,
        "[design]\npath = \"nowhere.stl\"\nunits = \"feet\"\n[inspect]\ntolerance = 0\n",
    )
    .unwrap();
    let out = Command::new(AGENT)
        .args(["--check-config", "--config"])
        .arg(&path)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    for key in [
        "3 problem(s)",
        "design.path",
        "design.units",
        "inspect.tolerance",
    ] {
        assert!(stderr.contains(key), "{key} not in:\n{stderr}");
    }
}
