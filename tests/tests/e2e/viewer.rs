//! The rerun view: `asbuilt inspect --rerun` and the agent's `[viewer]` write `.rrd` files that
//! decode, with the expected entities. Where the `rerun` command is installed, `rerun rrd
//! verify` checks the file too.

use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

use asbuilt_sim::{self as sim, Defect, Part, SimJob};
use asbuilt_tests::{
    Agent, Cell, agent_after_bunny_job, bunny_stations, recorder_section, shared_data,
    unique_prefix,
};
use asbuilt_viewer::{Job, Panel, PanelKind, panels};
use rerun::external::re_log_encoding::DecoderApp;
use rerun::external::re_log_types::LogMsg;

const AGENT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt-agent");
const ASBUILT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt");

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

/// Asserts that every path in `want` has data in the `.rrd` file; the number of chunks in it.
fn assert_has_entities(rrd: &Path, want: &[&str]) -> usize {
    let (paths, chunks) = entities(rrd);
    for w in want {
        assert!(paths.contains(*w), "{w} missing from {paths:?}");
    }
    chunks
}

/// `footer`: the file must end with rerun's footer (a bounded run's; the agent writes none).
fn verify_with_rerun(rrd: &Path, footer: bool) {
    let Ok(o) = Command::new("rerun")
        .args([
            "rrd",
            "verify",
            "--check-footers",
            if footer { "true" } else { "false" },
        ])
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
        .arg(bunny_stations())
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
    let chunks = assert_has_entities(
        &rrd,
        &[
            "/design",
            "/legend",
            "/stations/bun000",
            "/deviations/bun000/0000",
            "/stations/ear_back/histogram",
            "/stats/median_abs_mm",
            "/stats/p95_abs_mm",
            "/m3c2",
            "/layers/c2m_mean_mm",
        ],
    );
    assert!(chunks > 30, "{chunks}");
    let job = Job::Survey { layer_bands: true };
    assert_eq!(panels_without_data(&rrd, job), Vec::<String>::new());
    assert_eq!(time_panel_timeline(&rrd).as_deref(), Some("station"));
    verify_with_rerun(&rrd, true);
}

#[test]
fn the_agent_writes_a_view_of_a_job() {
    let viewer = "[viewer]\nrrd = \"job.rrd\"\nmax_points_per_station = 4000\n";
    let agent = agent_after_bunny_job(AGENT, ASBUILT, "viewer", viewer);
    let log = agent.log();
    assert!(log.contains("viewer: closed (0 item(s) dropped"), "{log}");
    let rrd = agent.dir.path().join("job.rrd");
    assert_has_entities(
        &rrd,
        &[
            "/design",
            "/stations/job1/station0",
            "/deviations/job1/station9/0000",
            // Every chunk shown stays: rerun shows an entity's latest points only.
            "/deviations/job1/station9/0001",
            "/stations/job1/station3/histogram",
            "/stats/mean_mm",
        ],
    );
    verify_with_rerun(&rrd, false);
}

/// Each scan layer's finding labels of report.json, by scan layer.
fn report_labels(report: &serde_json::Value) -> Vec<(i64, Vec<String>)> {
    report["assessment"]["scan_layers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            let labels = s["items"].as_array().unwrap().iter();
            let labels = labels.map(|i| i["label"].as_str().unwrap().to_string());
            (s["layer"].as_i64().unwrap(), labels.collect())
        })
        .collect()
}

/// An agent started again mid-job starts a new .rrd: it draws the job's findings so far again
/// from its recording (markers numbered as the report, the history, the statistics), so the
/// view after a crash is the view before it.
#[test]
fn the_view_of_a_resumed_job_draws_again_what_was_judged_before() {
    let mut job = SimJob::new(Part::wall());
    job.scan_after = vec![8, 16];
    job.stations_per_scan = 2;
    job.scanner.step_deg = 0.1;
    job.defects = vec![
        Defect::parse(
            "bulge:x=-0.5,y=-0.0867,z=0.1,radius=0.08,height=12mm",
            &job.part,
        )
        .unwrap(),
    ];
    let dir = tempfile::tempdir().unwrap();
    sim::write_stl(&dir.path().join("design.stl"), &job.part.design).unwrap();
    let config = format!(
        "[design]\npath = \"design.stl\"\nunits = \"m\"\n[inspect]\ntolerance = 0.005\n\
         max_distance = 0.03\n[limits]\nmax_points_per_chunk = {}\n{}\
         [findings]\nenabled = true\nlayer_height = {}\n[viewer]\nrrd = \"job.rrd\"\n",
        job.chunk_points,
        recorder_section("recording"),
        job.part.layer_height
    );
    let mut agent = Agent::start_in(AGENT, &unique_prefix("viewer-resume"), &config, dir);
    let cell = Cell::open(&agent.prefix, job.chunk_points);
    asbuilt_tests::send_job(&job, &agent, &cell, true);
    let rrd = agent.dir.path().join("job.rrd");
    // Killed as a power loss would, and started again: its view starts afresh.
    agent.kill_and_restart(Duration::from_millis(100));
    let start = std::time::Instant::now();
    while !agent.log().contains("serving ") && start.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(20));
    }
    agent.signal("TERM");
    agent.wait_exit(Duration::from_secs(60));
    let logs = agent.logs();
    assert!(logs.contains("resume"), "{logs}");
    let dir = agent.dir.path();
    let report = asbuilt_tests::report_json(ASBUILT, &dir.join("recording"), &dir.join("report"));
    let want = report_labels(&report);
    assert_eq!(want.len(), 2, "{want:?}");
    assert!(want.iter().any(|(_, l)| !l.is_empty()), "{want:?}");
    assert_eq!(markers(&rrd), want, "{logs}");
    // The history and the statistics are there too, on the timeline the view opens on.
    let job = Job::Printing { corrections: false };
    let empty = panels_without_data(&rrd, job);
    // Points are not drawn again: only the 3D view's points are gone, and the 3D view still has
    // the design and the markers.
    assert_eq!(empty, Vec::<String>::new(), "{logs}");
}

/// A blueprint's views and containers by entity path: (class or container kind, name,
/// contents).
type Layout = std::collections::BTreeMap<String, (String, String, Vec<String>)>;

/// The root container and the layout of the blueprint an `.rrd` file carries.
fn blueprint_layout(rrd: &Path) -> (Option<String>, Layout) {
    use rerun::external::re_sdk_types::blueprint::components as bp;
    use rerun::external::re_sdk_types::{Component, components as c};
    let mut root = None;
    let mut items = Layout::default();
    for chunk in chunks(rrd, rerun::StoreKind::Blueprint) {
        let path = chunk.entity_path().to_string();
        let item = items.entry(path).or_default();
        for d in chunk.component_descriptors() {
            let Some(ty) = d.component_type else { continue };
            if ty == bp::RootContainer::name() {
                for r in chunk.iter_component::<bp::RootContainer>(d.component) {
                    root = r.first().map(|u| format!("/container/{}", uuid_of(&u.0)));
                }
            } else if ty == bp::ViewClass::name() {
                for v in chunk.iter_component::<bp::ViewClass>(d.component) {
                    item.0 = v.first().map(|s| s.0.to_string()).unwrap_or_default();
                }
            } else if ty == bp::ContainerKind::name() {
                for v in chunk.iter_component::<bp::ContainerKind>(d.component) {
                    item.0 = v.first().map(|k| format!("{k:?}")).unwrap_or_default();
                }
            } else if ty == c::Name::name() {
                for v in chunk.iter_component::<c::Name>(d.component) {
                    item.1 = v.first().map(|s| s.to_string()).unwrap_or_default();
                }
            } else if ty == bp::IncludedContent::name() {
                for v in chunk.iter_component::<bp::IncludedContent>(d.component) {
                    item.2 = v
                        .iter()
                        .map(|p| format!("/{}", p.0.as_str().trim_start_matches('/')))
                        .collect();
                }
            }
        }
    }
    (root, items)
}

/// A UUID as blueprint entity paths spell it: 8-4-4-4-12 lower-case hex digits.
fn uuid_of(u: &rerun::external::re_sdk_types::datatypes::Uuid) -> String {
    let hex: String = u.bytes.iter().map(|b| format!("{b:02x}")).collect();
    format!(
        "{}-{}-{}-{}-{}",
        &hex[..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..]
    )
}

/// The demo's view opens on the part: a blueprint whose first tab starts with the 3D view,
/// and one history series per layer band.
#[test]
fn the_demo_view_opens_on_the_part_with_a_history_per_layer_band() {
    let out = tempfile::tempdir().unwrap();
    let o = asbuilt_tests::small_demo(ASBUILT, out.path());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rrd = out.path().join("demo.rrd");
    let (root, items) = blueprint_layout(&rrd);
    let root = root.expect("a blueprint with a root container");
    let (kind, _, tabs) = &items[&root];
    assert_eq!(kind, "Tabs", "{items:#?}");
    let (kind, name, first) = &items[&tabs[0]];
    assert_eq!(
        (kind.as_str(), name.as_str()),
        ("Horizontal", "part"),
        "{items:#?}"
    );
    let (class, name, _) = &items[&first[0]];
    assert_eq!(
        (class.as_str(), name.as_str()),
        ("3D", "part"),
        "{items:#?}"
    );
    let (_, history, _) = &items[&tabs[1]];
    assert_eq!(history, "layer history");

    // One width series per layer band, across scan layers.
    let (paths, _) = entities(&rrd);
    let bands: Vec<&String> = paths
        .iter()
        .filter(|p| p.starts_with("/history/width_mm/band_"))
        .collect();
    assert!(bands.len() >= 6, "{paths:?}");
    // And its relative width (less the scan layer's median), the creep the report follows.
    for b in &bands {
        let relative = b.replace("/width_mm/", "/relative_width_mm/");
        assert!(paths.contains(&relative), "{relative} missing: {paths:?}");
    }
    // One value per band and scan layer (its last, with all its stations), not one per
    // station as the scan layer's findings are redrawn.
    let mut width_rows: std::collections::BTreeMap<String, Vec<i64>> = Default::default();
    for c in recording_chunks(&rrd) {
        let path = c.entity_path().to_string();
        if let (true, Some(t)) = (
            path.starts_with("/history/width_mm/"),
            c.timelines().get(&rerun::TimelineName::from("layer")),
        ) {
            width_rows.entry(path).or_default().extend(t.times_raw());
        }
    }
    assert!(!width_rows.is_empty());
    for (path, layers) in &width_rows {
        let mut distinct = layers.clone();
        distinct.dedup();
        assert_eq!(&distinct, layers, "{path}: {layers:?}");
    }
    let job = Job::Printing { corrections: false };
    assert_eq!(panels_without_data(&rrd, job), Vec::<String>::new());
    assert_eq!(time_panel_timeline(&rrd).as_deref(), Some("layer"));
    // The part shows each scan layer's warnings and failures as markers numbered as in the
    // report, the scan layer at the cursor's only: one entity, logged once per scan layer.
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("report.json")).unwrap()).unwrap();
    let want = report_labels(&report);
    assert_eq!(want.len(), 2, "{want:?}");
    assert!(want.iter().all(|(_, l)| !l.is_empty()), "{want:?}");
    assert_eq!(markers(&rrd), want);
    verify_with_rerun(&rrd, false);
}

/// The chunks of the recording's (not the blueprint's) or the blueprint's store.
fn chunks(rrd: &Path, kind: rerun::StoreKind) -> Vec<rerun::log::Chunk> {
    let reader = std::io::BufReader::new(std::fs::File::open(rrd).unwrap());
    let mut out = Vec::new();
    for msg in DecoderApp::decode_eager(reader).unwrap() {
        if let LogMsg::ArrowMsg(store, arrow) = msg.unwrap()
            && store.kind() == kind
        {
            out.push(rerun::log::Chunk::from_arrow_msg(&arrow).unwrap());
        }
    }
    out
}

fn recording_chunks(rrd: &Path) -> Vec<rerun::log::Chunk> {
    chunks(rrd, rerun::StoreKind::Recording)
}

/// The titles of `job`'s panels that would draw nothing when the view opens: no entity they
/// show holds what they draw, on the timeline the view opens on (or static, where latest-at
/// data is drawn; a time series needs it on the timeline).
fn panels_without_data(rrd: &Path, job: Job) -> Vec<String> {
    let chunks = recording_chunks(rrd);
    let timeline = rerun::TimelineName::from(job.timeline());
    let draws = |p: &Panel, c: &rerun::log::Chunk| {
        let on_timeline = c.timelines().contains_key(&timeline);
        let when = match p.kind {
            PanelKind::TimeSeries => !c.is_static() && on_timeline,
            _ => c.is_static() || on_timeline,
        };
        let what = p.kind.component().is_none_or(|want| {
            c.component_descriptors()
                .any(|d| d.component.as_str() == want)
        });
        c.num_rows() > 0 && when && what && p.includes(&c.entity_path().to_string())
    };
    panels(job)
        .filter(|p| !chunks.iter().any(|c| draws(p, c)))
        .map(|p| p.title.to_string())
        .collect()
}

/// The timeline the blueprint's time panel opens on.
fn time_panel_timeline(rrd: &Path) -> Option<String> {
    use rerun::external::re_sdk_types::Component;
    use rerun::external::re_sdk_types::blueprint::components as bp;
    let mut found = None;
    for chunk in chunks(rrd, rerun::StoreKind::Blueprint) {
        for d in chunk.component_descriptors() {
            if d.component_type == Some(bp::TimelineName::name()) {
                for v in chunk.iter_component::<bp::TimelineName>(d.component) {
                    found = v.first().map(|t| t.0.to_string());
                }
            }
        }
    }
    found
}

/// The findings' marker labels at each scan layer (`layer` timeline), the last logged of each
/// (a scan layer's findings are redrawn as each of its stations completes).
fn markers(rrd: &Path) -> Vec<(i64, Vec<String>)> {
    use rerun::external::re_sdk_types::components::Text;
    let mut rows = Vec::new();
    for c in recording_chunks(rrd) {
        if c.entity_path().to_string() != "/findings/markers" {
            continue;
        }
        let Some(layers) = c.timelines().get(&rerun::TimelineName::from("layer")) else {
            continue;
        };
        let labels = c.iter_component::<Text>("Points3D:labels".into());
        for ((layer, row), id) in layers.times_raw().iter().zip(labels).zip(c.row_ids()) {
            rows.push((*layer, id, row.iter().map(|t| t.to_string()).collect()));
        }
    }
    rows.sort_by_key(|r| (r.0, r.1));
    let mut last = std::collections::BTreeMap::new();
    for (layer, _, labels) in rows {
        last.insert(layer, labels);
    }
    last.into_iter().collect()
}
