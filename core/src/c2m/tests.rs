//! The grid's paths against the BVH's on the same index: the same bits, not just close.

use std::borrow::Cow;

use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::mesh::NormalSource;
use super::{C2mIndex, C2mParams, Cursor, GridUse};
use crate::design::Design;
use crate::design::shapes::{cuboid, icosphere, study_wall, twisted_column};

fn indexed(design: &Design, max_distance: f64, grid: GridUse) -> C2mIndex {
    C2mIndex::build_mesh(
        design.vertices.clone(),
        Cow::Borrowed(&design.triangles),
        NormalSource::Own,
        C2mParams::within(max_distance),
        grid,
    )
    .unwrap()
}

/// Points on the surface pushed out or in by up to `reach`, points on the rim of the cut, and
/// points scattered over the design's box and a little beyond.
fn points(design: &Design, h: f64, reach: f64, n: usize, seed: u64) -> Vec<Point3<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (lo, hi) = design.bounds();
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let t = design.triangles[rng.random_range(0..design.triangles.len())];
        let [a, b, c] = t.map(|k| design.vertices[k as usize]);
        let jitter = Vector3::from_fn(|_, _| rng.random_range(-reach..reach));
        match rng.random_range(0..4) {
            0 | 1 => {
                let (u, v) = (rng.random::<f64>(), rng.random::<f64>());
                let (u, v) = if u + v > 1.0 {
                    (1.0 - u, 1.0 - v)
                } else {
                    (u, v)
                };
                out.push(a + (b - a) * u + (c - a) * v + jitter);
            }
            2 if (a.z - h) * (b.z - h) < 0.0 => {
                let s = (h - a.z) / (b.z - a.z);
                out.push(a + (b - a) * s + jitter * 0.1);
            }
            _ => out.push(Point3::from(Vector3::from_fn(|k, _| {
                rng.random_range(lo[k] - 2.0 * reach..hi[k] + 2.0 * reach)
            }))),
        }
    }
    out
}

#[test]
fn a_cut_answered_from_the_grid_gives_the_bits_of_the_bvh() {
    // Tall faces that every cut crosses (the wall, the cube), rings of small ones (the column)
    // and a sphere: cells whose candidates all lie below the cut, cross it, or lie above it.
    // The reference indexes neither the design nor the section in a grid.
    let cases = [
        (study_wall(), 0.03, vec![0.02, 0.5, 0.97]),
        (
            cuboid(Point3::new(-0.3, 0.0, 0.1), Point3::new(0.7, 2.0, 0.5)),
            0.2,
            vec![0.3, 0.49],
        ),
        (
            twisted_column(0.15, 0.1, 1.2, 90.0, 96, 40),
            0.03,
            vec![0.3, 0.6, 1.1],
        ),
        (
            icosphere(Point3::new(1.0, 2.0, 3.0), 0.5, 3),
            0.1,
            vec![2.7, 3.0, 3.41],
        ),
    ];
    let (mut matched, mut total) = (0, 0);
    for (k, (design, max_distance, heights)) in cases.iter().enumerate() {
        let grid = indexed(design, *max_distance, GridUse::Cells);
        let bvh = indexed(design, *max_distance, GridUse::BvhOnly);
        assert!(grid.stats().cells > 0, "case {k} has a grid");
        for (j, &h) in heights.iter().enumerate() {
            let section = grid.section(h).unwrap();
            let reference = bvh.section_indexed(h, GridUse::BvhOnly).unwrap();
            let (mut a, mut b) = (Cursor::default(), Cursor::default());
            for p in points(design, h, *max_distance, 20_000, (10 * k + j) as u64) {
                let fast = grid.query_cut(&p, &mut a, &section);
                let slow = bvh.query_cut(&p, &mut b, &reference);
                assert_eq!(fast, slow, "case {k}, cut at {h}, point {p:?}");
                matched += usize::from(fast.is_some());
                total += 1;
            }
        }
    }
    assert!(
        matched > total / 3,
        "only {matched} of {total} points matched"
    );
}

#[test]
fn a_whole_design_answered_from_the_grid_gives_the_bits_of_the_bvh() {
    let column = twisted_column(0.15, 0.1, 1.2, 90.0, 96, 40);
    let grid = indexed(&column, 0.03, GridUse::Cells);
    let bvh = indexed(&column, 0.03, GridUse::BvhOnly);
    let (mut a, mut b) = (Cursor::default(), Cursor::default());
    for p in points(&column, 0.6, 0.03, 40_000, 99) {
        assert_eq!(grid.query(&p, &mut a), bvh.query(&p, &mut b), "point {p:?}");
    }
}

#[test]
fn no_hint_changes_what_the_bvh_finds() {
    // Points by the rims of cut walls: the closest point is on an edge that bounds a box, where
    // a box's distance and a triangle's are one distance rounded two ways. Every triangle as the
    // hint, and none, give one answer.
    for (design, h) in [
        (study_wall(), 0.5),
        (
            cuboid(Point3::new(-0.3, 0.0, 0.1), Point3::new(0.7, 2.0, 0.5)),
            0.3,
        ),
    ] {
        let index = indexed(&design, 0.03, GridUse::BvhOnly);
        let section = index.section_indexed(h, GridUse::BvhOnly).unwrap();
        let pieces = section.index.as_ref().unwrap();
        for p in points(&design, h, 0.03, 20_000, 1) {
            for (mesh, bvh) in [(&index.mesh, &index.bvh), (&pieces.mesh, &pieces.bvh)] {
                let free = bvh.closest(mesh, &p, 0.03 * 0.03, None, &super::All);
                for t in 0..mesh.len() as u32 {
                    let hinted = bvh.closest(mesh, &p, 0.03 * 0.03, Some(t), &super::All);
                    assert_eq!(hinted, free, "{p:?} with hint {t}");
                }
            }
        }
    }
}

/// The cell sizes the grid steps over without enumerating them are sizes whose surface cells
/// would not have fitted: just below the bound, each design's surface takes more cells than
/// the budget, so skipping them leaves the grid the loop would have built.
#[test]
fn the_sizes_stepped_over_could_not_hold_the_surface() {
    use super::bvh::Bvh;
    use super::grid::{smallest_fitting, surface_cells};
    use super::mesh::Mesh;
    // Needles and specks of the kind a fuzzed STL gave (a 1 m edge beside denormal ones), a
    // sliver fan, and ordinary designs.
    let tiny = 5.8e-39;
    let needles = Design::from_indexed(
        vec![
            Point3::origin(),
            Point3::new(0.0, tiny, 0.0),
            Point3::new(tiny, 0.0, 0.0),
            Point3::new(0.125, 1.0, 0.5),
            Point3::new(1.0, 0.5, 0.25),
        ],
        vec![[0, 1, 2], [0, 2, 3], [1, 2, 4], [0, 1, 3]],
        1.0,
    );
    let mut fan_v = vec![Point3::origin()];
    let mut fan_t = Vec::new();
    for k in 0..50u32 {
        let a = f64::from(k) * 0.01;
        fan_v.push(Point3::new(
            2.0 * a.cos(),
            2.0 * a.sin(),
            1e-3 * f64::from(k),
        ));
        fan_v.push(Point3::new(
            2.0 * a.cos(),
            2.0 * a.sin() + 1e-6,
            1e-3 * f64::from(k),
        ));
        fan_t.push([0, 2 * k + 1, 2 * k + 2]);
    }
    let fan = Design::from_indexed(fan_v, fan_t, 1.0);
    let designs = [
        needles.ok(),
        fan.ok(),
        Some(cuboid(Point3::origin(), Point3::new(1.0, 2.0, 0.5))),
        Some(icosphere(Point3::new(0.1, 0.2, 0.3), 0.5, 3)),
        Some(study_wall()),
        Some(twisted_column(0.15, 0.1, 1.2, 90.0, 40, 20)),
    ];
    for (n, design) in designs.into_iter().enumerate() {
        let design = design.unwrap_or_else(|| panic!("design {n} loads"));
        let (_, order) = Bvh::build(&design.vertices, &design.triangles);
        let mesh = Mesh::new(
            design.vertices.clone(),
            &design.triangles,
            &order,
            NormalSource::Own,
        );
        for budget in [64, 4096 + mesh.len() / 2] {
            let least = smallest_fitting(&mesh, budget);
            assert!(least > 0.0, "design {n}");
            let h = least * 0.999;
            let (lo, _) = design.bounds();
            let origin = lo - Vector3::repeat(2.0 * h);
            let cells = surface_cells(&mesh, &origin, h, f64::INFINITY).len();
            assert!(
                cells > budget,
                "design {n}: {cells} surface cells of {h} m fit a budget of {budget}"
            );
        }
    }
}
