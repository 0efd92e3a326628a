//! Two-cloud M3C2, as in CloudCompare's plugin: normals by principal component analysis of the
//! first cloud at the normal scale, oriented towards a preferred direction, then projection of
//! both clouds inside the cylinder of each core point.

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use super::lod95;
use crate::cloud::CloudIndex;

/// How a cylinder's points become one position along the normal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Estimator {
    /// Mean position; spread is the standard deviation.
    Mean,
    /// Median position; spread is the interquartile range over 1.349 (σ for normal data).
    Median,
}

/// The parameters of two-cloud M3C2 (Lague et al. 2013), in the clouds' units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassicParams {
    /// Diameter of the sphere whose points of cloud 1 give each core point's normal.
    pub normal_diameter: f64,
    /// Cylinder diameter.
    pub projection_diameter: f64,
    /// Cylinder half-length along the normal.
    pub max_depth: f64,
    /// Mean or median position in each cylinder.
    pub estimator: Estimator,
    /// Registration error added to the level of detection, in the clouds' units.
    pub registration_error: f64,
    /// Normals are flipped to point along this direction (CloudCompare's default is +Z).
    pub orientation: Vector3<f64>,
    /// Below this many points in either cylinder there is a distance but no level of detection
    /// and no verdict (CloudCompare's "minimum points for statistics", 5 by default).
    pub min_points: u32,
}

impl ClassicParams {
    /// The paper's three scales, with a mean, no registration error, normals towards +Z and
    /// five points for statistics.
    pub fn new(normal_diameter: f64, projection_diameter: f64, max_depth: f64) -> Self {
        Self {
            normal_diameter,
            projection_diameter,
            max_depth,
            estimator: Estimator::Mean,
            registration_error: 0.0,
            orientation: Vector3::z(),
            min_points: 5,
        }
    }
}

#[derive(Debug, thiserror::Error)]
#[error(
    "M3C2 scales must be positive: normal diameter {normal_diameter}, projection diameter \
     {projection_diameter}, maximum depth {max_depth}"
)]
/// M3C2 scales that cannot be used.
pub struct ClassicError {
    /// The normal diameter given.
    pub normal_diameter: f64,
    /// The projection diameter given.
    pub projection_diameter: f64,
    /// The maximum depth given.
    pub max_depth: f64,
}

/// One cloud's projections inside a cylinder.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Projection {
    /// Points of the cloud in the cylinder.
    pub count: u32,
    /// Mean or median offset along the normal from the core point.
    pub position: f64,
    /// Their spread along the normal (standard deviation, or its robust estimate).
    pub spread: f64,
}

/// M3C2 at one core point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassicResult {
    /// `None` when fewer than three points of cloud 1 lie within the normal scale.
    pub normal: Option<Vector3<f64>>,
    /// Cloud 1's projection.
    pub cloud1: Projection,
    /// Cloud 2's projection.
    pub cloud2: Projection,
    /// Cloud 2's position minus cloud 1's; `None` when either cylinder is empty.
    pub distance: Option<f64>,
    /// `None` when either cylinder holds fewer than the minimum points for statistics.
    pub lod95: Option<f64>,
    /// Whether |distance| exceeds the level of detection.
    pub significant: bool,
}

/// M3C2 from `cloud1` to `cloud2` at every core point.
pub fn compare(
    cloud1: &CloudIndex,
    cloud2: &CloudIndex,
    cores: &[Point3<f64>],
    params: &ClassicParams,
) -> Result<Vec<ClassicResult>, ClassicError> {
    let ok = |v: f64| v > 0.0 && v.is_finite();
    if !ok(params.normal_diameter) || !ok(params.projection_diameter) || !ok(params.max_depth) {
        return Err(ClassicError {
            normal_diameter: params.normal_diameter,
            projection_diameter: params.projection_diameter,
            max_depth: params.max_depth,
        });
    }
    Ok(cores
        .par_iter()
        .map_init(
            || (Vec::new(), Vec::new()),
            |(ids, offsets), c| compare_one(cloud1, cloud2, c, params, ids, offsets),
        )
        .collect())
}

fn compare_one(
    cloud1: &CloudIndex,
    cloud2: &CloudIndex,
    core: &Point3<f64>,
    params: &ClassicParams,
    ids: &mut Vec<u32>,
    offsets: &mut Vec<f64>,
) -> ClassicResult {
    let empty = ClassicResult {
        normal: None,
        cloud1: Projection::default(),
        cloud2: Projection::default(),
        distance: None,
        lod95: None,
        significant: false,
    };
    let Some(normal) = pca_normal(
        cloud1,
        core,
        0.5 * params.normal_diameter,
        &params.orientation,
        ids,
    ) else {
        return empty;
    };
    let cloud1_p = project(cloud1, core, &normal, params, ids, offsets);
    let cloud2_p = project(cloud2, core, &normal, params, ids, offsets);
    let distance =
        (cloud1_p.count > 0 && cloud2_p.count > 0).then_some(cloud2_p.position - cloud1_p.position);
    let enough =
        cloud1_p.count >= params.min_points.max(1) && cloud2_p.count >= params.min_points.max(1);
    let lod = (distance.is_some() && enough).then(|| {
        lod95(
            cloud1_p.spread,
            cloud1_p.count,
            cloud2_p.spread,
            cloud2_p.count,
            params.registration_error,
        )
    });
    ClassicResult {
        normal: Some(normal),
        cloud1: cloud1_p,
        cloud2: cloud2_p,
        distance,
        lod95: lod,
        significant: matches!((distance, lod), (Some(d), Some(l)) if d.abs() > l),
    }
}

/// The normal of the least-squares plane through the points of `cloud` within `radius` of `p`:
/// the eigenvector of their covariance with the smallest eigenvalue.
pub fn pca_normal(
    cloud: &CloudIndex,
    p: &Point3<f64>,
    radius: f64,
    orientation: &Vector3<f64>,
    ids: &mut Vec<u32>,
) -> Option<Vector3<f64>> {
    cloud.within(p, radius, ids);
    if ids.len() < 3 {
        return None;
    }
    let n = plane_normal(ids.iter().map(|&i| cloud.point(i)))?;
    Some(if n.dot(orientation) < 0.0 { -n } else { n })
}

/// Least-squares plane normal through points (unit, sign arbitrary); `None` when degenerate.
pub fn plane_normal(points: impl Iterator<Item = Point3<f64>> + Clone) -> Option<Vector3<f64>> {
    let mut count = 0usize;
    let mut sum = Vector3::zeros();
    for q in points.clone() {
        sum += q.coords;
        count += 1;
    }
    if count < 3 {
        return None;
    }
    let mean = sum / count as f64;
    let mut cov = Matrix3::zeros();
    for q in points {
        let d = q.coords - mean;
        cov += d * d.transpose();
    }
    let eig = SymmetricEigen::new(cov / count as f64);
    let k = eig.eigenvalues.imin();
    let n = eig.eigenvectors.column(k).into_owned();
    n.try_normalize(1e-300)
}

fn project(
    cloud: &CloudIndex,
    core: &Point3<f64>,
    n: &Vector3<f64>,
    params: &ClassicParams,
    ids: &mut Vec<u32>,
    offsets: &mut Vec<f64>,
) -> Projection {
    let r = 0.5 * params.projection_diameter;
    let h = params.max_depth;
    cloud.within(core, (r * r + h * h).sqrt(), ids);
    offsets.clear();
    for &i in ids.iter() {
        let v = cloud.point(i) - core;
        let a = v.dot(n);
        if a.abs() <= h && v.norm_squared() - a * a <= r * r {
            offsets.push(a);
        }
    }
    let count = offsets.len() as u32;
    if count == 0 {
        return Projection::default();
    }
    match params.estimator {
        Estimator::Mean => {
            let mean = offsets.iter().sum::<f64>() / count as f64;
            // Population σ, as CloudCompare reports it.
            let var = offsets.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / count as f64;
            Projection {
                count,
                position: mean,
                spread: var.sqrt(),
            }
        }
        Estimator::Median => {
            offsets.sort_unstable_by(f64::total_cmp);
            let q = |f: f64| {
                let x = f * (offsets.len() - 1) as f64;
                let (i, t) = (x.floor() as usize, x - x.floor());
                let hi = offsets[(i + 1).min(offsets.len() - 1)];
                offsets[i] + t * (hi - offsets[i])
            };
            Projection {
                count,
                position: q(0.5),
                spread: (q(0.75) - q(0.25)) / 1.349,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Two tilted planes 0.3 apart: the distance along the recovered normal is the offset, at
    /// every core point, and the normal is the plane's.
    #[test]
    fn parallel_planes_give_their_separation() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let n = Vector3::new(0.2, -0.1, 1.0).normalize();
        let u = n.cross(&Vector3::x()).normalize();
        let v = n.cross(&u);
        let plane = |rng: &mut ChaCha8Rng, off: f64| -> Vec<Point3<f64>> {
            (0..20_000)
                .map(|_| {
                    let (a, b): (f64, f64) =
                        (rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0));
                    Point3::origin() + u * a + v * b + n * (off + rng.random_range(-0.01..0.01))
                })
                .collect()
        };
        let c1 = CloudIndex::new(&plane(&mut rng, 0.0)).unwrap();
        let c2 = CloudIndex::new(&plane(&mut rng, 0.3)).unwrap();
        let cores: Vec<Point3<f64>> = (0..20)
            .map(|i| Point3::origin() + u * (i as f64 * 0.3 - 3.0))
            .collect();
        for est in [Estimator::Mean, Estimator::Median] {
            let mut p = ClassicParams::new(1.0, 1.0, 0.5);
            p.estimator = est;
            for r in compare(&c1, &c2, &cores, &p).unwrap() {
                assert!((r.normal.unwrap() - n).norm() < 0.01);
                assert!((r.distance.unwrap() - 0.3).abs() < 0.005, "{r:?}");
                assert!(r.significant);
                assert!(r.cloud1.count > 100 && r.cloud2.count > 100);
                // Uniform ±0.01 noise: σ = 0.02 / √12, and an interquartile range of 0.01;
                // the normal's few milliradians of tilt widen both a little.
                let spread = match est {
                    Estimator::Mean => 0.02 / 12f64.sqrt(),
                    Estimator::Median => 0.01 / 1.349,
                };
                assert!((r.cloud1.spread - spread).abs() < 0.003, "{r:?}");
            }
        }
        // Beyond the depth the second plane is not found.
        let r = compare(&c1, &c2, &cores[..1], &ClassicParams::new(1.0, 1.0, 0.2)).unwrap();
        assert_eq!(r[0].cloud2.count, 0);
        assert_eq!(r[0].distance, None);
    }
}
