//! The bag reader against bags whose truth is known: the points each station should give, in
//! its frame, whatever the storage, the number type or the byte order.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use super::sample::{SampleCloud, SampleTransform, write_mcap, write_sqlite};
use super::*;
use crate::scan::ScanFile;

/// The flange at time t (s): on a circle, turning.
fn flange(t: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(2.0 * (0.1 * t).cos(), 2.0 * (0.1 * t).sin(), 1.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.1 * t + 3.0),
    )
}

fn mount() -> Isometry3<f64> {
    Isometry3::translation(0.05, 0.0, 0.1)
}

/// /tf at 50 Hz from 10 s to 20 s, and the mount on /tf_static.
fn transforms() -> Vec<SampleTransform> {
    let mut out = vec![SampleTransform {
        stamp: 10.0,
        parent: "flange".into(),
        child: "scanner".into(),
        pose: mount(),
        fixed: true,
    }];
    out.extend((0..=500).map(|k| {
        let t = 10.0 + k as f64 * 0.02;
        SampleTransform {
            stamp: t,
            parent: "world".into(),
            child: "flange".into(),
            pose: flange(t),
            fixed: false,
        }
    }));
    out
}

/// World points of cloud `k`, and the cloud as the scanner at its sampled pose saw them.
fn cloud(k: usize, stamp: f64, float64: bool, big_endian: bool) -> (Vec<Point3<f64>>, SampleCloud) {
    let world: Vec<Point3<f64>> = (0..50)
        .map(|i| {
            Point3::new(
                0.1 * k as f64 + 0.01 * i as f64,
                0.5,
                1.0 + 0.001 * i as f64,
            )
        })
        .collect();
    // At a stamp on a /tf sample, the tree's pose is the sample itself.
    let pose = flange(stamp) * mount();
    let points = world
        .iter()
        .map(|p| {
            let q = pose.inverse() * p;
            [q.x, q.y, q.z]
        })
        .collect();
    let c = SampleCloud {
        stamp,
        frame: "scanner".into(),
        points,
        float64,
        big_endian,
    };
    (world, c)
}

/// Station `index`'s points placed in the world by its pose.
fn placed(file: &ScanFile, index: usize) -> Vec<Point3<f64>> {
    let pose = file.scans[index].pose.expect("placed").0;
    let (points, _) = file.read_all(index).unwrap();
    points
        .iter()
        .map(|p| pose * Point3::new(p.xyz[0] as f64, p.xyz[1] as f64, p.xyz[2] as f64))
        .collect()
}

fn write_both(dir: &Path, clouds: &[SampleCloud]) -> [std::path::PathBuf; 2] {
    let mcap = dir.join("bag.mcap");
    let db3 = dir.join("bag.db3");
    write_mcap(&mcap, "/points", clouds, &transforms()).unwrap();
    write_sqlite(&db3, "/points", clouds, &transforms()).unwrap();
    [mcap, db3]
}

#[test]
fn every_storage_layout_and_byte_order_gives_the_points_where_they_were() {
    let dir = tempfile::tempdir().unwrap();
    let mut truth = Vec::new();
    let mut clouds = Vec::new();
    for (k, (stamp, f64s, big)) in [
        (11.0, false, false),
        (12.5, true, false),
        (14.02, false, true),
    ]
    .into_iter()
    .enumerate()
    {
        let (w, c) = cloud(k, stamp, f64s, big);
        truth.push(w);
        clouds.push(c);
    }
    for bag in write_both(dir.path(), &clouds) {
        let opened = Ros2Bag::open(&bag, &Ros2Options::default()).unwrap();
        assert!(
            opened
                .describe()
                .starts_with("3 cloud(s) on /points (3 placed"),
            "{}",
            opened.describe()
        );
        let file = ScanFile::of_ros2(&bag, std::sync::Arc::new(opened));
        assert_eq!(file.scans.len(), 3);
        for (k, want) in truth.iter().enumerate() {
            assert_eq!(file.scans[k].name, format!("points-{:04}", k + 1));
            let got = placed(&file, k);
            assert_eq!(got.len(), want.len());
            for (g, w) in got.iter().zip(want) {
                // f32 in the scanner frame, a few metres out.
                assert!((g - w).norm() < 1e-6, "{}: {g} vs {w}", bag.display());
            }
            let (points, _) = file.read_all(k).unwrap();
            assert_eq!(points[7].intensity, 7.0);
        }
    }
}

#[test]
fn windows_gather_clouds_into_stations_each_in_its_first_cloud_s_frame() {
    let dir = tempfile::tempdir().unwrap();
    let stamps = [11.0, 11.1, 11.2, 15.0, 18.0];
    let (truth, clouds): (Vec<_>, Vec<_>) = stamps
        .iter()
        .enumerate()
        .map(|(k, &t)| cloud(k, t, false, false))
        .unzip();
    let [bag, _] = write_both(dir.path(), &clouds);
    let windows = vec![
        StationWindow {
            id: "L008-S1".into(),
            from: 10.9,
            to: 11.25,
        },
        StationWindow {
            id: "L016-S1".into(),
            from: 14.0,
            to: 16.0,
        },
        StationWindow {
            id: "empty".into(),
            from: 19.0,
            to: 19.5,
        },
    ];
    let options = Ros2Options {
        stations: Some(windows),
        ..Default::default()
    };
    let file = ScanFile::of_ros2(
        &bag,
        std::sync::Arc::new(Ros2Bag::open(&bag, &options).unwrap()),
    );
    let names: Vec<&str> = file.scans.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["L008-S1", "L016-S1"]);
    assert_eq!(file.scans[0].points, Some(150));
    let got = placed(&file, 0);
    let want: Vec<&Point3<f64>> = truth[..3].iter().flatten().collect();
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).norm() < 1e-6, "{g} vs {w}");
    }
    // The station's pose is its first cloud's.
    let first = file.scans[0].pose.unwrap().0;
    let pose = flange(11.0) * mount();
    assert!((first.translation.vector - pose.translation.vector).norm() < 1e-9);
}

#[test]
fn a_cloud_the_tree_cannot_place_fails_alone_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let (_, early) = cloud(0, 9.5, false, false); // before the first /tf
    let (_, good) = cloud(1, 12.0, false, false);
    let (_, mut lost) = cloud(2, 13.0, false, false);
    lost.frame = "camera".into();
    let [bag, db3] = write_both(dir.path(), &[early, good, lost]);
    for bag in [bag, db3] {
        let opened = Ros2Bag::open(&bag, &Ros2Options::default()).unwrap();
        let e = opened.pose_error(0).unwrap();
        assert!(e.contains("500.0 ms outside"), "{e}");
        assert!(opened.pose_error(1).is_none());
        let e = opened.pose_error(2).unwrap();
        assert!(
            e.contains("frame \"camera\" is not in the bag's transform tree"),
            "{e}"
        );
        let file = ScanFile::of_ros2(&bag, std::sync::Arc::new(opened));
        assert!(file.scans[0].pose.is_none());
        let e = file.read_all(0).unwrap_err().to_string();
        assert!(
            e.contains("ms outside") && e.contains(&bag.display().to_string()),
            "{e}"
        );
        assert_eq!(file.read_all(1).unwrap().0.len(), 50);
    }
}

#[test]
fn a_bag_without_clouds_or_with_many_topics_or_damaged_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let (_, c) = cloud(0, 12.0, false, false);
    let bag = dir.path().join("bag.mcap");
    write_mcap(&bag, "/points", std::slice::from_ref(&c), &transforms()).unwrap();
    let asked = Ros2Options {
        cloud_topic: Some("/lidar".into()),
        ..Default::default()
    };
    let e = Ros2Bag::open(&bag, &asked).unwrap_err().to_string();
    assert!(
        e.contains("no PointCloud2 messages on /lidar") && e.contains("/points"),
        "{e}"
    );
    let none = dir.path().join("none.mcap");
    write_mcap(&none, "/points", &[], &transforms()).unwrap();
    let e = Ros2Bag::open(&none, &Ros2Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("holds no sensor_msgs/msg/PointCloud2"), "{e}");
    let bytes = std::fs::read(&bag).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    // A bag cut short (its recorder killed) reads up to where it stops, or says it is damaged.
    match Ros2Bag::open(&cut, &Ros2Options::default()) {
        Ok(b) => assert!(b.describe().contains("cloud(s)")),
        Err(e) => assert!(
            e.to_string().contains("damaged") || e.to_string().contains("cloud"),
            "{e}"
        ),
    }
    let e = Ros2Bag::open(&dir.path().join("x.bag"), &Ros2Options::default()).unwrap_err();
    assert!(e.to_string().contains(".mcap or .db3"), "{e}");
}
