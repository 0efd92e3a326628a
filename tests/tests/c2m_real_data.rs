//! C2M on a real scanned design (the Stanford bunny at res2, loaded through asbuilt-io): the
//! index equals brute force, whole, just beyond its band and cut at a printed height, and its
//! signs agree with an independent implementation (parry's pseudo-normal inside test) as judged
//! by the generalised winding number. core's own C2M tests on shapes made in code are
//! `core/tests/c2m.rs`; the checks are shared with them.

#[path = "../../core/tests/support/c2m_checks.rs"]
mod c2m_checks;

use asbuilt_core::{C2mIndex, C2mParams, Design, Units};
use asbuilt_tests::shared_data;
use c2m_checks::*;
use nalgebra::Point3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The bunny's res2 mesh: open boundaries and non-manifold edges, as scanned meshes have.
fn bunny() -> Design {
    let path = shared_data().join("stanford-bunny/bun_zipper_res2.ply");
    asbuilt_io::read_design(&path, Units::Metres).unwrap()
}

#[test]
fn equals_brute_force_on_the_bunny() {
    let bunny = bunny();
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
    let bunny = bunny();
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

#[test]
fn signs_agree_with_parry_on_the_bunny() {
    use parry3d_f64::math::Vector as PV;
    use parry3d_f64::query::PointQuery;
    use parry3d_f64::shape::{TriMesh, TriMeshFlags};

    let bunny = bunny();
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
fn a_cut_of_the_bunny_equals_brute_force_over_the_cut_mesh() {
    let bunny = bunny();
    let (lo, hi) = bunny.bounds();
    let heights = [lo.z + 0.3 * (hi.z - lo.z), lo.z + 0.71 * (hi.z - lo.z)];
    assert_cut_equals_brute_force(&bunny, 0.005, &heights, 20_000);
}
