//! Synthetic scans of the study wall's +y face (2 m along the layers, 0.98 m across them)
//! with known shapes and 0.3 mm of scanner noise: the gaps against their analytic values.

use super::*;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

const NOISE: f64 = 0.0003;
/// What bin means of a few points leave of the noise in the deepest gap over a face.
const SLACK: f64 = 0.0006;

/// Empty cells over the study wall, and the index of its +y face.
fn wall() -> (FlatnessGrid, usize) {
    let grid = FlatnessGrid::new(&crate::design::shapes::study_wall());
    let face = grid
        .faces()
        .iter()
        .position(|f| f.normal.y > 0.99)
        .expect("the wall has a +y face");
    (grid, face)
}

/// The wall's +y face scanned every 3 mm, its height off the plane `w(x, z)` plus noise.
fn scanned(w: impl Fn(f64, f64) -> f64) -> (FlatnessGrid, u32) {
    let (mut grid, face) = wall();
    let y = grid.faces()[face].origin.y;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let noise = Normal::new(0.0, NOISE).unwrap();
    let step = 0.003;
    let (nx, nz) = ((2.0 / step) as usize, (0.98 / step) as usize);
    for i in 0..nx {
        for j in 0..nz {
            let (x, z) = (-1.0 + (i as f64 + 0.5) * step, (j as f64 + 0.5) * step);
            let p = Point3::new(x, y + w(x, z) + noise.sample(&mut rng), z);
            grid.add_point(face, &p);
        }
    }
    (grid, face as u32)
}

fn gap(grid: &FlatnessGrid, face: u32, direction: Direction, span: f64) -> FlatnessGap {
    let din = FlatnessStandard::Din18202 { row: 6 };
    *grid
        .judge(&din)
        .iter()
        .find(|g| g.face == face && g.direction == direction && (g.span - span).abs() < 1e-9)
        .unwrap_or_else(|| panic!("no gap at {span} m {direction:?}"))
}

#[test]
fn a_flat_face_passes_the_strictest_row_at_every_span() {
    let (grid, face) = scanned(|_, _| 0.0);
    let row7 = FlatnessStandard::Din18202 { row: 7 };
    let gaps: Vec<_> = grid
        .judge(&row7)
        .into_iter()
        .filter(|g| g.face == face)
        .collect();
    // 0.1 m and 1 m along, 0.1 m across (the face is 0.98 m high).
    assert_eq!(gaps.len(), 3, "{gaps:?}");
    for g in &gaps {
        assert!(g.gap < SLACK && g.passes(), "{g:?}");
    }
}

#[test]
fn waviness_gives_twice_its_amplitude_at_spans_beyond_its_wavelength() {
    let (a, wavelength) = (0.002, 0.25);
    let (grid, face) = scanned(|x, _| a * (std::f64::consts::TAU * x / wavelength).sin());
    let along = gap(&grid, face, Direction::Along, 1.0);
    assert!((along.gap - 2.0 * a).abs() < SLACK, "{along:?}");
    // 4 mm at 1 m passes row 6 (5 mm) and fails row 7 (3 mm).
    assert!(along.passes());
    let row7 = FlatnessStandard::Din18202 { row: 7 };
    assert!(along.gap > row7.limit(1.0));
    // A straightedge shorter than the wave gives less: the same straightedge on the noise-free
    // wave sampled every millimetre.
    let short = gap(&grid, face, Direction::Along, 0.1);
    let exact: Vec<Option<f64>> = (0..2000)
        .map(|i| Some(a * (std::f64::consts::TAU * (i as f64 * 0.001) / wavelength).sin()))
        .collect();
    let truth = worst_gap(&exact, 100, 1.0).unwrap().0;
    assert!(truth < 2.0 * a);
    assert!(
        (short.gap - truth).abs() < SLACK,
        "{short:?} against {truth}"
    );
    // Across the layers the face is flat.
    assert!(gap(&grid, face, Direction::Across, 0.1).gap < SLACK);
}

#[test]
fn a_bow_along_the_wall_gives_its_chord_sag_at_each_span() {
    // w = c·x²: under a chord of span s the sag is c·s²/4, anywhere along.
    let c = 0.008;
    let (grid, face) = scanned(|x, _| c * x * x);
    for span in [0.1, 1.0] {
        let g = gap(&grid, face, Direction::Along, span);
        let sag = c * span * span / 4.0;
        assert!((g.gap - sag).abs() < SLACK, "{g:?} against {sag}");
    }
    // A bow the other way (the middle out) has no low point between two high ones: the
    // straightedge rocks on its crown, and the gap is measured nowhere. A crown is judged by
    // the dimensions, not here.
    let (grid, face) = scanned(|x, _| -c * x * x);
    let g = gap(&grid, face, Direction::Along, 1.0);
    assert!(g.gap < SLACK, "{g:?}");
}

#[test]
fn a_tilted_face_is_flat_and_a_dent_is_found_where_it_is() {
    // Tilted 5 mm over its height: plumb, not flatness.
    let (grid, face) = scanned(|_, z| -0.005 * z / 0.98);
    for d in [Direction::Along, Direction::Across] {
        assert!(gap(&grid, face, d, 0.1).gap < SLACK);
    }
    // A 6 mm dent, 0.1 m across, at x = 0.3, z = 0.5.
    let (grid, face) = scanned(|x, z| {
        let r = ((x - 0.3).powi(2) + (z - 0.5).powi(2)).sqrt();
        if r < 0.05 {
            -0.003 * (1.0 + (std::f64::consts::PI * r / 0.05).cos())
        } else {
            0.0
        }
    });
    // 6 mm at 1 m fails row 6 (5 mm).
    let g = gap(&grid, face, Direction::Along, 1.0);
    assert!((g.gap - 0.006).abs() < SLACK && !g.passes(), "{g:?}");
    assert!(
        (g.at.x - 0.3).abs() < 0.03 && (g.at.z - 0.5).abs() < 0.03,
        "{g:?}"
    );
}

#[test]
fn points_seen_at_grazing_incidence_are_left_out() {
    let (mut grid, face) = wall();
    let triangle = grid
        .faces
        .of_triangle
        .iter()
        .position(|t| *t == Some(face as u32))
        .unwrap() as u32;
    let y = grid.faces()[face].origin.y;
    let devs: Vec<PointDeviation> = (0..100)
        .map(|i| PointDeviation {
            position: [-0.9 + 0.018 * i as f64, y, 0.5],
            distance: 0.0,
            triangle,
            ..Default::default()
        })
        .collect();
    let counted = |g: &FlatnessGrid| g.cells[face].count.iter().sum::<u32>();
    // From 2 m in front: every point.
    grid.add(&devs, Some(Point3::new(0.0, y + 2.0, 0.5)));
    assert_eq!(counted(&grid), 100);
    // From beyond the wall's end, 5 cm off its face: all beyond 75°.
    grid.clear();
    grid.add(&devs, Some(Point3::new(1.5, y + 0.05, 0.5)));
    assert_eq!(counted(&grid), 0);
    // Without a known origin, every point.
    grid.add(&devs, None);
    assert_eq!(counted(&grid), 100);
}
