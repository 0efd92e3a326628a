//! Checks of the C2M index shared by core's own tests (`tests/c2m.rs`, on shapes made in
//! code) and the cross-crate tests on real designs (`tests/tests/c2m_real_data.rs`, loaded
//! through asbuilt-io): probe points of every kind, and the index against brute force, whole or
//! cut at a printed height.

// Each test file that includes this uses some of the checks.
#![allow(dead_code)]

use asbuilt_core::{C2mIndex, C2mParams, Closest, Cursor, Design};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub fn index(design: &Design, max_distance: f64) -> C2mIndex {
    C2mIndex::build(design, C2mParams::within(max_distance)).unwrap()
}

pub fn q(index: &C2mIndex, p: [f64; 3]) -> Option<Closest> {
    index.query(&Point3::from(p), &mut Cursor::default())
}

/// A uniform offset of up to `s` per axis.
pub fn jitter(rng: &mut ChaCha8Rng, s: f64) -> Vector3<f64> {
    Vector3::new(
        rng.random_range(-s..s),
        rng.random_range(-s..s),
        rng.random_range(-s..s),
    )
}

/// Random points of four kinds: near the surface, next to vertices, next to edges, and far.
pub fn probe_points(design: &Design, n: usize, scale: f64, seed: u64) -> Vec<Point3<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (lo, hi) = design.bounds();
    (0..n)
        .map(|i| {
            let t = design.triangles[rng.random_range(0..design.triangles.len())];
            let [a, b, c] = t.map(|k| design.vertices[k as usize]);
            match i % 4 {
                0 => {
                    let (u, v): (f64, f64) = (rng.random(), rng.random());
                    let (u, v) = if u + v > 1.0 {
                        (1.0 - u, 1.0 - v)
                    } else {
                        (u, v)
                    };
                    a + (b - a) * u + (c - a) * v + jitter(&mut rng, scale)
                }
                1 => a + jitter(&mut rng, scale * 0.1),
                2 => a + (b - a) * rng.random::<f64>() + jitter(&mut rng, scale * 0.1),
                _ => {
                    let m = (hi - lo) * 0.3;
                    Point3::new(
                        rng.random_range(lo.x - m.x..hi.x + m.x),
                        rng.random_range(lo.y - m.y..hi.y + m.y),
                        rng.random_range(lo.z - m.z..hi.z + m.z),
                    )
                }
            }
        })
        .collect()
}

/// Each point's query, from a fresh cursor, answers as brute force does.
pub fn assert_queries_equal_brute_force<'a>(
    idx: &C2mIndex,
    points: impl Iterator<Item = &'a Point3<f64>>,
) {
    for p in points {
        assert_eq!(
            idx.query(p, &mut Cursor::default()),
            idx.brute_force(p),
            "{p:?}"
        );
    }
}

pub fn assert_equals_brute_force(design: &Design, max_distance: f64, points: &[Point3<f64>]) {
    let idx = index(design, max_distance);
    let mut fast = vec![None; points.len()];
    idx.query_batch(points, &mut fast);
    let mut matched = 0;
    for (p, f) in points.iter().zip(&fast) {
        let b = idx.brute_force(p);
        match (f, &b) {
            (Some(f), Some(b)) => {
                matched += 1;
                // Same triangle, same bits: the fast path is exact, ties included.
                assert_eq!(f, b, "at {p:?}");
            }
            (None, None) => {}
            _ => panic!("at {p:?}: fast {f:?}, brute force {b:?}"),
        }
    }
    assert!(matched > points.len() / 2, "only {matched} matched");
    // A different chunking (single cursor, sequential) gives the same answers.
    let mut cursor = Cursor::default();
    for (p, f) in points.iter().zip(&fast).step_by(13) {
        assert_eq!(&idx.query(p, &mut cursor), f);
    }
}

/// Points for a cut at `h`: near the surface below the cut, on and around the cap's rim, on the
/// cap, above it within and beyond reach, and far.
pub fn cut_probe_points(
    design: &Design,
    h: f64,
    n: usize,
    scale: f64,
    seed: u64,
) -> Vec<Point3<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut pts = probe_points(design, n / 2, scale, seed);
    let (lo, hi) = design.bounds();
    while pts.len() < n {
        // A point of an edge that crosses the cut, where the rim is.
        let t = design.triangles[rng.random_range(0..design.triangles.len())];
        let [a, b, _] = t.map(|k| design.vertices[k as usize]);
        if (a.z - h) * (b.z - h) < 0.0 {
            let s = (h - a.z) / (b.z - a.z);
            let rim = a + (b - a) * s;
            pts.push(rim + jitter(&mut rng, scale * 0.2));
            pts.push(rim + jitter(&mut rng, 1e-6));
        } else if rng.random_bool(0.05) {
            pts.push(Point3::new(
                rng.random_range(lo.x..hi.x),
                rng.random_range(lo.y..hi.y),
                h + rng.random_range(-scale..scale),
            ));
        }
    }
    pts
}

pub fn assert_cut_equals_brute_force(
    design: &Design,
    max_distance: f64,
    heights: &[f64],
    n: usize,
) {
    let idx = index(design, max_distance);
    for (k, &h) in heights.iter().enumerate() {
        let (cut, _) = asbuilt_core::layers::cut_at(design, h).unwrap();
        let reference = index(&cut, max_distance);
        let section = idx.section(h).unwrap();
        let points = cut_probe_points(design, h, n, max_distance, 100 + k as u64);
        let mut cursor = Cursor::default();
        let (mut matched, mut on_cap) = (0, 0);
        for p in &points {
            let fast = idx.query_cut(p, &mut cursor, &section);
            let slow = reference.brute_force(p);
            match (fast, slow) {
                (Some(f), Some(s)) => {
                    matched += 1;
                    on_cap += usize::from(f.triangle as usize >= idx.triangles());
                    assert!(
                        (f.distance.abs() - s.distance.abs()).abs() <= 1e-9,
                        "height {h} at {p:?}: {f:?} vs {s:?}"
                    );
                    if s.distance.abs() > 1e-9 {
                        assert_eq!(
                            f.distance < 0.0,
                            s.distance < 0.0,
                            "sign at height {h}, {p:?}: {f:?} vs {s:?}"
                        );
                    }
                }
                (None, None) => {}
                (f, s) => {
                    let d = f.or(s).unwrap().distance.abs();
                    assert!(
                        (d - max_distance).abs() <= 1e-9,
                        "height {h} at {p:?}: fast {f:?}, brute force {s:?}"
                    );
                }
            }
        }
        assert!(matched > n / 4, "only {matched} of {n} matched at {h}");
        if section.report().cap_triangles > 0 {
            assert!(on_cap > 0, "no point found the cap at {h}");
        }
    }
}
