//! C2M on shapes made in code, against analytic ground truth and brute force. The same checks
//! on a real scanned design (the bunny, read through asbuilt-io), and against parry, are the
//! cross-crate tests' (`tests/tests/c2m_real_data.rs`).

#[path = "support/c2m_checks.rs"]
mod c2m_checks;

use asbuilt_core::c2m::triangle::Region;
use asbuilt_core::design::shapes::{cuboid, icosphere, sheet, study_wall};
use asbuilt_core::{C2mIndex, C2mParams, Cursor, Design};
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use c2m_checks::*;

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
fn non_finite_points_have_no_match() {
    let idx = index(&cuboid(Point3::origin(), Point3::new(1.0, 1.0, 1.0)), 1.0);
    assert_eq!(q(&idx, [f64::NAN, 0.0, 0.0]), None);
    assert_eq!(q(&idx, [f64::INFINITY, 0.0, 0.0]), None);
    assert_eq!(idx.brute_force(&Point3::new(0.0, f64::NAN, 0.0)), None);
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

#[test]
fn faces_on_cell_boundaries_keep_their_cells() {
    // The study wall's lowest faces lie exactly on cell boundaries (the grid starts two cells
    // below the design), half a cell from the centres on either side. Cells of a tenth of the
    // wall's height, given and picked, so that every point near a face is answered from the
    // face's own cells.
    let wall = study_wall();
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let points: Vec<Point3<f64>> = probe_points(&wall, 6000, 0.01, 12)
        .into_iter()
        .chain((0..2000).map(|_| {
            Point3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.0867..0.0867),
                rng.random_range(-0.01..0.01),
            )
        }))
        .collect();
    // Beyond the band a point outside every kept cell has no match, so a missing cell loses
    // matches.
    for cell_size in [
        Some(0.05),
        Some(0.07),
        Some(0.1),
        Some(0.04918011380375202),
        None,
    ] {
        let params = C2mParams {
            max_distance: 0.02,
            cell_size,
        };
        let idx = C2mIndex::build(&wall, params).unwrap();
        assert_queries_equal_brute_force(&idx, points.iter());
    }
}
