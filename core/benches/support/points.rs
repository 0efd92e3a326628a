//! Benchmark input shared by the C2M and agent benchmarks: points on a design's surface with
//! Gaussian noise (σ 0.5 mm per axis), in scan-like order (consecutive points lie close together,
//! as consecutive points of a scan line do). Deterministic.

use asbuilt_core::Design;
use nalgebra::Point3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub fn noisy_surface_points(design: &Design, n: usize) -> Vec<Point3<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let per_triangle = n.div_ceil(design.triangles.len());
    let mut out = Vec::with_capacity(n);
    'outer: for t in &design.triangles {
        let [a, b, c] = t.map(|i| design.vertices[i as usize]);
        for _ in 0..per_triangle {
            let (u, v): (f64, f64) = (rng.random(), rng.random());
            let (u, v) = if u + v > 1.0 {
                (1.0 - u, 1.0 - v)
            } else {
                (u, v)
            };
            let g = |rng: &mut ChaCha8Rng| {
                // Box–Muller: σ = 0.5 mm per axis.
                let (u1, u2): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
                0.5e-3 * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
            };
            let noise = nalgebra::Vector3::new(g(&mut rng), g(&mut rng), g(&mut rng));
            out.push(a + (b - a) * u + (c - a) * v + noise);
            if out.len() == n {
                break 'outer;
            }
        }
    }
    out
}
