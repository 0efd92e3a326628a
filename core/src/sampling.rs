//! Area-uniform samples on a design surface: the core points of design-referenced M3C2 and the
//! probes of reverse C2C and coverage. Each sample carries its face normal and stands for an
//! equal share of the surface, so counts of samples convert to areas.

use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::design::Design;

/// Points spread evenly over a design's surface, with the face each lies on.
#[derive(Debug, Clone)]
pub struct DesignSamples {
    /// The samples, design frame.
    pub points: Vec<Point3<f64>>,
    /// Unit outward normal of the face each sample lies on.
    pub normals: Vec<Vector3<f64>>,
    /// Index of that face in the design.
    pub triangles: Vec<u32>,
    /// Surface area each sample stands for, m²: the design's area over the sample count.
    pub area_per_sample: f64,
}

/// A sampling that cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum SamplingError {
    /// The spacing is not a positive number.
    #[error("sample spacing must be a positive number of metres, got {0}")]
    Spacing(f64),
    #[error(
        "a spacing of {spacing} m puts {count} samples on {area:.3} m² of design, more than the \
         limit of {limit}: use a larger --spacing"
    )]
    /// The spacing would make more samples than [`MAX_SAMPLES`].
    TooMany {
        /// The spacing, metres.
        spacing: f64,
        /// The design's area, m².
        area: f64,
        /// The samples it would take.
        count: f64,
        /// [`MAX_SAMPLES`].
        limit: usize,
    },
}

/// Samples beyond this would make per-sample state the dominant memory cost of a job.
pub const MAX_SAMPLES: usize = 20_000_000;

impl DesignSamples {
    /// About one sample per `spacing²` of surface, uniform in area. Each triangle receives
    /// `area / spacing²` samples with the fraction resolved by a seeded draw, so small triangles
    /// are sampled in proportion and the result is the same for the same seed.
    pub fn generate(design: &Design, spacing: f64, seed: u64) -> Result<Self, SamplingError> {
        if !(spacing > 0.0 && spacing.is_finite()) {
            return Err(SamplingError::Spacing(spacing));
        }
        // The triangles' areas in parallel; the draws below are one seeded sequence and stay in
        // order. Summed in order, as `Design::surface_area` sums them: same bits.
        let areas: Vec<f64> = design
            .triangles
            .par_iter()
            .map(|t| design.triangle_area(t))
            .collect();
        let area: f64 = areas.iter().sum();
        let expected = area / (spacing * spacing);
        if expected > MAX_SAMPLES as f64 {
            return Err(SamplingError::TooMany {
                spacing,
                area,
                count: expected.round(),
                limit: MAX_SAMPLES,
            });
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let capacity = expected.ceil() as usize + design.triangles.len();
        let mut points = Vec::with_capacity(capacity);
        let mut normals = Vec::with_capacity(capacity);
        let mut triangles = Vec::with_capacity(capacity);
        for (t, (tri, tri_area)) in design.triangles.iter().zip(&areas).enumerate() {
            let share = tri_area / (spacing * spacing);
            let mut n = share.floor() as usize;
            if rng.random::<f64>() < share - share.floor() {
                n += 1;
            }
            if n == 0 {
                continue;
            }
            let [a, b, c] = tri.map(|i| design.vertices[i as usize]);
            let normal = (b - a).cross(&(c - a)).normalize();
            for _ in 0..n {
                // Uniform on the triangle: fold the unit square onto it.
                let (mut u, mut v) = (rng.random::<f64>(), rng.random::<f64>());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                points.push(a + (b - a) * u + (c - a) * v);
                normals.push(normal);
                triangles.push(t as u32);
            }
        }
        let area_per_sample = if points.is_empty() {
            0.0
        } else {
            area / points.len() as f64
        };
        Ok(Self {
            points,
            normals,
            triangles,
            area_per_sample,
        })
    }

    /// Keeps only the samples at or above `z_min` (design frame), in order: a line profiler's
    /// pass judges only what its range reaches. Each keeps the area it stands for.
    pub fn retain_from(&mut self, z_min: f64) {
        let mut kept = 0;
        for i in 0..self.points.len() {
            if self.points[i].z >= z_min {
                self.points[kept] = self.points[i];
                self.normals[kept] = self.normals[i];
                self.triangles[kept] = self.triangles[i];
                kept += 1;
            }
        }
        self.points.truncate(kept);
        self.normals.truncate(kept);
        self.triangles.truncate(kept);
    }

    /// Samples.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether there is no sample.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::shapes;

    #[test]
    fn box_samples_are_on_the_surface_with_outward_normals_and_even_area() {
        let d = shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 2.0, 0.5));
        let s = DesignSamples::generate(&d, 0.02, 7).unwrap();
        let area = 2.0 * (1.0 * 2.0 + 1.0 * 0.5 + 2.0 * 0.5);
        let expected = area / 0.0004;
        assert!(
            (s.len() as f64 - expected).abs() < 0.02 * expected,
            "{}",
            s.len()
        );
        assert!((s.area_per_sample * s.len() as f64 - area).abs() < 1e-9);
        let centre = Point3::new(0.5, 1.0, 0.25);
        let mut top = 0usize;
        for (p, n) in s.points.iter().zip(&s.normals) {
            let on_face = [p.x, p.y, p.z]
                .iter()
                .zip([(0.0, 1.0), (0.0, 2.0), (0.0, 0.5)])
                .any(|(v, (lo, hi))| (v - lo).abs() < 1e-12 || (v - hi).abs() < 1e-12);
            assert!(on_face, "{p}");
            assert!((p - centre).dot(n) > 0.0, "normal points inward at {p}");
            if (p.z - 0.5).abs() < 1e-12 {
                top += 1;
            }
        }
        // The top face holds 2 of the 7 m²: its share of samples matches its share of area.
        let frac = top as f64 / s.len() as f64;
        assert!((frac - 2.0 / 7.0).abs() < 0.01, "{frac}");
    }

    #[test]
    fn same_seed_same_samples_and_bad_spacing_is_refused() {
        let d = shapes::icosphere(Point3::origin(), 1.0, 3);
        let a = DesignSamples::generate(&d, 0.05, 1).unwrap();
        let b = DesignSamples::generate(&d, 0.05, 1).unwrap();
        let c = DesignSamples::generate(&d, 0.05, 2).unwrap();
        assert_eq!(a.points, b.points);
        assert_ne!(a.points, c.points);
        assert!(matches!(
            DesignSamples::generate(&d, 0.0, 1),
            Err(SamplingError::Spacing(_))
        ));
        assert!(matches!(
            DesignSamples::generate(&d, 1e-6, 1),
            Err(SamplingError::TooMany { .. })
        ));
    }
}
