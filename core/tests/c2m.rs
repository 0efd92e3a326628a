//! C2M against analytic ground truth, against brute force, and against an independent
//! implementation (parry's pseudo-normal inside test).

use asbuilt_core::c2m::triangle::Region;
use asbuilt_core::design::shapes::{cuboid, icosphere, sheet};
use asbuilt_core::{C2mIndex, C2mParams, Closest, Cursor, Design, Units};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn index(design: &Design, max_distance: f64) -> C2mIndex {
    C2mIndex::build(design, C2mParams::within(max_distance)).unwrap()
}

fn q(index: &C2mIndex, p: [f64; 3]) -> Option<Closest> {
    index.query(&Point3::from(p), &mut Cursor::default())
}

fn shared_data() -> std::path::PathBuf {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    assert!(
        p.is_dir(),
        "test data not found at {}: clone the repository next to `shared/`",
        p.display()
    );
    p
}

#[test]
fn unit_cube_faces_edges_corners_inside_and_outside() {
    let cube = cuboid(Point3::origin(), Point3::new(1.0, 1.0, 1.0));
    assert!(cube.report.topology.is_closed_and_oriented());
    let idx = index(&cube, 10.0);
    // (point, signed distance, region kind)
    let cases: &[([f64; 3], f64, &str)] = &[
        ([0.3, 0.6, 1.25], 0.25, "face"),
        ([0.5, 0.5, 0.9], -0.1, "face"),
        ([0.3, -0.5, 0.6], 0.5, "face"),
        ([0.5, 0.5, 0.5], -0.5, "face"),
        ([0.2, 0.5, 0.5], -0.2, "face"),
        // Beyond an edge: distance to the edge line.
        ([1.3, 0.5, 1.4], 0.5, "edge"),
        ([-0.6, -0.8, 0.5], 1.0, "edge"),
        // Beyond a corner.
        (
            [2.0, 3.0, 1.0 + 6.0],
            (1.0f64 + 4.0 + 36.0).sqrt(),
            "vertex",
        ),
        ([-1.0, -1.0, -1.0], 3f64.sqrt(), "vertex"),
        // Inside near a corner: closest is the nearest face, never the corner.
        ([0.9, 0.95, 0.97], -0.03, "face"),
    ];
    for &(p, d, kind) in cases {
        let c = q(&idx, p).unwrap();
        assert!(
            (c.distance - d).abs() < 1e-15,
            "{p:?}: {} vs {d}",
            c.distance
        );
        let got = match c.region {
            Region::Face => "face",
            Region::Edge(_) => "edge",
            Region::Vertex(_) => "vertex",
        };
        // Inside points equidistant to two faces land on their shared edge; the distance is
        // what matters there.
        if kind != "face" || d > 0.0 {
            assert_eq!(got, kind, "{p:?}");
        }
        assert_eq!(Some(c), idx.brute_force(&Point3::from(p)));
    }
    // Exactly on the surface.
    assert_eq!(q(&idx, [0.5, 0.25, 1.0]).unwrap().distance, 0.0);
}

#[test]
fn sign_is_right_just_outside_and_inside_every_edge_and_corner() {
    // Points displaced by ±ε along the bisector of each edge and corner: the classic failure of
    // face-normal signing.
    let cube = cuboid(Point3::new(-1.0, -1.0, -1.0), Point3::new(1.0, 1.0, 1.0));
    let idx = index(&cube, 1.0);
    let eps = 1e-4;
    for sx in [-1.0f64, 0.0, 1.0] {
        for sy in [-1.0f64, 0.0, 1.0] {
            for sz in [-1.0f64, 0.0, 1.0] {
                let k = sx.abs() + sy.abs() + sz.abs();
                if k < 2.0 {
                    continue; // faces are covered above
                }
                let dir = Vector3::new(sx, sy, sz).normalize();
                let on = Point3::new(sx, sy, sz);
                let out = q(&idx, (on + dir * eps).into()).unwrap();
                assert!(
                    (out.distance - eps).abs() < 1e-12,
                    "{on:?} out {}",
                    out.distance
                );
                let inside = q(&idx, (on - dir * eps).into()).unwrap();
                assert!(inside.distance < 0.0, "{on:?} in {}", inside.distance);
            }
        }
    }
}

#[test]
fn plane_distance_is_height() {
    let plane = sheet(1.0, 0.25, 8);
    assert!(plane.report.topology.boundary_edges > 0);
    let idx = index(&plane, 0.5);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for _ in 0..10_000 {
        let p = [
            rng.random_range(-0.99..0.99),
            rng.random_range(-0.99..0.99),
            rng.random_range(-0.24..0.74),
        ];
        let c = q(&idx, p).unwrap();
        assert!(
            (c.distance - (p[2] - 0.25)).abs() < 1e-15,
            "{p:?} {}",
            c.distance
        );
    }
    // Beyond the maximum distance: no match, not a clamped value.
    assert_eq!(q(&idx, [0.0, 0.0, 0.76]), None);
    assert_eq!(q(&idx, [0.0, 0.0, 100.0]), None);
    assert_eq!(idx.brute_force(&Point3::new(0.0, 0.0, 0.76)), None);
}

#[test]
fn sphere_vertices_and_faces() {
    let center = Point3::new(0.3, -0.2, 1.5);
    let sphere = icosphere(center, 1.0, 3);
    assert!(sphere.report.topology.is_closed_and_oriented());
    let idx = index(&sphere, 0.5);
    // Outside along a vertex direction, the vertex is closest and the distance is r - 1 exactly.
    for v in sphere.vertices.iter().step_by(7) {
        let dir = (v - center).normalize();
        for r in [1.0001, 1.01, 1.3] {
            let c = q(&idx, (center + dir * r).into()).unwrap();
            assert!((c.distance - (r - 1.0)).abs() < 1e-12, "{}", c.distance);
            assert!(matches!(c.region, Region::Vertex(_)));
        }
    }
    // Under a face centroid, along the face normal: the distance is the depth, negative.
    for t in sphere.triangles.iter().step_by(11) {
        let [a, b, c] = t.map(|i| sphere.vertices[i as usize]);
        let centroid = Point3::from((a.coords + b.coords + c.coords) / 3.0);
        let n = (b - a).cross(&(c - a)).normalize();
        for depth in [1e-3, 1e-2] {
            let hit = q(&idx, (centroid - n * depth).into()).unwrap();
            assert!((hit.distance + depth).abs() < 1e-12, "{}", hit.distance);
            assert_eq!(hit.region, Region::Face);
            let out = q(&idx, (centroid + n * depth).into()).unwrap();
            assert!((out.distance - depth).abs() < 1e-12);
        }
    }
    assert!(q(&idx, center.into()).is_none(), "centre is 0.95+ m deep");
}

/// A uniform offset of up to `s` per axis.
fn jitter(rng: &mut ChaCha8Rng, s: f64) -> Vector3<f64> {
    Vector3::new(
        rng.random_range(-s..s),
        rng.random_range(-s..s),
        rng.random_range(-s..s),
    )
}

/// Random points of four kinds: near the surface, next to vertices, next to edges, and far.
fn probe_points(design: &Design, n: usize, scale: f64, seed: u64) -> Vec<Point3<f64>> {
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
fn assert_queries_equal_brute_force<'a>(
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

fn assert_equals_brute_force(design: &Design, max_distance: f64, points: &[Point3<f64>]) {
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

#[test]
fn equals_brute_force_on_a_sphere_100k_points() {
    let sphere = icosphere(Point3::new(1.0, 2.0, 3.0), 0.5, 3);
    let points = probe_points(&sphere, 100_000, 0.05, 11);
    assert_equals_brute_force(&sphere, 0.2, &points);
}

#[test]
fn equals_brute_force_on_a_cube_100k_points_with_far_band() {
    // Max distance beyond the grid band: far points go through the BVH path.
    let cube = cuboid(Point3::new(-0.3, 0.0, 0.1), Point3::new(0.7, 2.0, 0.5));
    let points = probe_points(&cube, 100_000, 0.2, 12);
    assert_equals_brute_force(&cube, 0.4, &points);
}

#[test]
fn equals_brute_force_on_the_bunny() {
    let path = shared_data().join("stanford-bunny/bun_zipper_res2.ply");
    let bunny = asbuilt_io::read_design(&path, Units::Metres).unwrap();
    let points = probe_points(&bunny, 12_000, 0.004, 13);
    assert_equals_brute_force(&bunny, 0.005, &points);
    // With a cell size forced small, a band far narrower than the maximum distance.
    let idx = C2mIndex::build(
        &bunny,
        C2mParams {
            max_distance: 0.02,
            cell_size: Some(0.0007),
        },
    )
    .unwrap();
    assert_queries_equal_brute_force(&idx, points.iter().step_by(5));
}

/// Points just beyond the grid's band, where a list's best is taken as the closest only when
/// the point lies deep enough in its cell: every answer is brute force's, on a smooth sphere
/// and on the bunny's small features.
#[test]
fn just_beyond_the_band_equals_brute_force() {
    let path = shared_data().join("stanford-bunny/bun_zipper_res2.ply");
    let bunny = asbuilt_io::read_design(&path, Units::Metres).unwrap();
    let sphere = asbuilt_core::design::shapes::icosphere(Point3::new(0.3, -0.2, 1.0), 0.5, 5);
    for (design, seed) in [(bunny, 21), (sphere, 22)] {
        let idx = index(&design, 0.05);
        let s = idx.stats();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let points: Vec<Point3<f64>> = (0..10_000)
            .map(|_| {
                let t = design.triangles[rng.random_range(0..design.triangles.len())];
                let [a, b, c] = t.map(|k| design.vertices[k as usize]);
                let (u, v): (f64, f64) = (rng.random(), rng.random());
                let (u, v) = if u + v > 1.0 {
                    (1.0 - u, 1.0 - v)
                } else {
                    (u, v)
                };
                let n = (b - a).cross(&(c - a)).normalize();
                let off = s.band + rng.random::<f64>() * s.cell_size;
                let side = if rng.random::<bool>() { 1.0 } else { -1.0 };
                a + (b - a) * u + (c - a) * v + n * (side * off)
            })
            .collect();
        let mut fast = vec![None; points.len()];
        idx.query_batch(&points, &mut fast);
        for (p, f) in points.iter().zip(&fast) {
            assert_eq!(f, &idx.brute_force(p), "at {p:?}");
        }
    }
}

/// A batch in no spatial order is answered block by block along a Morton curve; every answer
/// is the one its point gets in scan order.
#[test]
fn a_shuffled_batch_answers_as_in_scan_order() {
    let d = asbuilt_core::design::shapes::twisted_column(0.15, 0.1, 1.2, 90.0, 64, 30);
    let idx = index(&d, 0.01);
    // Scan-like: ring after ring up the column, as a scanner turning about it would write
    // them; then shuffled with a fixed stride.
    let mut scan = probe_points(&d, 300_000, 0.002, 5);
    let ring = |p: &Point3<f64>| ((p.z / 0.005).floor() as i64, p.y.atan2(p.x));
    scan.sort_by(|a, b| {
        let (ra, rb) = (ring(a), ring(b));
        ra.0.cmp(&rb.0).then(ra.1.total_cmp(&rb.1))
    });
    let n = scan.len();
    let perm: Vec<usize> = (0..n).map(|k| k * 7919 % n).collect();
    let shuffled: Vec<Point3<f64>> = perm.iter().map(|&i| scan[i]).collect();
    let (mut a, mut b) = (vec![None; n], vec![None; n]);
    idx.query_batch(&scan, &mut a);
    idx.query_batch(&shuffled, &mut b);
    for (k, &i) in perm.iter().enumerate() {
        assert_eq!(b[k], a[i], "point {i}");
    }
    assert!(a.iter().filter(|c| c.is_some()).count() > n / 2);
}

#[test]
fn signs_agree_with_parry_on_the_bunny() {
    use parry3d_f64::math::Vector as PV;
    use parry3d_f64::query::PointQuery;
    use parry3d_f64::shape::{TriMesh, TriMeshFlags};

    let path = shared_data().join("stanford-bunny/bun_zipper_res2.ply");
    let bunny = asbuilt_io::read_design(&path, Units::Metres).unwrap();
    let mesh = TriMesh::with_flags(
        bunny
            .vertices
            .iter()
            .map(|v| PV::new(v.x, v.y, v.z))
            .collect(),
        bunny.triangles.clone(),
        TriMeshFlags::ORIENTED,
    )
    .unwrap();
    let idx = index(&bunny, 0.01);
    let points = probe_points(&bunny, 6_000, 0.003, 14);
    let (mut judged, mut ours_wrong, mut parry_wrong) = (0, 0, 0);
    for p in &points {
        let Some(c) = q(&idx, (*p).into()) else {
            continue;
        };
        let proj = mesh.project_local_point(PV::new(p.x, p.y, p.z), false);
        let d = (PV::new(p.x, p.y, p.z) - proj.point).length();
        assert!(
            (d - c.distance.abs()).abs() < 1e-9,
            "{p:?}: {d} vs {}",
            c.distance
        );
        // The generalised winding number is the referee: ~1 inside, ~0 outside, even near the
        // holes of this scanned mesh. Points it cannot decide are skipped.
        let w = winding(&bunny, p);
        if d < 1e-7 || (w - 0.5).abs() < 0.4 {
            continue;
        }
        judged += 1;
        let inside = w > 0.5;
        ours_wrong += usize::from((c.distance < 0.0) != inside);
        parry_wrong += usize::from(proj.is_inside != inside);
    }
    assert!(judged > 4_000, "{judged}");
    // res2 has open boundaries and non-manifold edges, where a pseudo-normal sign can be wrong.
    assert!(
        ours_wrong * 1000 <= judged,
        "{ours_wrong} of {judged} signs wrong"
    );
    assert!(
        ours_wrong <= parry_wrong,
        "ours {ours_wrong} vs parry {parry_wrong}"
    );
}

fn winding(design: &Design, p: &Point3<f64>) -> f64 {
    let mut w = 0.0;
    for t in &design.triangles {
        let [a, b, c] = t.map(|i| design.vertices[i as usize] - p);
        let (la, lb, lc) = (a.norm(), b.norm(), c.norm());
        let num = a.dot(&b.cross(&c));
        let den = la * lb * lc + a.dot(&b) * lc + b.dot(&c) * la + c.dot(&a) * lb;
        w += 2.0 * num.atan2(den);
    }
    w / (4.0 * std::f64::consts::PI)
}

#[test]
fn non_finite_points_have_no_match() {
    let idx = index(&cuboid(Point3::origin(), Point3::new(1.0, 1.0, 1.0)), 1.0);
    assert_eq!(q(&idx, [f64::NAN, 0.0, 0.0]), None);
    assert_eq!(q(&idx, [f64::INFINITY, 0.0, 0.0]), None);
    assert_eq!(idx.brute_force(&Point3::new(0.0, f64::NAN, 0.0)), None);
}

/// Points for a cut at `h`: near the surface below the cut, on and around the cap's rim, on the
/// cap, above it within and beyond reach, and far.
fn cut_probe_points(design: &Design, h: f64, n: usize, scale: f64, seed: u64) -> Vec<Point3<f64>> {
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

fn assert_cut_equals_brute_force(design: &Design, max_distance: f64, heights: &[f64], n: usize) {
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

#[test]
fn a_cut_from_the_one_index_equals_brute_force_over_the_cut_mesh() {
    use asbuilt_core::design::shapes::twisted_column;
    // Free-form: no face parallel to an axis; heights at random, a ring's height included.
    let column = twisted_column(0.15, 0.1, 1.2, 90.0, 96, 40);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut heights: Vec<f64> = (0..4).map(|_| rng.random_range(0.05..1.15)).collect();
    heights.push(0.6);
    assert_cut_equals_brute_force(&column, 0.03, &heights, 30_000);
    let cube = cuboid(Point3::new(-0.3, 0.0, 0.1), Point3::new(0.7, 2.0, 0.5));
    assert_cut_equals_brute_force(&cube, 0.2, &[0.3, 0.49], 20_000);
    let sphere = icosphere(Point3::new(1.0, 2.0, 3.0), 0.5, 3);
    assert_cut_equals_brute_force(&sphere, 0.1, &[2.7, 3.0, 3.41], 20_000);
}

#[test]
fn a_cut_of_the_bunny_equals_brute_force_over_the_cut_mesh() {
    let path = shared_data().join("stanford-bunny/bun_zipper_res2.ply");
    let bunny = asbuilt_io::read_design(&path, Units::Metres).unwrap();
    let (lo, hi) = bunny.bounds();
    let heights = [lo.z + 0.3 * (hi.z - lo.z), lo.z + 0.71 * (hi.z - lo.z)];
    assert_cut_equals_brute_force(&bunny, 0.005, &heights, 20_000);
}

#[test]
fn slivers_duplicates_and_specks_index_within_the_memory_bound() {
    // A box, 500 copies of one of its faces, slivers a thousand times longer than wide and
    // specks of 1e-9 m: the cell size follows the surface, not the smallest triangle.
    let cube = cuboid(Point3::origin(), Point3::new(1.0, 1.0, 1.0));
    let mut v = cube.vertices.clone();
    let mut t = cube.triangles.clone();
    for _ in 0..500 {
        t.push(cube.triangles[0]);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for _ in 0..2000 {
        let a = Point3::new(rng.random::<f64>(), rng.random::<f64>(), 1.0);
        let long = Vector3::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5, 0.0);
        let s = v.len() as u32;
        v.extend([
            a,
            a + long,
            a + long * 0.5 + Vector3::new(1e-3 * long.y, -1e-3 * long.x, 0.0),
        ]);
        t.push([s, s + 1, s + 2]);
        let s = v.len() as u32;
        v.extend([
            a,
            a + Vector3::new(1e-9, 0.0, 0.0),
            a + Vector3::new(0.0, 1e-9, 0.0),
        ]);
        t.push([s, s + 1, s + 2]);
    }
    let design = Design::from_indexed(v, t, 1.0).unwrap();
    let idx = index(&design, 0.05);
    let stats = idx.stats();
    assert!(
        stats.bytes < 150 * stats.triangles + (1 << 16),
        "{} bytes for {} triangles",
        stats.bytes,
        stats.triangles
    );
    let points = probe_points(&design, 20_000, 0.03, 21);
    assert_queries_equal_brute_force(&idx, points.iter().step_by(3));
}

#[test]
fn an_index_that_takes_the_design_over_answers_as_one_that_borrows_it() {
    let design = icosphere(Point3::new(0.1, -0.2, 0.3), 0.5, 4);
    let points = probe_points(&design, 20_000, 0.01, 11);
    let borrowed = index(&design, 0.02);
    let owned = C2mIndex::from_design(design.clone(), C2mParams::within(0.02)).unwrap();
    let (mut a, mut b) = (Cursor::default(), Cursor::default());
    for p in &points {
        let (x, y) = (borrowed.query(p, &mut a), owned.query(p, &mut b));
        assert_eq!(
            x.map(|c| (c.distance.to_bits(), c.triangle)),
            y.map(|c| (c.distance.to_bits(), c.triangle)),
            "{p:?}"
        );
    }
    assert_eq!(borrowed.stats().bytes, owned.stats().bytes);
}
