//! Scan files as a user feeds them to the command line: a PTX job whose poses are in its headers
//! needs no stations file, and `convert` turns the shared E57 bunny into files CloudCompare opens.

use std::process::Command;

use asbuilt_io::scan::write::{self, OutScan};
use asbuilt_protocol::ScanPoint;
use asbuilt_tests::{shared_data, write_box_stl};
use nalgebra::{Isometry3, Point3, Vector3};

const ASBUILT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt");

/// An agent on the box `stl` (metres) at 5 mm tolerance, serving under `prefix`.
fn box_agent(prefix: &str, stl: &std::path::Path) -> asbuilt_tests::Agent {
    asbuilt_tests::Agent::start(
        env!("CARGO_BIN_EXE_e2e-asbuilt-agent"),
        prefix,
        &format!(
            "[design]\npath = {:?}\nunits = \"m\"\n[inspect]\ntolerance = 0.005\n",
            stl.display().to_string()
        ),
    )
}

/// The top and front of a 1 × 0.5 × 0.4 m box as two scans taken from two poses.
fn write_ptx_job(path: &std::path::Path) -> usize {
    let poses = [
        Isometry3::new(Vector3::new(0.5, -2.0, 1.0), Vector3::new(0.3, 0.0, 0.2)),
        Isometry3::new(Vector3::new(-1.0, 0.3, 1.5), Vector3::new(0.0, -0.4, 1.2)),
    ];
    let mut scans = Vec::new();
    for (k, pose) in poses.iter().enumerate() {
        let mut pts = Vec::new();
        for i in 0..100 {
            for j in 0..50 {
                let (x, y) = (i as f64 * 0.01 + 0.005, j as f64 * 0.01 + 0.005);
                let p = if k == 0 {
                    Point3::new(x, 0.0, y * 0.8)
                } else {
                    Point3::new(x, y, 0.4)
                };
                let q = pose.inverse() * p;
                pts.push(ScanPoint::new(q.x as f32, q.y as f32, q.z as f32));
            }
        }
        scans.push((
            OutScan {
                name: format!("scan {k}"),
                pose: *pose,
                points: pts.len() as u64,
            },
            pts,
        ));
    }
    let total = scans.iter().map(|s| s.1.len() as u64).sum();
    let mut w = write::create(path, total).unwrap();
    for (s, pts) in &scans {
        w.write_scan(s, &mut |emit| emit(pts)).unwrap();
    }
    w.finish().unwrap();
    total as usize
}

#[test]
fn a_ptx_job_is_inspected_with_the_poses_in_its_headers() {
    let dir = tempfile::tempdir().unwrap();
    write_box_stl(&dir.path().join("box.stl"), [0.0; 3], [1.0, 0.5, 0.4]);
    let points = write_ptx_job(&dir.path().join("job.ptx"));
    let out = dir.path().join("out");
    let o = Command::new(ASBUILT)
        .arg("inspect")
        .args(["--design", dir.path().join("box.stl").to_str().unwrap()])
        .args([
            "--units",
            "m",
            "--scan",
            dir.path().join("job.ptx").to_str().unwrap(),
        ])
        .args(["--out", out.to_str().unwrap(), "--ascii"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("station job/scan 0: pose from the PTX header's transform"),
        "{err}"
    );
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let stations = r["stations"].as_array().unwrap();
    assert_eq!(stations.len(), 2);
    assert_eq!(stations[1]["id"], "job/scan 1");
    for s in stations {
        assert_eq!(s["matched"], 5000);
        // f32 scanner coordinates a few metres out: well under 0.01 mm.
        assert!(s["p95_abs"].as_f64().unwrap() < 1e-5, "{s}");
    }
    let text = std::fs::read_to_string(out.join("deviations.txt")).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("//X Y Z C2M Triangle Station Feature Flags")
    );
    assert_eq!(lines.count(), points);
}

#[test]
fn convert_writes_the_e57_bunny_as_ply_ascii_and_ptx() {
    let dir = tempfile::tempdir().unwrap();
    let bunny = shared_data().join("e57/bunnyFloat.e57");
    for name in ["bunny.ply", "bunny.txt", "bunny.ptx", "bunny.las"] {
        let out = dir.path().join(name);
        let o = Command::new(ASBUILT)
            .arg("convert")
            .arg(&bunny)
            .args(["--out", out.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let back = asbuilt_io::scan::ScanFile::open(&out).unwrap();
        let (pts, _) = back.read_all(0).unwrap();
        assert_eq!(pts.len(), 30_571, "{name}");
    }
    let head = std::fs::read(dir.path().join("bunny.ply")).unwrap();
    let head = String::from_utf8_lossy(&head[..300]);
    assert!(head.contains("property float intensity") && head.contains("property ushort scan"));
    let o = Command::new(ASBUILT)
        .args(["convert", "a.e57", "--out", "b.docx"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown scan format .docx"));
}

/// `asbuilt publish FILE` streams every scan of a file that holds its poses into a running
/// agent, one station each.
#[test]
fn publish_streams_a_ptx_job_into_the_agent() {
    let dir = tempfile::tempdir().unwrap();
    let stl = dir.path().join("box.stl");
    write_box_stl(&stl, [0.0; 3], [1.0, 0.5, 0.4]);
    write_ptx_job(&dir.path().join("job.ptx"));
    let prefix = asbuilt_tests::unique_prefix("ptx");
    let agent = box_agent(&prefix, &stl);
    let o = Command::new(ASBUILT)
        .arg("publish")
        .arg(dir.path().join("job.ptx"))
        .args(["--prefix", &prefix, "--chunk-points", "1000"])
        .output()
        .unwrap();
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "{out}\n{err}\nagent:\n{}", agent.log());
    assert!(
        err.contains("station job/scan 1: pose from the PTX header's transform"),
        "{err}"
    );
    assert_eq!(
        out.matches("Complete: 5000 points, 5000 matched").count(),
        2,
        "{out}"
    );
}

/// A cell's ROS 2 bag of the box: the scanner on a moving flange, a cloud of the top from each
/// of three stamps between /tf samples.
fn write_box_bag(path: &std::path::Path) {
    use asbuilt_io::scan::ros2::interpolate;
    use asbuilt_io::scan::ros2::sample::{SampleCloud, SampleTransform, write_mcap};
    let flange = |t: f64| {
        Isometry3::new(
            Vector3::new(0.5 + 1.5 * (0.2 * t).cos(), 1.5 * (0.2 * t).sin(), 1.2),
            Vector3::new(0.0, 0.0, 0.2 * t + 3.0),
        )
    };
    let mount = Isometry3::new(Vector3::new(0.05, 0.0, 0.1), Vector3::new(0.0, 0.3, 0.0));
    let mut tf = vec![SampleTransform {
        stamp: 0.0,
        parent: "flange".into(),
        child: "scanner".into(),
        pose: mount,
        fixed: true,
    }];
    tf.extend((0..=250).map(|k| SampleTransform {
        stamp: k as f64 * 0.02,
        parent: "world".into(),
        child: "flange".into(),
        pose: flange(k as f64 * 0.02),
        fixed: false,
    }));
    let clouds = [0.513, 2.207, 4.391]
        .iter()
        .map(|&t: &f64| {
            let k = (t / 0.02).floor();
            let s = (t - k * 0.02) / 0.02;
            let pose = interpolate(&flange(k * 0.02), &flange((k + 1.0) * 0.02), s) * mount;
            let points = (0..2000)
                .map(|i| {
                    let p = Point3::new(
                        0.01 + (i % 50) as f64 * 0.02,
                        0.01 + (i / 50) as f64 * 0.012,
                        0.401,
                    );
                    let q = pose.inverse() * p;
                    [q.x, q.y, q.z]
                })
                .collect();
            SampleCloud {
                stamp: t,
                frame: "scanner".into(),
                points,
                float64: false,
                big_endian: false,
            }
        })
        .collect::<Vec<_>>();
    write_mcap(path, "/scanner/points", &clouds, &tf).unwrap();
}

/// The same bag through `inspect --ros2`, `pack --ros2` then `report`, and `publish --ros2` into
/// a running agent: the same stations, the same statistics.
#[test]
fn a_ros2_bag_is_inspected_packed_and_published_alike() {
    let dir = tempfile::tempdir().unwrap();
    let stl = dir.path().join("box.stl");
    write_box_stl(&stl, [0.0; 3], [1.0, 0.5, 0.4]);
    let bag = dir.path().join("bag.mcap");
    write_box_bag(&bag);
    let run = |args: &[&std::ffi::OsStr]| {
        let o = Command::new(ASBUILT).args(args).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{args:?}: {err}");
        (String::from_utf8_lossy(&o.stdout).into_owned(), err)
    };
    let os = |s: &str| std::ffi::OsString::from(s);
    let (inspect_dir, report_dir) = (dir.path().join("inspect"), dir.path().join("report"));
    let (_, err) = run(&[
        &os("inspect"),
        &os("--design"),
        stl.as_os_str(),
        &os("--units"),
        &os("m"),
        &os("--ros2"),
        bag.as_os_str(),
        &os("--out"),
        inspect_dir.as_os_str(),
    ]);
    assert!(
        err.contains("3 cloud(s) on /scanner/points (3 placed in \"world\""),
        "{err}"
    );
    let packed = dir.path().join("packed.mcap");
    run(&[
        &os("pack"),
        &os("--ros2"),
        bag.as_os_str(),
        &os("--design"),
        stl.as_os_str(),
        &os("--units"),
        &os("m"),
        &os("--out"),
        packed.as_os_str(),
    ]);
    run(&[
        &os("report"),
        packed.as_os_str(),
        &os("--out"),
        report_dir.as_os_str(),
    ]);
    let stations = |d: &std::path::Path| {
        let v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.join("report.json")).unwrap()).unwrap();
        v["stations"].as_array().unwrap().clone()
    };
    let (a, b) = (stations(&inspect_dir), stations(&report_dir));
    assert_eq!(a.len(), 3);
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x["id"], y["id"]);
        for key in [
            "points",
            "matched",
            "mean",
            "std",
            "median_abs",
            "p95_abs",
            "max",
        ] {
            assert_eq!(x[key], y[key], "{key} of {}", x["id"]);
        }
        // The top is scanned 1 mm above the box, wherever the robot stood.
        assert!(
            (x["median_abs"].as_f64().unwrap() - 0.001).abs() < 2e-5,
            "{x}"
        );
    }
    let prefix = asbuilt_tests::unique_prefix("ros2");
    let agent = box_agent(&prefix, &stl);
    let o = Command::new(ASBUILT)
        .arg("publish")
        .arg("--ros2")
        .arg(&bag)
        .args(["--prefix", &prefix, "--chunk-points", "1000"])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{out}\nagent:\n{}", agent.log());
    assert_eq!(
        out.matches("Complete: 2000 points, 2000 matched").count(),
        3,
        "{out}"
    );
}
