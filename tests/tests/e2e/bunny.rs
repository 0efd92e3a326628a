//! The Stanford bunny stations through protocol and core together.

use std::path::{Path, PathBuf};

use asbuilt_core::station::{InspectParams, StationInspector};
use asbuilt_core::{C2mIndex, C2mParams, Design, Units};
use asbuilt_protocol::{DeviationFlags, PointDeviation, ScanPoint, StationReport, codec};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};

fn bunny_dir() -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/stanford-bunny");
    assert!(p.is_dir(), "test data not found at {}", p.display());
    p
}

/// `bmesh FILE tx ty tz qx qy qz qw` with `p_mesh = R(q)ᵀ p_scan + t` (the data's README).
fn stations() -> Vec<(String, Isometry3<f64>)> {
    let text = std::fs::read_to_string(bunny_dir().join("scans/bun.conf")).unwrap();
    text.lines()
        .filter(|l| l.starts_with("bmesh"))
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            let n: Vec<f64> = f[2..].iter().map(|s| s.parse().unwrap()).collect();
            let q = UnitQuaternion::from_quaternion(Quaternion::new(n[6], n[3], n[4], n[5]));
            let t = Isometry3::from_parts(
                Translation3::from(Vector3::new(n[0], n[1], n[2])),
                q.conjugate(),
            );
            (f[1].to_string(), t)
        })
        .collect()
}

fn read_scan(name: &str) -> Vec<ScanPoint> {
    let mut f =
        std::io::BufReader::new(std::fs::File::open(bunny_dir().join("scans").join(name)).unwrap());
    let ply = Parser::<DefaultElement>::new().read_ply(&mut f).unwrap();
    ply.payload["vertex"]
        .iter()
        .map(|v| {
            let c = |k: &str| match v[k] {
                Property::Float(x) => x,
                _ => panic!("float coordinates expected"),
            };
            ScanPoint::new(c("x"), c("y"), c("z"))
        })
        .collect()
}

fn bunny_mesh(file: &str) -> Design {
    asbuilt_io::read_design(&bunny_dir().join(file), Units::Metres).unwrap()
}

fn c2m_index(design: &Design, max_distance: f64) -> C2mIndex {
    C2mIndex::build(design, C2mParams::within(max_distance)).unwrap()
}

/// The index of a bunny mesh within 5 mm, the maximum distance of every test here.
fn bunny_index(file: &str) -> C2mIndex {
    c2m_index(&bunny_mesh(file), 0.005)
}

/// The first station of the scans, or the last: its name, its pose and its points.
fn end_station(last: bool) -> (String, Isometry3<f64>, Vec<ScanPoint>) {
    let mut all = stations();
    let (name, t) = if last {
        all.pop()
    } else {
        all.into_iter().next()
    }
    .unwrap();
    let points = read_scan(&name);
    (name, t, points)
}

fn inspect(
    index: &C2mIndex,
    t: Isometry3<f64>,
    points: &[ScanPoint],
    chunk: usize,
) -> (StationReport, Vec<PointDeviation>) {
    let mut st = StationInspector::new(index, t, InspectParams::with_tolerance(0.005));
    let mut all = vec![PointDeviation::default(); points.len()];
    for (ps, out) in points.chunks(chunk).zip(all.chunks_mut(chunk)) {
        st.process(ps, out);
    }
    (st.report(1, 9, "ear_back"), all)
}

/// The bunny's meshes (ASCII PLY, float coordinates) read as ply-rs reads them, bit for bit.
#[test]
fn the_bunny_meshes_read_as_ply_rs_reads_them() {
    for file in ["bun_zipper.ply", "bun_zipper_res2.ply"] {
        let mut f = std::io::BufReader::new(std::fs::File::open(bunny_dir().join(file)).unwrap());
        let ply = Parser::<DefaultElement>::new().read_ply(&mut f).unwrap();
        let vertices = ply.payload["vertex"]
            .iter()
            .map(|v| {
                let c = |k: &str| match v[k] {
                    Property::Float(x) => f64::from(x),
                    _ => panic!("float coordinates expected"),
                };
                nalgebra::Point3::new(c("x"), c("y"), c("z"))
            })
            .collect();
        let triangles = ply.payload["face"]
            .iter()
            .map(|f| match &f["vertex_indices"] {
                Property::ListInt(l) => [l[0], l[1], l[2]].map(|i| i as u32),
                other => panic!("{other:?}"),
            })
            .collect();
        let want = Design::from_indexed(vertices, triangles, 1.0).unwrap();
        let got = bunny_mesh(file);
        assert_eq!(got.vertices, want.vertices, "{file}");
        assert_eq!(got.triangles, want.triangles, "{file}");
    }
}

#[test]
fn every_no_match_point_is_truly_beyond_the_maximum_distance() {
    let design = bunny_mesh("bun_zipper.ply");
    let index = c2m_index(&design, 0.005);
    let far = c2m_index(&design, 1.0);
    let mut no_match = 0;
    for (name, t) in stations() {
        let points = read_scan(&name);
        let (report, devs) = inspect(&index, t, &points, 1 << 16);
        assert_eq!(report.points_received as usize, points.len());
        for d in devs
            .iter()
            .filter(|d| d.flags.contains(DeviationFlags::NO_MATCH))
        {
            no_match += 1;
            let truth = far.brute_force(&d.position.into()).unwrap();
            assert!(
                truth.distance.abs() > 0.005,
                "{name}: {d:?} is {} m away",
                truth.distance
            );
            assert!(d.distance.is_nan(), "no-match is flagged, never clamped");
        }
    }
    // One stray point in ear_back.ply, 79 mm from the surface.
    assert_eq!(no_match, 1);
}

#[test]
fn station_reports_do_not_depend_on_chunking() {
    let index = bunny_index("bun_zipper_res2.ply");
    let (_, t, points) = end_station(true);
    let (a, da) = inspect(&index, t, &points, 65_536);
    let (b, db) = inspect(&index, t, &points, 997);
    let (c, _) = inspect(&index, t, &points, 1);
    // Bit-identical encodings (NaN fields compare equal as bytes, not as floats).
    assert_eq!(codec::encode(&a), codec::encode(&b));
    assert_eq!(codec::encode(&a), codec::encode(&c));
    assert_eq!(da.len(), db.len());
    for (x, y) in da.iter().zip(&db) {
        assert_eq!(x.distance.to_bits(), y.distance.to_bits());
        assert_eq!(x.triangle, y.triangle);
    }
    let back: StationReport = codec::decode(&codec::encode(&a)).unwrap();
    assert_eq!(back.stats.count, a.stats.count);
    assert!(a.stats.count > 30_000);
}

/// A merged or shuffled cloud is queried along a Morton curve; every point still gets the bits
/// it gets in scan order, and the station's report is the same.
#[test]
fn a_shuffled_station_gives_the_bits_of_its_scan_order() {
    let index = bunny_index("bun_zipper.ply");
    let (name, t, points) = end_station(false);
    // A fixed permutation: multiplying by a number prime to the length visits every index.
    let n = points.len();
    let step = (1..)
        .map(|k| 7919 * k + 1)
        .find(|s| gcd(*s, n) == 1)
        .unwrap();
    let order: Vec<usize> = (0..n).map(|i| i * step % n).collect();
    let shuffled: Vec<ScanPoint> = order.iter().map(|&i| points[i]).collect();
    let (ra, a) = inspect(&index, t, &points, 1 << 16);
    let (rb, b) = inspect(&index, t, &shuffled, 1 << 16);
    assert_eq!(codec::encode(&ra), codec::encode(&rb), "{name}");
    for (k, &i) in order.iter().enumerate() {
        let (x, y) = (&a[i], &b[k]);
        assert_eq!(
            x.distance.to_bits(),
            y.distance.to_bits(),
            "{name} point {i}"
        );
        assert_eq!(
            (x.triangle, x.flags.0),
            (y.triangle, y.flags.0),
            "{name} point {i}"
        );
    }
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

#[test]
fn every_station_of_the_full_bunny_gives_the_same_bits_in_any_chunking() {
    let index = bunny_index("bun_zipper.ply");
    for (name, t) in stations() {
        let points = read_scan(&name);
        let (ra, a) = inspect(&index, t, &points, 1 << 16);
        for chunk in [10_000, 997] {
            let (rb, b) = inspect(&index, t, &points, chunk);
            for (i, (da, db)) in a.iter().zip(&b).enumerate() {
                if da.distance.to_bits() != db.distance.to_bits() || da.triangle != db.triangle {
                    let truth = index.brute_force(&da.position.into());
                    panic!(
                        "{name} point {i}, chunks of {chunk}: {da:?} vs {db:?}; brute force \
                         {truth:?}"
                    );
                }
            }
            assert_eq!(codec::encode(&ra), codec::encode(&rb), "{name}");
        }
    }
}
