use std::path::{Path, PathBuf};

use asbuilt_protocol::ScanPoint;
use nalgebra::{Isometry3, Vector3};

use super::write::{self, OutScan};
use super::*;

fn e57(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/e57")
        .join(name)
}

/// Every scan of a file: (declared, read, invalid).
fn counts(path: &Path) -> Result<Vec<(Option<u64>, usize, u64)>, IoError> {
    let f = ScanFile::open(path)?;
    f.scans
        .iter()
        .map(|s| {
            let (pts, notes) = f.read_all(s.index)?;
            Ok((s.points, pts.len(), notes.invalid))
        })
        .collect()
}

fn err(path: &Path) -> String {
    match counts(path) {
        Ok(c) => panic!("{} loaded: {c:?}", path.display()),
        Err(e) => format!("{e:#}"),
    }
}

#[test]
fn every_shared_e57_file_loads_with_its_count_and_pose_or_fails_clearly() {
    let bunny = Some(30_571);
    for name in [
        "bunnyDouble.e57",
        "bunnyFloat.e57",
        "bunnyInt19.e57",
        "bunnyInt32.e57",
    ] {
        assert_eq!(
            counts(&e57(name)).unwrap(),
            vec![(bunny, 30_571, 0)],
            "{name}"
        );
    }
    // One scan each, (declared points, points read, points flagged invalid): spherical ones
    // with every other point a direction only, flagged invalid and kept; invalid states; empty
    // but valid.
    for (name, want) in [
        ("pumpAVisualReferenceImage.e57", (Some(155_201), 155_201, 0)),
        ("tinyCartesianFloatRgb.e57", (Some(2090), 2090, 0)),
        ("tiny_spherical.e57", (Some(360), 360, 180)),
        ("cartesian_invalid_state_single.e57", (Some(3), 3, 2)),
        ("ZeroPoints.e57", (Some(0), 0, 0)),
        ("empty_pc.e57", (Some(0), 0, 0)),
    ] {
        assert_eq!(counts(&e57(name)).unwrap(), vec![want], "{name}");
    }
    // Two scans each, no pose: the file's frame.
    for name in ["A_B.e57", "A_moved_B.e57"] {
        let f = ScanFile::open(&e57(name)).unwrap();
        assert_eq!(f.scans.len(), 2);
        assert!(
            f.scans
                .iter()
                .all(|s| s.pose == Some((Isometry3::identity(), PoseSource::FileFrame)))
        );
        assert_eq!(
            counts(&e57(name)).unwrap(),
            vec![(Some(2), 2, 0), (Some(4), 4, 0)]
        );
    }
    // A pose with a translation and no rotation.
    let f = ScanFile::open(&e57("translationWithoutRotation.e57")).unwrap();
    let (pose, source) = f.scans[0].pose.unwrap();
    assert_eq!(source, PoseSource::E57);
    assert_eq!(pose.translation.vector, Vector3::new(4.0, 5.0, 6.0));
    assert_eq!(pose.rotation.angle(), 0.0);
    // Spherical: the first point lies on the x axis, one metre out.
    let (pts, _) = ScanFile::open(&e57("tiny_spherical.e57"))
        .unwrap()
        .read_all(0)
        .unwrap();
    let first = pts[0].xyz;
    assert!((first[0] - 1.0).abs() < 1e-6 && first[1].abs() < 1e-6 && first[2].abs() < 1e-6);
    assert!(err(&e57("empty.e57")).contains("no point cloud in it"));
    // Damaged.
    let e = err(&e57("corrupt_crc.e57"));
    assert!(e.contains("checksum") && e.contains("damaged"), "{e}");
    let e = err(&e57("read_error.e57"));
    assert!(
        e.contains("none of its 2651 points is a measurement"),
        "{e}"
    );
    // Not an E57 file at all.
    let dir = tempfile::tempdir().unwrap();
    let fake = written(&dir, "fake.e57", "not an e57 file");
    assert!(err(&fake).contains("as E57"));
}

/// `contents` written to the file `name` in `dir`; its path.
fn written(dir: &tempfile::TempDir, name: &str, contents: impl AsRef<[u8]>) -> PathBuf {
    let path = dir.path().join(name);
    std::fs::write(&path, contents).unwrap();
    path
}

fn sample_scan(n: usize, seed: u32) -> Vec<ScanPoint> {
    (0..n)
        .map(|i| {
            let t =
                (i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) as f32 / u32::MAX as f32;
            let mut p = ScanPoint::new(
                3.0 * t - 1.0,
                (i as f32 * 0.37).sin() * 2.0,
                0.5 + (i % 7) as f32 * 0.01,
            );
            p.intensity = (i % 101) as f32 / 100.0;
            if i % 50 == 0 {
                p = ScanPoint::new(0.0, 0.0, 0.0);
                p.flags =
                    asbuilt_protocol::ScanPointFlags(asbuilt_protocol::ScanPointFlags::INVALID);
            }
            p
        })
        .collect()
}

fn write_file(path: &Path, scans: &[(OutScan, Vec<ScanPoint>)]) {
    let total = scans.iter().map(|s| s.1.len() as u64).sum();
    let mut w = write::create(path, total).unwrap();
    for (scan, pts) in scans {
        w.write_scan(scan, &mut |emit| {
            for c in pts.chunks(1000) {
                emit(c)?;
            }
            Ok(())
        })
        .unwrap();
    }
    w.finish().unwrap();
}

fn two_scans() -> Vec<(OutScan, Vec<ScanPoint>)> {
    let pose_a = Isometry3::new(Vector3::new(10.0, -4.0, 1.5), Vector3::new(0.1, 0.2, 1.3));
    let pose_b = Isometry3::new(Vector3::new(-2.0, 7.0, 0.5), Vector3::new(0.0, 0.0, -2.0));
    vec![
        (
            OutScan {
                name: "north".into(),
                pose: pose_a,
                points: 3000,
            },
            sample_scan(3000, 1),
        ),
        (
            OutScan {
                name: "south".into(),
                pose: pose_b,
                points: 1234,
            },
            sample_scan(1234, 2),
        ),
    ]
}

/// PTX and E57 keep every scan in its frame, with its pose and its invalid points.
#[test]
fn ptx_and_e57_round_trip_scans_poses_and_invalid_points() {
    let dir = tempfile::tempdir().unwrap();
    let scans = two_scans();
    for name in ["job.ptx", "job.e57"] {
        let path = dir.path().join(name);
        write_file(&path, &scans);
        let f = ScanFile::open(&path).unwrap();
        assert_eq!(f.scans.len(), 2, "{name}");
        for (info, (scan, pts)) in f.scans.iter().zip(&scans) {
            let (pose, _) = info.pose.unwrap();
            assert!(
                (pose.translation.vector - scan.pose.translation.vector).norm() < 1e-9,
                "{name}"
            );
            assert!(pose.rotation.angle_to(&scan.pose.rotation) < 1e-9, "{name}");
            let (back, notes) = f.read_all(info.index).unwrap();
            assert_eq!(back.len(), pts.len(), "{name}");
            assert_eq!(
                notes.invalid,
                pts.iter().filter(|p| p.flags.is_invalid()).count() as u64
            );
            for (a, b) in back.iter().zip(pts) {
                assert_eq!(a.flags.is_invalid(), b.flags.is_invalid());
                if !b.flags.is_invalid() {
                    assert_eq!(a.xyz, b.xyz, "{name}");
                    assert!((a.intensity - b.intensity).abs() < 1e-6, "{name}");
                }
            }
        }
    }
}

/// LAS, PLY and ASCII hold points in the file's frame: read back (with the LAS origin as pose)
/// they are the scans' points placed by their poses.
#[test]
fn las_ply_and_ascii_round_trip_placed_points() {
    let dir = tempfile::tempdir().unwrap();
    let scans = two_scans();
    let placed: Vec<nalgebra::Point3<f64>> = scans
        .iter()
        .flat_map(|(s, pts)| {
            pts.iter()
                .filter(|p| !p.flags.is_invalid())
                .map(|p| {
                    s.pose
                        * nalgebra::Point3::new(p.xyz[0] as f64, p.xyz[1] as f64, p.xyz[2] as f64)
                })
                .collect::<Vec<_>>()
        })
        .collect();
    for (name, tol) in [
        ("job.las", 1e-4),
        ("job.laz", 1e-4),
        ("job.ply", 1e-6),
        ("job.xyz", 1e-5),
    ] {
        let path = dir.path().join(name);
        write_file(&path, &scans);
        let f = ScanFile::open(&path).unwrap();
        assert_eq!(f.scans.len(), 1);
        let pose = f.scans[0]
            .pose
            .map(|p| p.0)
            .unwrap_or(Isometry3::identity());
        let (back, notes) = f.read_all(0).unwrap();
        // PLY keeps invalid points as NaN so its count holds; the others drop them.
        let back: Vec<_> = back
            .iter()
            .filter(|p| p.xyz.iter().all(|v| v.is_finite()))
            .map(|p| {
                pose * nalgebra::Point3::new(p.xyz[0] as f64, p.xyz[1] as f64, p.xyz[2] as f64)
            })
            .collect();
        assert_eq!(back.len(), placed.len(), "{name}");
        // The ASCII header is a `//` comment line, as CloudCompare writes it.
        assert_eq!(notes.malformed_lines, 0, "{name}");
        for (a, b) in back.iter().zip(&placed) {
            // f32 in the reader, at up to 12 m from the origin: 1 µm.
            assert!((a - b).norm() < f64::max(tol, 2e-6), "{name}: {a} vs {b}");
        }
    }
}

#[test]
fn ptx_headers_and_lines_that_cannot_be_read_are_reported_with_their_line() {
    let dir = tempfile::tempdir().unwrap();
    let header = "2\n1\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n5 6 7 1\n";
    let path = written(&dir, "bad.ptx", format!("{header}1 2 3 0.5\nnot a point\n"));
    let f = ScanFile::open(&path).unwrap();
    assert_eq!(
        f.scans[0].pose.unwrap().0.translation.vector,
        Vector3::new(5.0, 6.0, 7.0)
    );
    let (pts, notes) = f.read_all(0).unwrap();
    assert_eq!(pts.len(), 1);
    assert_eq!(
        (notes.malformed_lines, notes.first_malformed_line),
        (1, Some(12))
    );

    std::fs::write(&path, format!("{header}1 2 3 0.5\n")).unwrap();
    let e = format!("{:#}", ScanFile::open(&path).err().unwrap());
    assert!(
        e.contains("promises 2 points") && e.contains("ends after 1"),
        "{e}"
    );

    let skewed = header.replace("1 0 0 0\n0 1 0 0", "2 0 0 0\n0 1 0 0");
    std::fs::write(&path, format!("{skewed}1 2 3 0.5\n4 5 6 0.5\n")).unwrap();
    let e = format!("{:#}", ScanFile::open(&path).err().unwrap());
    assert!(e.contains("not a rotation"), "{e}");
}

#[test]
fn ply_skips_elements_before_the_vertices_and_reads_every_encoding() {
    let dir = tempfile::tempdir().unwrap();
    let path = written(
        &dir,
        "a.ply",
        "ply\nformat ascii 1.0\nelement camera 1\nproperty float f\nelement vertex 3\n\
         property float x\nproperty float y\nproperty float z\nproperty float intensity\n\
         element face 0\nproperty list uchar int vertex_indices\nend_header\n\
         9\n1 2 3 0.5\n4 5 6 0.25\nbad line\n",
    );
    let (pts, notes) = ScanFile::open(&path).unwrap().read_all(0).unwrap();
    assert_eq!(pts.len(), 2);
    assert_eq!(pts[1].xyz, [4.0, 5.0, 6.0]);
    assert_eq!(pts[1].intensity, 0.25);
    assert_eq!(notes.malformed_lines, 1);
    // Big-endian binary with a double and a list before xyz.
    let mut bytes = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty double t\n\
        property list uchar int idx\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
        .to_vec();
    for i in 0..2 {
        bytes.extend(1.5f64.to_be_bytes());
        bytes.push(2);
        bytes.extend(7i32.to_be_bytes());
        bytes.extend(8i32.to_be_bytes());
        for v in [i as f32, 2.0, 3.0] {
            bytes.extend(v.to_be_bytes());
        }
    }
    std::fs::write(&path, &bytes).unwrap();
    let (pts, _) = ScanFile::open(&path).unwrap().read_all(0).unwrap();
    assert_eq!(
        pts.iter().map(|p| p.xyz).collect::<Vec<_>>(),
        vec![[0.0, 2.0, 3.0], [1.0, 2.0, 3.0]]
    );
    // Truncated.
    std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
    let e = format!(
        "{:#}",
        ScanFile::open(&path).unwrap().read_all(0).err().unwrap()
    );
    assert!(e.contains("ends after 1 of 2 vertices"), "{e}");
}

/// Binary records of one size are read a block at a time: across blocks, in both byte orders,
/// with properties around x, y, z, and cut short mid-record.
#[test]
fn ply_binary_records_of_one_size_read_across_blocks_and_stop_where_cut() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fixed.ply");
    let n = 10_007u32;
    for (format, big) in [("binary_little_endian", false), ("binary_big_endian", true)] {
        let mut bytes = format!(
            "ply\nformat {format} 1.0\nelement vertex {n}\nproperty double t\n\
             property float x\nproperty uchar intensity\nproperty float y\nproperty float z\n\
             end_header\n"
        )
        .into_bytes();
        for i in 0..n {
            let f = |v: f32| {
                if big {
                    v.to_be_bytes()
                } else {
                    v.to_le_bytes()
                }
            };
            let t = 0.5f64;
            bytes.extend(if big {
                t.to_be_bytes()
            } else {
                t.to_le_bytes()
            });
            bytes.extend(f(i as f32 * 0.25));
            bytes.push((i % 256) as u8);
            bytes.extend(f(-(i as f32)));
            bytes.extend(f(3.0));
        }
        std::fs::write(&path, &bytes).unwrap();
        let (pts, _) = ScanFile::open(&path).unwrap().read_all(0).unwrap();
        assert_eq!(pts.len(), n as usize, "{format}");
        for (i, p) in pts.iter().enumerate() {
            assert_eq!(p.xyz, [i as f32 * 0.25, -(i as f32), 3.0], "{format} {i}");
            assert_eq!(p.intensity, (i % 256) as f32, "{format} {i}");
        }
        std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
        let e = format!(
            "{:#}",
            ScanFile::open(&path).unwrap().read_all(0).err().unwrap()
        );
        assert!(
            e.contains(&format!("ends after {} of {n} vertices", n - 1)),
            "{e}"
        );
    }
}

#[test]
fn the_stanford_scans_stream_in_chunks_as_they_read_whole() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/stanford-bunny/scans/bun000.ply");
    let f = ScanFile::open(&path).unwrap();
    assert_eq!(f.scans[0].points, Some(40_256));
    let mut chunks = Vec::new();
    f.stream(0, 10_000, &mut |c| {
        chunks.push(c.len());
        Ok(())
    })
    .unwrap();
    assert_eq!(chunks, vec![10_000, 10_000, 10_000, 10_000, 256]);
}

#[test]
fn xyz_keeps_good_points_around_bad_lines_and_nan() {
    let text = "3\n# comment\n1 2 3\n4,5,6,0.5\nnan 0 0\nbroken line\n7 8 9\n";
    let mut pts = Vec::new();
    let notes = xyz::parse(text.as_bytes(), Path::new("t.xyz"), 2, &mut |c| {
        pts.extend_from_slice(c);
        Ok(())
    })
    .unwrap();
    assert_eq!(pts.len(), 4);
    assert!(pts[2].xyz[0].is_nan());
    assert_eq!(pts[1].intensity, 0.5);
    assert_eq!(notes.malformed_lines, 1);
    assert_eq!(notes.first_malformed_line, Some(6));
    assert!(xyz::parse("a b c\n".as_bytes(), Path::new("t.xyz"), 2, &mut |_| Ok(())).is_err());
}

/// Reading ahead on a thread hands the sink the same chunks in the same order as reading in
/// turn, and a sink's error stops the reader and comes back naming the file.
#[test]
fn reading_ahead_gives_the_same_chunks_and_stops_at_the_sinks_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ahead.ply");
    let points = sample_scan(10_007, 3);
    write_file(
        &path,
        &[(
            OutScan {
                name: "ahead".into(),
                pose: Isometry3::identity(),
                points: points.len() as u64,
            },
            points,
        )],
    );
    let f = ScanFile::open(&path).unwrap();
    let collect = |ahead: Option<usize>| {
        let mut chunks: Vec<Vec<[u32; 3]>> = Vec::new();
        let mut sink = |c: &[ScanPoint]| {
            chunks.push(c.iter().map(|p| p.xyz.map(f32::to_bits)).collect());
            Ok(())
        };
        let notes = match ahead {
            None => f.stream(0, 1000, &mut sink),
            Some(a) => f.stream_ahead(0, 1000, a, &mut sink),
        }
        .unwrap();
        (chunks, notes.invalid)
    };
    let in_turn = collect(None);
    assert_eq!(in_turn.0.len(), 11);
    assert_eq!(collect(Some(1)), in_turn);
    assert_eq!(collect(Some(3)), in_turn);

    let mut seen = 0;
    let e = f
        .stream_ahead(0, 1000, 2, &mut |_| {
            seen += 1;
            if seen == 3 {
                return Err("the disk is full".into());
            }
            Ok(())
        })
        .unwrap_err();
    assert_eq!(seen, 3, "no chunk after the failing one");
    let msg = format!("{e:#}");
    assert!(
        msg.contains("the disk is full") && msg.contains("ahead.ply"),
        "{msg}"
    );
}
