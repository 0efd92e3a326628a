//! Spheres of known radius in a point cloud.

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};

use crate::cloud::CloudIndex;
use crate::m3c2::classic::plane_normal;

/// A sphere target found in a scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SphereFit {
    /// The sphere's centre, in the scan's frame.
    pub centre: Point3<f64>,
    /// RMS of the radial residuals of the inliers, metres.
    pub residual_rms: f64,
    /// One-sigma uncertainty of the centre per axis, metres: σ̂² (JᵀJ)⁻¹ of the fit.
    pub centre_sigma: Vector3<f64>,
    /// Points on the sphere's shell.
    pub inliers: usize,
}

/// How sphere targets are looked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectParams {
    /// The targets' radius, metres.
    pub radius: f64,
    /// Half-width of the shell a point must lie in to count for a sphere, metres (about three
    /// times the range noise).
    pub shell: f64,
    /// Fewest points on a sphere for it to count.
    pub min_inliers: usize,
}

impl DetectParams {
    /// Parameters for targets of `radius` metres: a shell of 3 % of it (1 to 5 mm), 50 points.
    pub fn new(radius: f64) -> Self {
        Self {
            radius,
            shell: (0.03 * radius).clamp(0.001, 0.005),
            min_inliers: 50,
        }
    }
}

/// Least-squares centre of a sphere of radius `r` through `points`, from `start`
/// (Gauss–Newton on the radial residuals `|p − c| − r`).
pub fn fit_known_radius(points: &[Point3<f64>], r: f64, start: Point3<f64>) -> Option<SphereFit> {
    if points.len() < 4 {
        return None;
    }
    let mut c = start;
    let mut jtj = Matrix3::zeros();
    for _ in 0..50 {
        jtj = Matrix3::zeros();
        let mut jtr = Vector3::zeros();
        for p in points {
            let d = p - c;
            let n = d.norm();
            if n == 0.0 {
                continue;
            }
            let u = d / n;
            // r_i = |p − c| − r; ∂r_i/∂c = −u.
            let res = n - r;
            jtj += u * u.transpose();
            jtr -= u * res;
        }
        let step = jtj.try_inverse()? * (-jtr);
        c += step;
        if step.norm() < 1e-12 {
            break;
        }
    }
    let res2: f64 = points.iter().map(|p| ((p - c).norm() - r).powi(2)).sum();
    let dof = (points.len() - 3) as f64;
    let s2 = res2 / dof;
    let cov = jtj.try_inverse()? * s2;
    Some(SphereFit {
        centre: c,
        residual_rms: (res2 / points.len() as f64).sqrt(),
        centre_sigma: Vector3::new(cov[(0, 0)], cov[(1, 1)], cov[(2, 2)]).map(f64::sqrt),
        inliers: points.len(),
    })
}

/// Every sphere of `params.radius` in `points`, best supported first.
///
/// Each of a few thousand seed points proposes two centres, one radius along each side of its
/// local normal; a centre scores the points in its shell on a subsampled copy of the cloud. The
/// best candidates, apart by at least a radius, are refitted on the full cloud and kept when
/// enough points lie on them and those points cover a cap rather than a ring (a plane cut by the
/// shell also scores, but only along a circle).
pub fn detect(points: &[Point3<f64>], params: &DetectParams) -> Vec<SphereFit> {
    let r = params.radius;
    if points.len() < params.min_inliers || r.is_nan() || r <= 0.0 {
        return Vec::new();
    }
    let Ok(full) = CloudIndex::new(points) else {
        return Vec::new();
    };
    // Score on about 40 cells per radius: enough to tell a sphere from a ring, far fewer points.
    let voxel = r / 20.0;
    let mut seen = std::collections::HashSet::new();
    let coarse: Vec<Point3<f64>> = points
        .iter()
        .filter(|p| seen.insert((p.coords / voxel).map(|v| v.floor() as i64)))
        .copied()
        .collect();
    let Ok(coarse_index) = CloudIndex::new(&coarse) else {
        return Vec::new();
    };
    let step = (coarse.len() / 3000).max(1);
    let mut ids = Vec::new();
    let mut candidates: Vec<(usize, Point3<f64>)> = Vec::new();
    for p in coarse.iter().step_by(step) {
        coarse_index.within(p, 0.4 * r, &mut ids);
        if ids.len() < 6 {
            continue;
        }
        let Some(n) = plane_normal(ids.iter().map(|&i| coarse_index.point(i))) else {
            continue;
        };
        for c in [p + n * r, p - n * r] {
            coarse_index.within(&c, r + params.shell.max(voxel), &mut ids);
            let score = ids
                .iter()
                .filter(|&&i| {
                    ((coarse_index.point(i) - c).norm() - r).abs() <= params.shell.max(voxel)
                })
                .count();
            candidates.push((score, c));
        }
    }
    candidates.sort_by_key(|c| std::cmp::Reverse(c.0));
    let mut found: Vec<SphereFit> = Vec::new();
    let mut tried: Vec<Point3<f64>> = Vec::new();
    for (_, c) in candidates {
        if tried.iter().any(|t| (t - c).norm() < r) || tried.len() > 200 {
            continue;
        }
        tried.push(c);
        let mut centre = c;
        let mut fit = None;
        for _ in 0..3 {
            full.within(&centre, r + params.shell, &mut ids);
            let shell: Vec<Point3<f64>> = ids
                .iter()
                .map(|&i| full.point(i))
                .filter(|q| ((q - centre).norm() - r).abs() <= params.shell)
                .collect();
            fit = fit_known_radius(&shell, r, centre);
            match fit {
                Some(f) => centre = f.centre,
                None => break,
            }
        }
        let Some(f) = fit else { continue };
        if f.inliers < params.min_inliers || found.iter().any(|g| (g.centre - f.centre).norm() < r)
        {
            continue;
        }
        full.within(&f.centre, r + params.shell, &mut ids);
        let dirs: Vec<Vector3<f64>> = ids
            .iter()
            .map(|&i| full.point(i) - f.centre)
            .filter(|d| (d.norm() - r).abs() <= params.shell)
            .map(|d| d / d.norm())
            .collect();
        if cap_spread(&dirs) < 0.004 {
            continue;
        }
        found.push(f);
    }
    found.sort_by_key(|f| std::cmp::Reverse(f.inliers));
    found
}

/// The smallest variance of unit directions: near 0 for a ring, about 0.02 for a 60° cap.
fn cap_spread(dirs: &[Vector3<f64>]) -> f64 {
    if dirs.len() < 4 {
        return 0.0;
    }
    let n = dirs.len() as f64;
    let mean = dirs.iter().sum::<Vector3<f64>>() / n;
    let mut cov = Matrix3::zeros();
    for d in dirs {
        let e = d - mean;
        cov += e * e.transpose();
    }
    SymmetricEigen::new(cov / n).eigenvalues.min()
}

/// Points on the cap of a sphere a station at `eye` sees (within 75° of the line of sight),
/// spaced about `step`: ground truth for tests and the simulator.
pub fn visible_cap(centre: Point3<f64>, r: f64, eye: Point3<f64>, step: f64) -> Vec<Point3<f64>> {
    let axis = (eye - centre).normalize();
    let (u, v) = {
        let a = if axis.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let u = axis.cross(&a).normalize();
        (u, axis.cross(&u))
    };
    let max = 75f64.to_radians();
    let mut out = Vec::new();
    let rings = ((max * r) / step).ceil() as usize;
    for k in 0..=rings {
        let theta = max * k as f64 / rings.max(1) as f64;
        let count = ((std::f64::consts::TAU * r * theta.sin()) / step)
            .ceil()
            .max(1.0) as usize;
        for j in 0..count {
            let phi = std::f64::consts::TAU * j as f64 / count as f64;
            let d = axis * theta.cos() + (u * phi.cos() + v * phi.sin()) * theta.sin();
            out.push(centre + d * r);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn three_spheres_on_a_floor_are_found_within_their_sigma() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let noise = Normal::new(0.0, 0.0005).unwrap();
        let r = 0.0725;
        let eye = Point3::new(0.0, -3.0, 1.5);
        let truth = [
            Point3::new(-1.0, 0.5, 0.3),
            Point3::new(0.2, 1.0, 0.9),
            Point3::new(1.1, 0.2, 0.5),
        ];
        let mut pts: Vec<Point3<f64>> = truth
            .iter()
            .flat_map(|c| visible_cap(*c, r, eye, 0.003))
            .collect();
        // A floor and a wall, as busy as the spheres.
        for i in 0..300 {
            for j in 0..200 {
                pts.push(Point3::new(
                    -1.5 + i as f64 * 0.01,
                    -0.5 + j as f64 * 0.01,
                    0.0,
                ));
                pts.push(Point3::new(-1.5 + i as f64 * 0.01, 2.0, j as f64 * 0.01));
            }
        }
        let mut jitter = |p: &Point3<f64>| {
            p + Vector3::new(
                noise.sample(&mut rng),
                noise.sample(&mut rng),
                noise.sample(&mut rng),
            )
        };
        let pts: Vec<Point3<f64>> = pts.iter().map(&mut jitter).collect();
        let found = detect(&pts, &DetectParams::new(r));
        assert_eq!(found.len(), 3, "{found:?}");
        for c in truth {
            let f = found
                .iter()
                .find(|f| (f.centre - c).norm() < 0.01)
                .unwrap_or_else(|| panic!("no sphere at {c}: {found:?}"));
            let err = f.centre - c;
            for k in 0..3 {
                assert!(
                    err[k].abs() < 4.0 * f.centre_sigma[k] + 1e-5,
                    "{err} vs σ {}",
                    f.centre_sigma
                );
            }
            assert!(
                (f.residual_rms - 0.0005).abs() < 0.0002,
                "{}",
                f.residual_rms
            );
        }
    }

    #[test]
    fn an_exact_cap_fits_exactly_and_too_few_points_do_not() {
        let c = Point3::new(0.3, -0.2, 1.0);
        let pts = visible_cap(c, 0.05, Point3::new(2.0, 2.0, 2.0), 0.004);
        let f = fit_known_radius(&pts, 0.05, c + Vector3::new(0.01, -0.01, 0.02)).unwrap();
        assert!((f.centre - c).norm() < 1e-9);
        assert!(f.residual_rms < 1e-9);
        assert!(fit_known_radius(&pts[..3], 0.05, c).is_none());
    }
}
