//! Valid files to mutate: written by our own writers, and taken from `../shared/data` where a
//! file is under 1 MB.

use std::path::Path;

use anyhow::{Context, Result};
use asbuilt_io::scan::write::{OutScan, create};
use asbuilt_protocol::recording::{ChunkCompression, JobMetadata, Recorded, RecordingWriter};
use asbuilt_protocol::{
    AgentStatus, ChunkHeader, DeviationHeader, PointDeviation, PoseMode, PoseSnapshot, ScanPoint,
    StationEvent, StationEventKind, StationFindings, StationReport,
};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};

/// The agent configuration the seed recordings carry, and a seed of the agent.toml target. With
/// findings on, `asbuilt report` runs the agent's findings stage over every mutated recording.
pub const AGENT_TOML: &str = "[design]\npath = \"box.stl\"\nunits = \"m\"\n\
    [inspect]\ntolerance = 0.005\nmax_distance = 0.05\n\
    [limits]\nmax_points_per_chunk = 4096\npending_chunks = 4\n\
    [findings]\nenabled = true\nspacing = 0.02\nlayer_height = 0.05\n\
    [calibration]\nt_design_base = { translation = [0.1, 0.0, 0.0], rotation_xyzw = [0.0, 0.0, 0.0, 1.0] }\n";

/// Writes every target's seeds under `dir/<target>/`.
pub fn write_seeds(dir: &Path, shared: &Path) -> Result<()> {
    let sub = |name: &str| -> Result<std::path::PathBuf> {
        let d = dir.join(name);
        std::fs::create_dir_all(&d).with_context(|| format!("cannot create {}", d.display()))?;
        Ok(d)
    };
    for (target, ext) in [
        ("scan-ply", "ply"),
        ("scan-xyz", "xyz"),
        ("scan-ptx", "ptx"),
        ("scan-las", "las"),
        ("scan-laz", "laz"),
        ("scan-e57", "e57"),
    ] {
        let d = sub(target)?;
        for (k, n) in [(0, 40u64), (1, 700)] {
            write_cloud(&d.join(format!("ours-{k}.{ext}")), n, 1 + k as usize)?;
        }
    }
    std::fs::write(
        sub("scan-ply")?.join("ascii.ply"),
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
         property float z\nproperty uchar intensity\nend_header\n0 0 0 1\n1 0 0 2\n0 1 0.5 3\n",
    )?;
    std::fs::write(
        sub("scan-xyz")?.join("plain.pts"),
        "3\n0.1 0.2 0.3 10\n1.5 -2 3e-3 20\n7 8 9 30\n",
    )?;
    copy_small(shared, "autzen-m3c2", "las", &sub("scan-las")?)?;
    copy_small(shared, "e57", "e57", &sub("scan-e57")?)?;

    let d = sub("design-stl")?;
    crate::write_box_stl(&d.join("box-ascii.stl"), [0.0; 3], [1.0, 0.5, 0.25]);
    write_binary_stl(&d.join("box-binary.stl"))?;
    let d = sub("design-ply")?;
    std::fs::write(d.join("box.ply"), box_ply())?;
    copy_small(shared, "stanford-bunny", "ply", &d)?;
    let d = sub("design-obj")?;
    std::fs::write(d.join("box.obj"), box_obj())?;

    let d = sub("wire")?;
    for (i, m) in wire_messages().iter().enumerate() {
        std::fs::write(d.join(format!("{i:02}-{:?}.bin", m.channel())), m.encode())?;
    }
    for target in ["recording", "report", "resume"] {
        let d = sub(target)?;
        for compression in [
            ChunkCompression::None,
            ChunkCompression::Lz4,
            ChunkCompression::Zstd,
        ] {
            let path = d.join(format!("job-{compression:?}.mcap").to_lowercase());
            std::fs::write(&path, recording(compression)?)?;
        }
    }
    write_bags(&sub("ros2-mcap")?, &sub("ros2-db3")?)?;
    std::fs::write(sub("agent-toml")?.join("agent.toml"), AGENT_TOML)?;
    // The shipped example, with its design where the target puts one.
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("../agent/agent.example.toml");
    let text = std::fs::read_to_string(&example)
        .with_context(|| format!("cannot read {}", example.display()))?;
    let text: Vec<String> = text
        .lines()
        .map(|l| {
            if l.starts_with("path = ") {
                "path = \"box.stl\"".to_string()
            } else {
                l.to_string()
            }
        })
        .collect();
    std::fs::write(dir.join("agent-toml/agent.example.toml"), text.join("\n"))?;
    Ok(())
}

/// ROS 2 bags in both storages: a flange moved on /tf, the scanner on /tf_static, clouds of
/// each layout (float32 and float64, both byte orders).
fn write_bags(mcap: &Path, db3: &Path) -> Result<()> {
    use asbuilt_io::scan::ros2::sample::{SampleCloud, SampleTransform, write_mcap, write_sqlite};
    use nalgebra::Isometry3;
    let mut tf = vec![SampleTransform {
        stamp: 1.0,
        parent: "flange".into(),
        child: "scanner".into(),
        pose: Isometry3::translation(0.05, 0.0, 0.1),
        fixed: true,
    }];
    tf.extend((0..20).map(|k| SampleTransform {
        stamp: 1.0 + 0.02 * k as f64,
        parent: "world".into(),
        child: "flange".into(),
        pose: Isometry3::translation(0.01 * k as f64, 0.0, 1.0),
        fixed: false,
    }));
    let clouds: Vec<SampleCloud> = [(false, false), (true, false), (false, true)]
        .into_iter()
        .enumerate()
        .map(|(k, (float64, big_endian))| SampleCloud {
            stamp: 1.05 + 0.1 * k as f64,
            frame: "scanner".into(),
            points: (0..6).map(|i| [0.1 * i as f64, 0.2, -1.0]).collect(),
            float64,
            big_endian,
        })
        .collect();
    write_mcap(&mcap.join("bag.mcap"), "/points", &clouds, &tf)?;
    write_sqlite(&db3.join("bag.db3"), "/points", &clouds, &tf)?;
    Ok(())
}

/// Files of `shared/<folder>` the readers refuse by design (test files of the E57 library).
const REFUSED: [&str; 3] = ["corrupt_crc.e57", "empty.e57", "read_error.e57"];

/// Every file of `shared/<folder>` ending in `.ext` and under 1 MB; those meant to be refused
/// are named `bad-…`.
fn copy_small(shared: &Path, folder: &str, ext: &str, to: &Path) -> Result<()> {
    let from = shared.join(folder);
    for e in std::fs::read_dir(&from).with_context(|| format!("cannot list {}", from.display()))? {
        let p = e?.path();
        let small = p.metadata()?.len() < 1 << 20;
        if small && p.extension().is_some_and(|x| x == ext) {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            let to_name = if REFUSED.contains(&name.as_str()) {
                format!("bad-{name}")
            } else {
                name
            };
            std::fs::copy(&p, to.join(to_name))?;
        }
    }
    Ok(())
}

fn points(n: u64, scan: usize) -> Vec<ScanPoint> {
    (0..n)
        .map(|i| {
            let t = i as f32 * 0.37 + scan as f32;
            let mut p = ScanPoint::new(t.sin() * 2.0, t.cos() * 2.0, 0.01 * i as f32);
            p.intensity = (i % 7) as f32 / 7.0;
            p
        })
        .collect()
}

/// A cloud of `scans` scans with poses, written by our writer for `path`'s format.
fn write_cloud(path: &Path, n: u64, scans: usize) -> Result<()> {
    let mut w = create(path, n * scans as u64)?;
    for s in 0..scans {
        let scan = OutScan {
            name: format!("scan{s}"),
            pose: Isometry3::from_parts(
                Translation3::new(s as f64, 0.5, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3 * s as f64),
            ),
            points: n,
        };
        let pts = points(n, s);
        w.write_scan(&scan, &mut |sink| sink(&pts))?;
    }
    Ok(w.finish()?)
}

fn box_corners() -> [[f32; 3]; 8] {
    std::array::from_fn(|i| {
        [
            (i & 1) as f32,
            ((i >> 1) & 1) as f32 * 0.5,
            ((i >> 2) & 1) as f32 * 0.25,
        ]
    })
}

const BOX_FACES: [[usize; 3]; 12] = [
    [0, 2, 1],
    [1, 2, 3],
    [4, 5, 6],
    [5, 7, 6],
    [0, 1, 4],
    [1, 5, 4],
    [2, 6, 3],
    [3, 6, 7],
    [0, 4, 2],
    [2, 4, 6],
    [1, 3, 5],
    [3, 7, 5],
];

fn write_binary_stl(path: &Path) -> Result<()> {
    let c = box_corners();
    let mut b = vec![0u8; 80];
    b.extend_from_slice(&(BOX_FACES.len() as u32).to_le_bytes());
    for f in BOX_FACES {
        b.extend_from_slice(&[0u8; 12]);
        for v in f {
            for x in c[v] {
                b.extend_from_slice(&x.to_le_bytes());
            }
        }
        b.extend_from_slice(&[0, 0]);
    }
    Ok(std::fs::write(path, b)?)
}

fn box_ply() -> String {
    let mut s = String::from(
        "ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\n\
         property float z\nelement face 12\nproperty list uchar int vertex_indices\nend_header\n",
    );
    for v in box_corners() {
        s += &format!("{} {} {}\n", v[0], v[1], v[2]);
    }
    for f in BOX_FACES {
        s += &format!("3 {} {} {}\n", f[0], f[1], f[2]);
    }
    s
}

fn box_obj() -> String {
    let mut s = String::from("# box\no box\n");
    for v in box_corners() {
        s += &format!("v {} {} {}\n", v[0], v[1], v[2]);
    }
    for f in BOX_FACES {
        s += &format!("f {} {} {}\n", f[0] + 1, f[1] + 1, f[2] + 1);
    }
    s
}

/// One message of every kind a peer or a recording can hold.
fn wire_messages() -> Vec<Recorded> {
    let mut begin = StationEvent::new(StationEventKind::Begin, 3, 1);
    begin.expected_chunks = 2;
    begin.printed_height = 0.2;
    let mut end = StationEvent::new(StationEventKind::End, 3, 1);
    end.expected_chunks = 2;
    let mut pose = PoseSnapshot::new(3, 1, PoseMode::DesignScanner);
    pose.translation = [0.5, -2.0, 0.3];
    let pts = points(30, 0);
    let mut report = StationReport::new(3, 1);
    report.points_received = 30;
    vec![
        Recorded::Event(begin),
        Recorded::Pose(pose),
        Recorded::Chunk(ChunkHeader::new(3, 1, 0, 30), pts.clone()),
        Recorded::Chunk(ChunkHeader::new(3, 1, 1, 30), pts),
        Recorded::Event(end),
        Recorded::Deviations(
            {
                let mut h = DeviationHeader::new(3, 1, 0);
                h.point_count = 10;
                h
            },
            vec![PointDeviation::default(); 10],
        ),
        Recorded::Report(Box::new(report)),
        Recorded::Status(Box::new(AgentStatus::new(42))),
        Recorded::Findings(Box::new(StationFindings::new(3, 1))),
        Recorded::Correction(Box::new(asbuilt_protocol::LayerCorrection::neutral(
            3, 1, 1, 0,
        ))),
        Recorded::Applied(asbuilt_protocol::LayerApplied::nominal(3, 0)),
        // A line profiler's pass 1: two mount poses 4 ms apart, a chunk of two profiles
        // between them.
        Recorded::MountPose(asbuilt_protocol::MountPose::new(3, 1, 0, 1_000_000_000)),
        Recorded::Profiles(
            Box::new({
                let mut h = asbuilt_protocol::ProfileHeader::new(3, 1, 0);
                h.push(1_001_000_000, 3);
                h.push(1_002_000_000, 3);
                h
            }),
            vec![asbuilt_protocol::ProfilePoint { x: 0.01, z: 0.1 }; 6],
        ),
        Recorded::MountPose({
            let mut m = asbuilt_protocol::MountPose::new(3, 1, 1, 1_004_000_000);
            m.translation = [0.001, 0.0, 0.0];
            m
        }),
        Recorded::Surface(Box::new({
            let mut s = asbuilt_protocol::SurfaceFindings::new(3, 1);
            s.flatness_standard = asbuilt_protocol::FixedText::truncated("din18202:6");
            let _ = s.flatness.push(asbuilt_protocol::FlatnessRow {
                face: 0,
                direction: 1,
                verdict: asbuilt_protocol::SurveyVerdict::Fail,
                span: 0.1,
                gap: 0.004,
                support_distance: 0.1,
                limit: 0.003,
                uncertainty: 0.0003,
                at: [0.0, 0.0, 0.1],
            });
            s
        })),
    ]
}

/// A small job as the agent records it: metadata, the design, three stations, their outputs.
fn recording(compression: ChunkCompression) -> Result<Vec<u8>> {
    let mut w = RecordingWriter::with_compression(std::io::Cursor::new(Vec::new()), compression)?;
    w.metadata(&JobMetadata {
        writer: "asbuilt-agent".into(),
        config: AGENT_TOML.into(),
        design_path: "box.stl".into(),
        design_units: "m".into(),
        design_sha256: "0".repeat(64),
        ..Default::default()
    })?;
    let stl = std::env::temp_dir().join(format!("asbuilt-fuzz-box-{}.stl", std::process::id()));
    crate::write_box_stl(&stl, [0.0; 3], [1.0, 0.5, 0.25]);
    let design = std::fs::read(&stl)?;
    let _ = std::fs::remove_file(&stl);
    w.attach_design("box.stl", &design, 0)?;
    let mut t = 0;
    for station in 0..3u32 {
        for mut m in wire_messages() {
            match &mut m {
                Recorded::Event(e) => e.station = station,
                Recorded::Pose(p) => p.station = station,
                Recorded::Chunk(h, _) => h.station = station,
                Recorded::Report(r) => r.station = station,
                _ => {}
            }
            t += 1_000_000;
            w.write(t, &m)?;
        }
    }
    Ok(w.finish()?.into_inner())
}
