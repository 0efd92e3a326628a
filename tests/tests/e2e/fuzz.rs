//! The fuzzing harness's fixed budget (`tests/src/fuzz`): every seed file is read by its target,
//! every input kept in `tests/fuzz/regressions` and a few hundred mutated inputs per target give
//! a result or an error naming the file, with no panic, abort, hang or unjustified allocation.
//! Longer runs: `target/release/fuzz --seconds N` (see the README).

use std::process::Command;

const FUZZ: &str = env!("CARGO_BIN_EXE_fuzz");
const ASBUILT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt");

fn fuzz(args: &[&str]) -> std::process::Output {
    Command::new(FUZZ)
        .args(args)
        .env("ASBUILT", ASBUILT)
        .output()
        .unwrap()
}

#[test]
fn every_seed_file_is_read_by_its_target() {
    let o = fuzz(&["--check-seeds"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // Every target had seeds, and they were read, not refused.
    for target in asbuilt_tests::fuzz::TARGETS {
        assert!(
            err.lines()
                .any(|l| l.starts_with(&format!("{} ", target.name))),
            "{}: {err}",
            target.name
        );
    }
}

#[test]
fn mutated_inputs_and_every_kept_regression_get_a_result_or_a_clear_error() {
    let keep = tempfile::tempdir().unwrap();
    // The time limit per input is above the 5 s of a long run: a loaded CI machine is slow.
    let o = fuzz(&[
        "--inputs",
        "200",
        "--timeout",
        "15",
        "--keep",
        keep.path().to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    eprintln!("{err}");
    assert!(o.status.success(), "{err}");
    assert!(err.contains("regression input(s) checked"), "{err}");
    for target in asbuilt_tests::fuzz::TARGETS {
        assert!(
            err.contains(&format!("{}: ", target.name)) && !err.contains("failure(s)\nFAIL"),
            "{err}"
        );
    }
}
