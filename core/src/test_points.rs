//! Random points for the unit tests that check geometry against brute force or a slower path.

use std::ops::Range;

use nalgebra::Point3;
use rand::Rng;

/// A point drawn from `rng`, each coordinate uniform in `range`.
pub fn random_point(rng: &mut impl Rng, range: Range<f64>) -> Point3<f64> {
    let mut coordinate = || rng.random_range(range.clone());
    Point3::new(coordinate(), coordinate(), coordinate())
}

/// `n` points drawn from `rng`, each coordinate uniform in `range`.
pub fn random_points(rng: &mut impl Rng, n: usize, range: Range<f64>) -> Vec<Point3<f64>> {
    (0..n).map(|_| random_point(rng, range.clone())).collect()
}

/// The tests' generator: the same draws for the same seed on every machine.
pub fn seeded(seed: u64) -> rand_chacha::ChaCha8Rng {
    rand::SeedableRng::seed_from_u64(seed)
}
