//! The rerun view: `asbuilt inspect --rerun` and the agent's `[viewer]` write `.rrd` files that
//! decode, with the expected entities. Where the `rerun` command is installed, `rerun rrd
//! verify` checks the file too.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

use asbuilt_tests::{Agent, bunny_agent_config, publish_bunny, shared_data, unique_prefix};
use rerun::external::re_log_encoding::DecoderApp;
use rerun::external::re_log_types::LogMsg;

const AGENT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt-agent");
const ASBUILT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt");

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Entity paths (and the number of chunks) in a `.rrd` file.
fn entities(rrd: &Path) -> (BTreeSet<String>, usize) {
    let reader = std::io::BufReader::new(std::fs::File::open(rrd).unwrap());
    let mut paths = BTreeSet::new();
    let mut chunks = 0;
    for msg in DecoderApp::decode_eager(reader).unwrap() {
        if let LogMsg::ArrowMsg(_, arrow) = msg.unwrap() {
            let chunk = rerun::log::Chunk::from_arrow_msg(&arrow).unwrap();
            paths.insert(chunk.entity_path().to_string());
            chunks += 1;
        }
    }
    (paths, chunks)
}

fn verify_with_rerun(rrd: &Path) {
    let Ok(o) = Command::new("rerun")
        .args(["rrd", "verify"])
        .arg(rrd)
        .output()
    else {
        eprintln!("SKIPPED: the rerun command is not installed (pip install rerun-sdk==0.36.*)");
        return;
    };
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn inspect_writes_a_view_of_the_bunny() {
    let dir = tempfile::tempdir().unwrap();
    let rrd = dir.path().join("bunny.rrd");
    let design = shared_data().join("stanford-bunny/bun_zipper.ply");
    let o = Command::new(ASBUILT)
        .arg("inspect")
        .args(["--design", design.to_str().unwrap(), "--units", "m"])
        .arg("--stations")
        .arg(repo().join("examples/bunny/stations.toml"))
        .args([
            "--max-distance",
            "0.005",
            "--method",
            "all",
            "--spacing",
            "0.004",
        ])
        .args(["--layer-height", "0.02", "--rerun-points", "5000"])
        .args(["--rerun", rrd.to_str().unwrap()])
        .args(["--out", dir.path().join("out").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (paths, chunks) = entities(&rrd);
    for want in [
        "/design",
        "/legend",
        "/stations/bun000",
        "/deviations/bun000",
        "/stations/ear_back/histogram",
        "/stats/median_abs_mm",
        "/stats/p95_abs_mm",
        "/m3c2",
        "/layers/c2m_mean_mm",
    ] {
        assert!(paths.contains(want), "{want} missing from {paths:?}");
    }
    assert!(chunks > 30, "{chunks}");
    verify_with_rerun(&rrd);
}

#[test]
fn the_agent_writes_a_view_of_a_job() {
    let prefix = unique_prefix("viewer");
    let mut agent = Agent::start(
        AGENT,
        &prefix,
        &bunny_agent_config("[viewer]\nrrd = \"job.rrd\"\nmax_points_per_station = 4000\n"),
    );
    let publish = publish_bunny(ASBUILT, &prefix);
    assert!(publish.status.success(), "{}", agent.log());
    agent.signal("TERM");
    assert!(
        agent
            .wait_exit(std::time::Duration::from_secs(30))
            .success()
    );
    let log = agent.log();
    assert!(log.contains("viewer: closed (0 item(s) dropped"), "{log}");
    let rrd = agent.dir.path().join("job.rrd");
    let (paths, _) = entities(&rrd);
    for want in [
        "/design",
        "/stations/job1/station0",
        "/deviations/job1/station9",
        "/stations/job1/station3/histogram",
        "/stats/mean_mm",
    ] {
        assert!(paths.contains(want), "{want} missing from {paths:?}");
    }
    verify_with_rerun(&rrd);
}
