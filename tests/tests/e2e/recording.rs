//! Recordings: the bunny packed into a recording and replayed through a real agent reports what
//! `asbuilt inspect` reports; a recording cut at 60 % of its bytes gives back every station it
//! had finished; an independent MCAP reader (Python `mcap`, when installed) reads the file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use asbuilt_protocol::recording::RecordingWriter;
use asbuilt_protocol::recording::{self, Recorded};
use asbuilt_protocol::{StationEventKind, StationReport};
use asbuilt_tests::{
    Agent, agent_after_bunny_job, assert_section_matches, bunny_agent_config, bunny_stations,
    publish_command, recorder_section, repo, shared_data, unique_prefix,
};
use serde_json::Value;

const AGENT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt-agent");
const ASBUILT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt");

fn run(args: &[&str]) -> std::process::Output {
    let o = Command::new(ASBUILT).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "asbuilt {args:?}:\n{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn pack_bunny(out: &Path) {
    pack_bunny_with(out, &[]);
}

fn pack_bunny_with(out: &Path, extra: &[&str]) {
    let design = shared_data().join("stanford-bunny/bun_zipper.ply");
    let stations = bunny_stations();
    let mut args = vec![
        "pack",
        "--stations",
        stations.to_str().unwrap(),
        "--design",
        design.to_str().unwrap(),
        "--units",
        "m",
        "--chunk-points",
        "10000",
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    run(&args);
}

/// Each topic's messages, and each topic's schema name.
type Topics = (BTreeMap<String, Vec<Vec<u8>>>, BTreeMap<String, String>);

/// Messages of an MCAP file by topic, with each topic's schema name.
fn by_topic(bytes: &[u8]) -> Topics {
    let mut by_topic: BTreeMap<String, Vec<Vec<u8>>> = BTreeMap::new();
    let mut schemas = BTreeMap::new();
    for m in mcap::MessageStream::new(bytes).unwrap() {
        let m = m.unwrap();
        if let Some(s) = &m.channel.schema {
            schemas.insert(m.channel.topic.clone(), s.name.clone());
        }
        by_topic
            .entry(m.channel.topic.clone())
            .or_default()
            .push(m.data.into_owned());
    }
    (by_topic, schemas)
}

/// `asbuilt replay` of `recording` into `agent`, with `args`; it must succeed.
fn replay(recording: &Path, agent: &Agent, args: &[&str]) {
    let o = Command::new(ASBUILT)
        .arg("replay")
        .arg(recording)
        .args(["--prefix", &agent.prefix])
        .args(args)
        .output()
        .unwrap();
    agent.assert_fed(&o);
}

/// `pack --foxglove`: the design, a frame per station and every valid scan point in its
/// station's frame, for Foxglove.
#[test]
fn a_packed_recording_with_foxglove_channels_shows_the_scans_in_their_frames() {
    use asbuilt_protocol::foxglove as fx;
    use foxglove::Decode;
    use foxglove::messages::{FrameTransform, PointCloud};

    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("bunny.mcap");
    pack_bunny_with(&rec, &["--foxglove"]);
    let bytes = std::fs::read(&rec).unwrap();
    let (topics, schemas) = by_topic(&bytes);
    assert_eq!(schemas[fx::TOPIC_SCANS], "foxglove.PointCloud");
    assert_eq!(topics[fx::TOPIC_DESIGN].len(), 1);
    let frames: Vec<String> = topics[fx::TOPIC_STATIONS]
        .iter()
        .map(|b| FrameTransform::decode(&b[..]).unwrap().child_frame_id)
        .collect();
    assert_eq!(frames.len(), 10);
    let mut points = BTreeMap::<String, usize>::new();
    for b in &topics[fx::TOPIC_SCANS] {
        let c = PointCloud::decode(&b[..]).unwrap();
        assert!(frames.contains(&c.frame_id), "{}", c.frame_id);
        *points.entry(c.frame_id).or_default() += c.data.len() / c.point_stride as usize;
    }
    // Every valid point of the recorded chunks, in its own station's frame.
    let mut valid = BTreeMap::<String, usize>::new();
    for (_, m) in recording::messages(&bytes).unwrap().map(Result::unwrap) {
        if let Recorded::Chunk(h, ps) = m {
            *valid
                .entry(fx::station_frame(h.job, h.station))
                .or_default() += ps
                .iter()
                .filter(|p| !p.flags.is_invalid() && p.xyz.iter().all(|v| v.is_finite()))
                .count();
        }
    }
    assert_eq!(points, valid);
    // Without the flag, none of it.
    let plain = dir.path().join("plain.mcap");
    pack_bunny(&plain);
    let (topics, _) = by_topic(&std::fs::read(&plain).unwrap());
    assert!(
        topics.keys().all(|t| !t.starts_with("/foxglove")),
        "{topics:?}"
    );
}

/// `asbuilt inspect` on the bunny stations into `out`; its report.json.
fn inspect_bunny(out: &Path) -> Value {
    let design = shared_data().join("stanford-bunny/bun_zipper.ply");
    run(&[
        "inspect",
        "--design",
        design.to_str().unwrap(),
        "--units",
        "m",
        "--stations",
        repo()
            .join("tools/examples/bunny/stations.toml")
            .to_str()
            .unwrap(),
        "--max-distance",
        "0.005",
        "--out",
        out.to_str().unwrap(),
    ]);
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn the_packed_bunny_replayed_through_the_agent_reports_what_inspect_reports() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("bunny.mcap");
    pack_bunny(&rec);
    let prefix = unique_prefix("replay");
    let agent = Agent::start(AGENT, &prefix, &bunny_agent_config(""));
    let out = dir.path().join("replay");
    replay(&rec, &agent, &["--out", out.to_str().unwrap()]);
    let replayed: Vec<Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join("replay.json")).unwrap()).unwrap();

    let report = inspect_bunny(&dir.path().join("inspect"));
    let stations = report["stations"].as_array().unwrap();
    assert_eq!(replayed.len(), stations.len());
    for (a, b) in replayed.iter().zip(stations) {
        for (k, v) in a.as_object().unwrap() {
            // Parsed with float_roundtrip: equal values are equal bits.
            assert_eq!(&b[k], v, "station {} field {k}", a["id"]);
        }
    }
}

#[test]
fn a_recording_cut_at_60_percent_gives_back_every_finished_station() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("bunny.mcap");
    // Uncompressed: the cut falls among the stations, past the 3 MB design attachment.
    pack_bunny_with(&rec, &["--compression", "none"]);
    let bytes = std::fs::read(&rec).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let fixed = dir.path().join("fixed.mcap");
    let o = run(&["recover", cut.to_str().unwrap(), fixed.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("the file ended inside a record"), "{said}");

    // What the whole file says each station holds.
    let full: Vec<(u64, Recorded)> = recording::messages(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .collect();
    let fixed_bytes = std::fs::read(&fixed).unwrap();
    let saved: Vec<(u64, Recorded)> = recording::messages(&fixed_bytes)
        .unwrap()
        .map(Result::unwrap)
        .collect();
    // Stations the cut file finished: every message of theirs is back, byte for byte.
    let ended: Vec<u32> = saved
        .iter()
        .filter_map(|(_, m)| match m {
            Recorded::Event(e) if e.kind() == Some(StationEventKind::End) => Some(e.station),
            _ => None,
        })
        .collect();
    // The stations whose every chunk lies before the cut: their End is no later than the last
    // message of the last whole chunk.
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let cut_at = (bytes.len() * 6 / 10) as u64;
    let whole_until = summary
        .chunk_indexes
        .iter()
        .filter(|c| c.chunk_start_offset + c.chunk_length <= cut_at)
        .map(|c| c.message_end_time)
        .max()
        .unwrap_or(0);
    let finished: Vec<u32> = full
        .iter()
        .filter_map(|(t, m)| match m {
            Recorded::Event(e) if e.kind() == Some(StationEventKind::End) && *t <= whole_until => {
                Some(e.station)
            }
            _ => None,
        })
        .collect();
    assert!(
        !finished.is_empty(),
        "the cut leaves no finished station to check"
    );
    assert_eq!(ended, finished);
    let of = |msgs: &[(u64, Recorded)], s: u32| -> Vec<Vec<u8>> {
        msgs.iter()
            .filter(|(_, m)| match m {
                Recorded::Event(e) => e.station == s,
                Recorded::Pose(p) => p.station == s,
                Recorded::Chunk(h, _) => h.station == s,
                _ => false,
            })
            .map(|(_, m)| m.encode())
            .collect()
    };
    for &s in &ended {
        assert_eq!(of(&saved, s), of(&full, s), "station {s}");
    }
    // The design and the job metadata survive too.
    let (meta, attachments) = recording::job(&fixed_bytes).unwrap();
    assert_eq!(meta.unwrap().writer, "asbuilt pack");
    assert_eq!(attachments.len(), 1);
    println!(
        "cut at {} of {} bytes (the 3 MB design attachment comes first): {} of 10 stations \
         recovered",
        bytes.len() * 6 / 10,
        bytes.len(),
        ended.len()
    );
}

/// The Python `mcap` package reads the packed bunny: topics, schemas, message counts and the
/// attachment. Skipped, saying so, where Python or the package is missing.
#[test]
fn an_independent_mcap_reader_reads_the_recording() {
    let have = Command::new("python3")
        .args(["-c", "import mcap"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !have {
        eprintln!("SKIPPED: python3 with the `mcap` package is not installed (pip install mcap)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("bunny.mcap");
    pack_bunny(&rec);
    let o = Command::new("python3")
        .arg(repo().join("tests/scripts/check_mcap.py"))
        .arg(&rec)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(out.contains("/scanner/chunks 43"), "{out}");
    assert!(out.contains("/job/stations 20"), "{out}");
    assert!(out.contains("/robot/poses 10"), "{out}");
    assert!(
        out.contains("attachment design/bun_zipper.ply 3033"),
        "{out}"
    );
    assert!(out.contains("metadata asbuilt.job"), "{out}");
}

/// The agent records a job; the recording replayed into a fresh agent gives the same reports,
/// bit for bit, as the ones recorded.
#[test]
fn a_recorded_job_replays_to_identical_reports() {
    let agent = agent_after_bunny_job(AGENT, ASBUILT, "record", &recorder_section("rec"));
    let log = agent.log();
    assert!(log.contains("recorder: closed"), "{log}");
    assert!(log.contains("43 scan chunks recorded, 0 left out"), "{log}");
    let files = recordings(&agent);
    assert_eq!(files.len(), 1, "{files:?}");
    let bytes = std::fs::read(&files[0]).unwrap();
    let recorded: Vec<StationReport> = recording::messages(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .filter_map(|(_, m)| match m {
            Recorded::Report(r) => Some(*r),
            _ => None,
        })
        .collect();
    assert_eq!(recorded.len(), 10, "{log}");
    let (meta, attachments) = recording::job(&bytes).unwrap();
    let meta = meta.unwrap();
    assert_eq!(meta.writer, "asbuilt-agent");
    assert!(meta.config.contains("[recorder]"));
    assert_eq!(meta.design_sha256.len(), 64);
    assert_eq!(attachments.len(), 1);

    // A fresh agent, without a recorder, fed the recording.
    let prefix2 = unique_prefix("replayed");
    let fresh = Agent::start(AGENT, &prefix2, &bunny_agent_config(""));
    let cell = asbuilt_tests::Cell::open(&prefix2, 16);
    replay(&files[0], &fresh, &[]);
    let replayed = cell.reports(10, std::time::Duration::from_secs(30));
    // Compared bit for bit, as encoded; in any order.
    let encoded = |v: &[StationReport]| {
        let mut e: Vec<Vec<u8>> = v
            .iter()
            .map(|r| Recorded::Report(Box::new(*r)).encode())
            .collect();
        e.sort();
        e
    };
    assert!(
        encoded(&replayed) == encoded(&recorded),
        "replayed:\n{replayed:#?}\nrecorded:\n{recorded:#?}\nrecording agent:\n{log}\n\
         replayed agent:\n{}",
        fresh.log()
    );
}

/// `asbuilt report` on the packed bunny writes the report.json `inspect` writes (every station
/// and the overall section, bit for bit) and an HTML page that needs no network.
#[test]
fn a_recording_reports_what_inspect_reports() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("bunny.mcap");
    pack_bunny(&rec);
    let out = dir.path().join("report");
    run(&[
        "report",
        rec.to_str().unwrap(),
        "--max-distance",
        "0.005",
        "--out",
        out.to_str().unwrap(),
    ]);
    let a: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let b = inspect_bunny(&dir.path().join("inspect"));
    let strip = |v: &Value| {
        let mut v = v.clone();
        v.as_object_mut().unwrap().remove("scan");
        v
    };
    let sa = a["stations"].as_array().unwrap();
    let sb = b["stations"].as_array().unwrap();
    assert_eq!(sa.len(), 10);
    for (x, y) in sa.iter().zip(sb) {
        assert_eq!(strip(x), strip(y));
    }
    assert_eq!(strip(&a["overall"]), strip(&b["overall"]));
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("<td>bun000</td>") && html.contains("<svg"));
    assert!(!html.contains("http://") && !html.contains("https://") && !html.contains("<script"));
    // A station's verdict is about its measurement: the bunny's one stray point (79 mm off, a
    // no-match) does not put ear_back's in doubt; every station passes, in the page too.
    let verdicts = a["assessment"]["stations"].as_array().unwrap();
    assert_eq!(verdicts.len(), 10);
    for v in verdicts.iter().chain([&a["assessment"]["overall"]]) {
        assert_eq!(v["verdict"], "pass", "{v}");
    }
    assert_eq!(html.matches("<td class=\"pass\">PASS</td>").count(), 11);
    // Without findings the job is judged by all its points together.
    assert_eq!(a["assessment"]["verdict"], "pass");
    let first = a["assessment"]["summary"][0].as_str().unwrap();
    assert!(first.starts_with("No findings"), "{first}");
    assert!(
        first.contains("together, PASS: "),
        "one sentence, evenly spaced: {first}"
    );
}

/// The recordings an agent wrote into its `rec` folder, in name order.
fn recordings(agent: &Agent) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(agent.dir.path().join("rec"))
        .unwrap()
        .map(|e| e.unwrap().path())
        // The folder also keeps the agent's design index cache.
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    files.sort();
    files
}

/// Runs the bunny job through an agent with `recorder` settings added to the tests' own
/// (`recorder_section`); returns the recordings, their messages, and the agent's log.
fn record_bunny(recorder: &str) -> (Agent, Vec<Vec<(u64, Recorded)>>, String) {
    record_bunny_with(&format!("{}{recorder}\n", recorder_section("rec")))
}

/// [`record_bunny`] with the whole `[recorder]` section given.
fn record_bunny_with(section: &str) -> (Agent, Vec<Vec<(u64, Recorded)>>, String) {
    let agent = agent_after_bunny_job(AGENT, ASBUILT, "rec-limits", section);
    let log = agent.log();
    let msgs = recordings(&agent)
        .iter()
        .map(|f| {
            let b = std::fs::read(f).unwrap();
            recording::messages(&b)
                .unwrap()
                .map(Result::unwrap)
                .collect()
        })
        .collect();
    (agent, msgs, log)
}

/// With `foxglove = true` the recording also carries Foxglove's schemas: the design as one
/// scene of every triangle, a frame per pose, one point in `foxglove_every` of each chunk (if
/// it matched) in the design frame coloured by its deviation (without the asbuilt deviations
/// channel), and each report and findings as JSON.
#[test]
fn a_recording_with_foxglove_channels_shows_the_design_stations_and_points() {
    use asbuilt_protocol::foxglove as fx;
    use foxglove::Decode;
    use foxglove::messages::{FrameTransform, PointCloud, SceneUpdate};

    let (agent, msgs, log) = record_bunny("foxglove = true\nfoxglove_every = 4");
    assert!(log.contains("recorder: job"), "{log}");
    let file = recordings(&agent).remove(0);
    let (by_topic, schemas) = by_topic(&std::fs::read(&file).unwrap());
    assert_eq!(schemas[fx::TOPIC_DESIGN], "foxglove.SceneUpdate");
    assert_eq!(schemas[fx::TOPIC_STATIONS], "foxglove.FrameTransform");
    assert_eq!(schemas[fx::TOPIC_DEVIATIONS], "foxglove.PointCloud");
    assert!(
        !by_topic.contains_key(fx::TOPIC_SCANS),
        "the agent shows deviations, not scans"
    );

    // The design: one scene of the bunny's 69,451 triangles.
    let scenes = &by_topic[fx::TOPIC_DESIGN];
    assert_eq!(scenes.len(), 1);
    let scene = SceneUpdate::decode(&scenes[0][..]).unwrap();
    assert_eq!(scene.entities[0].frame_id, fx::DESIGN_FRAME);
    assert_eq!(scene.entities[0].triangles[0].indices.len(), 3 * 69_451);

    // A frame per pose, named for its station.
    let poses: Vec<_> = msgs[0]
        .iter()
        .filter_map(|(_, m)| match m {
            Recorded::Pose(p) => Some(*p),
            _ => None,
        })
        .collect();
    let frames: Vec<FrameTransform> = by_topic[fx::TOPIC_STATIONS]
        .iter()
        .map(|b| FrameTransform::decode(&b[..]).unwrap())
        .collect();
    assert_eq!(frames.len(), poses.len());
    for (f, p) in frames.iter().zip(&poses) {
        assert_eq!(f.parent_frame_id, fx::DESIGN_FRAME);
        assert_eq!(f.child_frame_id, fx::station_frame(p.job, p.station));
        assert_eq!(f.translation.unwrap().x, p.translation[0]);
    }

    // One point in four of each chunk if it matched, though the asbuilt deviations channel is
    // off.
    assert!(
        !msgs[0]
            .iter()
            .any(|(_, m)| matches!(m, Recorded::Deviations(..)))
    );
    let reports: Vec<StationReport> = msgs[0]
        .iter()
        .filter_map(|(_, m)| match m {
            Recorded::Report(r) => Some(**r),
            _ => None,
        })
        .collect();
    let matched: u64 = reports
        .iter()
        .map(|r| r.points_received - r.rejected.total() - r.no_match)
        .sum();
    let mut points = 0u64;
    for b in &by_topic[fx::TOPIC_DEVIATIONS] {
        let c = PointCloud::decode(&b[..]).unwrap();
        assert_eq!(c.frame_id, fx::DESIGN_FRAME);
        assert_eq!(c.point_stride, fx::POINT_STRIDE);
        assert_eq!(c.data.len() % fx::POINT_STRIDE as usize, 0);
        points += (c.data.len() / fx::POINT_STRIDE as usize) as u64;
        // A point on the design is white; one 5 mm out is red.
        for p in c.data.chunks(fx::POINT_STRIDE as usize).take(50) {
            let d = f32::from_le_bytes(p[12..16].try_into().unwrap()) as f64 * 1e-3;
            let rgb = [p[16], p[17], p[18]];
            assert_eq!(rgb, asbuilt_core::colour::deviation_colour(d, 0.005), "{d}");
            assert_eq!(p[19], 255);
        }
    }
    // Places 0, 4, 8, ... of each chunk, less those without a match or rejected.
    let places: u64 = msgs[0]
        .iter()
        .filter_map(|(_, m)| match m {
            Recorded::Chunk(h, _) => Some(u64::from(h.point_count).div_ceil(4)),
            _ => None,
        })
        .sum();
    let unmatched: u64 = reports.iter().map(|r| r.points_received).sum::<u64>() - matched;
    assert!(
        places.saturating_sub(unmatched) <= points && points <= places,
        "{points} points in the clouds, {places} places one in four, {unmatched} unmatched"
    );
    // And the unmatched did not all fall on those places: the cloud shows its share.
    assert!(
        points > 0 && points * 4 >= matched * 9 / 10,
        "{points} of {matched} matched"
    );

    // Reports and findings as JSON a panel reads.
    let json: Vec<Value> = by_topic[fx::json_topic(recording::Channel::Reports).as_str()]
        .iter()
        .map(|b| serde_json::from_slice(b).unwrap())
        .collect();
    assert_eq!(json.len(), reports.len());
    assert_eq!(json[0]["points_received"], reports[0].points_received);
}

#[test]
fn a_long_job_rotates_into_parts_that_each_read_on_their_own() {
    // Uncompressed, so that the bunny job is long enough for three parts.
    let (_agent, files, log) = record_bunny("max_file_mb = 2\ncompression = \"none\"");
    assert!(files.len() >= 3, "{} file(s)\n{log}", files.len());
    let chunks: usize = files
        .iter()
        .flatten()
        .filter(|(_, m)| matches!(m, Recorded::Chunk(..)))
        .count();
    let reports: usize = files
        .iter()
        .flatten()
        .filter(|(_, m)| matches!(m, Recorded::Report(_)))
        .count();
    assert_eq!((chunks, reports), (43, 10));
}

#[test]
fn a_nearly_full_disk_stops_the_scans_but_never_the_reports() {
    let (_agent, files, log) = record_bunny_with("[recorder]\ndir = \"rec\"\nmin_free_mb = 1e12\n");
    assert!(
        log.contains("scan and deviation chunks are no longer recorded"),
        "{log}"
    );
    let all: Vec<&Recorded> = files.iter().flatten().map(|(_, m)| m).collect();
    assert_eq!(
        all.iter()
            .filter(|m| matches!(m, Recorded::Chunk(..)))
            .count(),
        0
    );
    assert_eq!(
        all.iter()
            .filter(|m| matches!(m, Recorded::Report(_)))
            .count(),
        10
    );
    assert!(log.contains("0 scan chunks recorded, 43 left out"), "{log}");
}

/// A recording read back gives what the live agent gave, wherever the file puts a station's End
/// among that station's chunks: the agent reads station events ahead of the chunks still queued,
/// so its recordings can hold an End before, between or after them.
#[test]
fn a_recording_reports_the_live_reports_wherever_a_station_end_is_recorded() {
    let (agent, files, _log) = record_bunny("");
    assert_eq!(files.len(), 1);
    let messages = &files[0];
    let live: BTreeMap<String, StationReport> = messages
        .iter()
        .filter_map(|(_, m)| match m {
            Recorded::Report(r) => Some((r.name.as_str().to_string(), **r)),
            _ => None,
        })
        .collect();
    assert_eq!(live.len(), 10);
    let path = recordings(&agent).remove(0);
    let (meta, attachments) = recording::job(&std::fs::read(path).unwrap()).unwrap();
    let (name, design) = &attachments[0];

    let is_end =
        |m: &Recorded| matches!(m, Recorded::Event(e) if e.kind() == Some(StationEventKind::End));
    for place in ["before", "between", "after"] {
        // Every End taken out, then put back at `place` among its station's chunks.
        let mut moved: Vec<(u64, Recorded)> = messages
            .iter()
            .filter(|(_, m)| !is_end(m))
            .cloned()
            .collect();
        for (t, m) in messages.iter().filter(|(_, m)| is_end(m)) {
            let Recorded::Event(e) = m else {
                unreachable!()
            };
            assert!(e.expected_chunks > 0);
            let chunks: Vec<usize> = (0..moved.len())
                .filter(|&i| {
                    matches!(&moved[i].1, Recorded::Chunk(h, _) if (h.job, h.station) == (e.job, e.station))
                })
                .collect();
            let at = match place {
                "before" => chunks[0],
                "between" => chunks[chunks.len() / 2],
                _ => chunks[chunks.len() - 1] + 1,
            };
            moved.insert(at, (*t, m.clone()));
        }
        let dir = tempfile::tempdir().unwrap();
        let rec = dir.path().join(format!("end-{place}.mcap"));
        let mut w = RecordingWriter::new(std::fs::File::create(&rec).unwrap()).unwrap();
        w.metadata(meta.as_ref().unwrap()).unwrap();
        w.attach_design(name.trim_start_matches("design/"), design, 0)
            .unwrap();
        for (t, m) in &moved {
            w.write(*t, m).unwrap();
        }
        w.finish().unwrap();
        let stations = reported_stations(&rec, &dir.path().join("report"));
        assert_eq!(stations.len(), 10, "End {place} its chunks");
        for s in &stations {
            let r = &live[s["id"].as_str().unwrap()];
            assert_section_matches(s, r, &format!("End {place} the chunks of {}", s["id"]));
        }
    }
}

/// The agent killed with SIGKILL in the middle of a recorded job: `recover`, then `report`, give
/// every station the agent reported before the kill, equal to its live reports. (The agent
/// publishes a report only once the recorder has it on disk.)
#[test]
fn a_job_killed_mid_way_recovers_every_station_reported_before_the_kill() {
    let config = bunny_agent_config(&recorder_section("rec"));
    let prefix = unique_prefix("sigkill");
    let mut agent = Agent::start(AGENT, &prefix, &config);
    let cell = asbuilt_tests::Cell::open(&prefix, 16);
    // Paced, so that the kill lands while stations are still coming.
    let mut publish = publish_command(ASBUILT, &bunny_stations(), &prefix)
        .args(["--chunk-points", "10000", "--rate", "150000"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut live = cell.reports(3, std::time::Duration::from_secs(60));
    assert!(live.len() >= 3, "{}", agent.log());
    agent.signal("KILL");
    agent.wait_exit(std::time::Duration::from_secs(10));
    // Reports that were on their way when the agent died count too.
    live.extend(cell.reports(10, std::time::Duration::from_millis(200)));
    let _ = publish.kill();
    let _ = publish.wait();
    assert!(
        live.len() < 10,
        "the job ended before the kill: {} reports",
        live.len()
    );

    let broken = recordings(&agent).remove(0);
    let dir = tempfile::tempdir().unwrap();
    let fixed = dir.path().join("fixed.mcap");
    run(&["recover", broken.to_str().unwrap(), fixed.to_str().unwrap()]);
    let stations = reported_stations(&fixed, &dir.path().join("report"));
    for r in &live {
        let name = r.name.as_str();
        let s = stations
            .iter()
            .find(|s| s["id"] == name)
            .unwrap_or_else(|| panic!("station {name}, reported live, is not in {stations:#?}"));
        assert_section_matches(s, r, name);
    }
}

/// `asbuilt report` on `recording` into `out`: the stations of its report.json.
fn reported_stations(recording: &Path, out: &Path) -> Vec<Value> {
    run(&[
        "report",
        recording.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let got: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    got["stations"].as_array().unwrap().clone()
}
