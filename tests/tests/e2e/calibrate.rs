//! `asbuilt calibrate` on simulated sphere targets: two robot stations scan five spheres on a
//! floor (0.3 mm range noise), written as PTX by our own writer with the robot's poses in the
//! headers. The command must recover the robot base in the design frame within its σ, name a
//! target whose coordinates are wrong, and refuse targets on one line.

use std::path::Path;
use std::process::{Command, Output};

use asbuilt_core::calibration::sphere::visible_cap;
use asbuilt_io::scan::write::{self, OutScan};
use asbuilt_protocol::ScanPoint;
use nalgebra::{Isometry3, Point3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

const ASBUILT: &str = env!("CARGO_BIN_EXE_e2e-asbuilt");
const R: f64 = 0.0725;

fn truth() -> Isometry3<f64> {
    Isometry3::new(Vector3::new(4.2, -1.3, 0.25), Vector3::new(0.0, 0.0, 0.7))
}

/// Targets in the design frame.
fn targets() -> Vec<Point3<f64>> {
    [
        [4.0, 1.0, 0.8],
        [5.5, 0.2, 1.1],
        [6.1, 1.9, 0.6],
        [4.6, 2.6, 1.4],
        [5.2, 1.2, 0.3],
    ]
    .map(Point3::from)
    .to_vec()
}

fn stations() -> Vec<Isometry3<f64>> {
    vec![
        Isometry3::new(Vector3::new(0.3, 0.2, 1.5), Vector3::new(0.1, -0.2, 0.4)),
        Isometry3::new(Vector3::new(1.8, -0.6, 1.2), Vector3::new(-0.1, 0.1, 2.1)),
    ]
}

/// One PTX file with one scan per station of the given sphere centres (design frame).
fn write_scene(path: &Path, centres: &[Point3<f64>]) {
    let base: Vec<Point3<f64>> = centres.iter().map(|c| truth().inverse() * c).collect();
    write_scans(path, &base, &stations(), &stations());
}

/// Spheres at `centres` (robot base frame) scanned from `scanners` (scanner poses in the base
/// frame); each scan's header holds the matching pose of `written`.
fn write_scans(
    path: &Path,
    centres: &[Point3<f64>],
    scanners: &[Isometry3<f64>],
    written: &[Isometry3<f64>],
) {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let noise = Normal::new(0.0, 0.0003).unwrap();
    let scans: Vec<(OutScan, Vec<ScanPoint>)> = scanners
        .iter()
        .zip(written)
        .enumerate()
        .map(|(k, (pose, header))| {
            let eye = Point3::from(pose.translation.vector);
            let mut pts: Vec<Point3<f64>> = centres
                .iter()
                .flat_map(|c| visible_cap(*c, R, eye, 0.003))
                .collect();
            for i in 0..150 {
                for j in 0..150 {
                    pts.push(Point3::new(
                        i as f64 * 0.02 - 1.0,
                        j as f64 * 0.02 - 1.0,
                        0.0,
                    ));
                }
            }
            let local: Vec<ScanPoint> = pts
                .iter()
                .map(|p| {
                    let q = pose.inverse() * p;
                    let d = q.coords.normalize() * noise.sample(&mut rng);
                    ScanPoint::new((q.x + d.x) as f32, (q.y + d.y) as f32, (q.z + d.z) as f32)
                })
                .collect();
            (
                OutScan {
                    name: format!("station {k}"),
                    pose: *header,
                    points: local.len() as u64,
                },
                local,
            )
        })
        .collect();
    let total = scans.iter().map(|s| s.1.len() as u64).sum();
    let mut w = write::create(path, total).unwrap();
    for (s, pts) in &scans {
        w.write_scan(s, &mut |emit| emit(pts)).unwrap();
    }
    w.finish().unwrap();
}

fn write_targets(path: &Path, targets: &[Point3<f64>]) {
    let mut text = String::new();
    for (k, t) in targets.iter().enumerate() {
        text.push_str(&format!(
            "[[target]]\nid = \"T{}\"\nposition = [{}, {}, {}]\n\n",
            k + 1,
            t.x,
            t.y,
            t.z
        ));
    }
    std::fs::write(path, text).unwrap();
}

fn calibrate(dir: &Path, extra: &[&str]) -> Output {
    Command::new(ASBUILT)
        .arg("calibrate")
        .args(["--targets", dir.join("targets.toml").to_str().unwrap()])
        .args(["--radius", &R.to_string()])
        .args(["--out", dir.join("calibration.toml").to_str().unwrap()])
        .arg(dir.join("scene.ptx"))
        .args(extra)
        .output()
        .unwrap()
}

#[derive(serde::Deserialize)]
struct Written {
    calibration: Calib,
}
#[derive(serde::Deserialize)]
struct Calib {
    t_design_base: Pose,
}
#[derive(serde::Deserialize)]
struct Pose {
    translation: [f64; 3],
    rotation_xyzw: [f64; 4],
}

#[test]
fn the_robot_base_is_recovered_within_its_sigma() {
    let dir = tempfile::tempdir().unwrap();
    write_scene(&dir.path().join("scene.ptx"), &targets());
    write_targets(&dir.path().join("targets.toml"), &targets());
    let o = calibrate(dir.path(), &[]);
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "{out}\n{err}");
    assert!(
        err.contains("5 sphere(s) of radius 0.0725 m found, 5 matched"),
        "{err}"
    );
    assert!(
        err.contains("pose from the PTX header's transform"),
        "{err}"
    );
    let text = std::fs::read_to_string(dir.path().join("calibration.toml")).unwrap();
    let w: Written = toml::from_str(&text).unwrap();
    let got = asbuilt_core::frames::isometry(
        w.calibration.t_design_base.translation,
        w.calibration.t_design_base.rotation_xyzw,
    )
    .unwrap();
    // Where it matters: at the targets.
    let worst = targets()
        .iter()
        .map(|a| (got * (truth().inverse() * a) - a).norm())
        .fold(0.0, f64::max);
    println!("{out}\nworst error at a target: {:.3} mm", worst * 1e3);
    assert!(worst < 0.0005, "{worst}");
    // Every one of the 10 spheres has a residual line.
    assert_eq!(
        out.lines().filter(|l| l.starts_with('T')).count(),
        10,
        "{out}"
    );
}

#[test]
fn a_target_with_wrong_coordinates_is_named() {
    let dir = tempfile::tempdir().unwrap();
    write_scene(&dir.path().join("scene.ptx"), &targets());
    let mut wrong = targets();
    wrong[2] += Vector3::new(0.0, 0.03, 0.0);
    write_targets(&dir.path().join("targets.toml"), &wrong);
    let o = calibrate(dir.path(), &["--match-tolerance", "0.05"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("target T3 (stations"), "{err}");
    assert!(err.contains("--exclude T3"), "{err}");
    // Left out, the rest calibrates cleanly.
    let o = calibrate(
        dir.path(),
        &["--match-tolerance", "0.05", "--exclude", "T3"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn targets_on_one_line_are_refused_and_fixed_orientation_still_works() {
    let dir = tempfile::tempdir().unwrap();
    let line: Vec<Point3<f64>> = (0..3)
        .map(|i| Point3::new(4.0 + 0.6 * i as f64, 1.0 + 0.4 * i as f64, 0.8))
        .collect();
    write_scene(&dir.path().join("scene.ptx"), &line);
    write_targets(&dir.path().join("targets.toml"), &line);
    let o = calibrate(dir.path(), &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("on one line"), "{err}");
    // With the rotation known, a line of targets fixes the translation.
    let q = truth().rotation.quaternion().coords;
    let rot = format!("{},{},{},{}", q.x, q.y, q.z, q.w);
    let o = calibrate(
        dir.path(),
        &["--fixed-orientation", "--rotation-xyzw", &rot],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let w: Written =
        toml::from_str(&std::fs::read_to_string(dir.path().join("calibration.toml")).unwrap())
            .unwrap();
    let t = Vector3::from(w.calibration.t_design_base.translation);
    assert!((t - truth().translation.vector).norm() < 0.0005, "{t}");
}

#[derive(serde::Deserialize)]
struct WrittenFlange {
    calibration: CalibFlange,
}
#[derive(serde::Deserialize)]
struct CalibFlange {
    t_flange_scanner: Pose,
}

/// The scanner's mount on the flange, from targets known in the robot base frame and the
/// flange's pose at three stations.
#[test]
fn the_scanner_mount_on_the_flange_is_recovered() {
    let dir = tempfile::tempdir().unwrap();
    let mount = Isometry3::new(
        Vector3::new(0.05, -0.12, 0.31),
        Vector3::new(0.2, -1.4, 0.1),
    );
    let flanges = [
        Isometry3::new(Vector3::new(0.3, 0.2, 1.5), Vector3::new(0.1, -0.2, 0.4)),
        Isometry3::new(Vector3::new(1.8, -0.6, 1.2), Vector3::new(-0.1, 0.1, 2.1)),
        Isometry3::new(Vector3::new(0.9, -1.2, 1.8), Vector3::new(0.3, 0.2, -0.6)),
    ];
    let scanners: Vec<_> = flanges.iter().map(|f| f * mount).collect();
    // Targets in the base frame, in front of every scanner.
    let base: Vec<Point3<f64>> = targets().iter().map(|c| truth().inverse() * c).collect();
    write_scans(&dir.path().join("scene.ptx"), &base, &scanners, &flanges);
    write_targets(&dir.path().join("targets.toml"), &base);
    let o = calibrate(dir.path(), &["--solve", "flange-scanner"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let w: WrittenFlange =
        toml::from_str(&std::fs::read_to_string(dir.path().join("calibration.toml")).unwrap())
            .unwrap();
    let got = asbuilt_core::frames::isometry(
        w.calibration.t_flange_scanner.translation,
        w.calibration.t_flange_scanner.rotation_xyzw,
    )
    .unwrap();
    let off = got * mount.inverse();
    assert!(off.translation.vector.norm() < 0.0005, "{off}");
    assert!(off.rotation.angle() < 1e-3, "{off}");
}
