//! The rigid transform that best carries one set of points onto another (Horn 1987; Kabsch
//! 1976, via SVD), or the translation alone when the orientation is known.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// A rigid fit of measured points onto known ones, with what a surveyor checks of it.
#[derive(Debug, Clone, PartialEq)]
pub struct RigidFit {
    /// `to ≈ transform · from`.
    pub transform: Isometry3<f64>,
    /// |transform · from_i − to_i| per pair, metres.
    pub residuals: Vec<f64>,
    /// Root mean square of the residuals, metres.
    pub rms: f64,
    /// One-sigma uncertainty of the translation per axis at the targets' centroid, metres:
    /// σ̂ / √n with σ̂² = Σ|r|² / degrees of freedom.
    pub translation_sigma: Vector3<f64>,
    /// Targets (groups; pair indices for ungrouped fits) whose leave-one-out residual (the
    /// largest distance of their pairs from the fit made without them) is beyond
    /// `FLAG_SIGMAS` √3 σ̂ of that fit and more than `FLAG_FLOOR`: group and residual.
    pub misfits: Vec<(usize, f64)>,
}

/// A leave-one-out residual below this is never flagged, however good the others are.
pub const FLAG_FLOOR: f64 = 0.002;
/// How many σ (per axis, as a 3-D distance) a target must stand off the others' fit to be
/// named. Wide, because σ̂ comes from few targets and targets far out have long lever arms.
pub const FLAG_SIGMAS: f64 = 6.0;

/// Why a rigid fit cannot be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RigidError {
    /// Measured and known points do not pair up.
    #[error("{from} measured points for {to} known points: every target needs both")]
    Lengths {
        /// Measured points.
        from: usize,
        /// Known points.
        to: usize,
    },
    /// Fewer targets than the fit needs.
    #[error("{got} target(s) given; {need} are needed ({what})")]
    TooFew {
        /// Targets given.
        got: usize,
        /// Targets needed.
        need: usize,
        /// What needs them.
        what: &'static str,
    },
    /// The targets are on one line: the rotation about it is not determined.
    #[error(
        "the targets are (nearly) on one line (spread across the line {spread_mm:.2} mm): the \
         rotation about that line is not determined. Add a target off the line, or use the \
         fixed-orientation mode"
    )]
    Collinear {
        /// How far the targets spread across their line, millimetres.
        spread_mm: f64,
    },
}

/// The least-squares rigid transform with `to ≈ T · from`. Needs at least 3 targets that are
/// not on one line.
pub fn fit(from: &[Point3<f64>], to: &[Point3<f64>]) -> Result<RigidFit, RigidError> {
    let groups: Vec<usize> = (0..from.len()).collect();
    fit_grouped(from, to, &groups)
}

/// [`fit`] where pairs share a target (`groups[i]`, the same sphere seen from several
/// stations): a target is left out with all its pairs when it is judged, and `misfits` name
/// groups.
pub fn fit_grouped(
    from: &[Point3<f64>],
    to: &[Point3<f64>],
    groups: &[usize],
) -> Result<RigidFit, RigidError> {
    check(
        from,
        to,
        3,
        "three targets off one line fix a rigid transform",
    )?;
    let t = kabsch(from, to)?;
    Ok(finish(from, to, groups, t, 6, |f, t| kabsch(f, t).ok()))
}

/// The translation with `to ≈ R · from + t` for a known rotation `rotation`.
pub fn fit_translation(
    from: &[Point3<f64>],
    to: &[Point3<f64>],
    rotation: UnitQuaternion<f64>,
) -> Result<RigidFit, RigidError> {
    let groups: Vec<usize> = (0..from.len()).collect();
    fit_translation_grouped(from, to, &groups, rotation)
}

/// [`fit_translation`] with pairs grouped by target, as in [`fit_grouped`].
pub fn fit_translation_grouped(
    from: &[Point3<f64>],
    to: &[Point3<f64>],
    groups: &[usize],
    rotation: UnitQuaternion<f64>,
) -> Result<RigidFit, RigidError> {
    check(from, to, 1, "one target fixes a translation")?;
    let solve = |f: &[Point3<f64>], t: &[Point3<f64>]| {
        let n = f.len() as f64;
        let d: Vector3<f64> = f
            .iter()
            .zip(t)
            .map(|(a, b)| b - rotation * a)
            .sum::<Vector3<f64>>()
            / n;
        Some(Isometry3::from_parts(Translation3::from(d), rotation))
    };
    let t = solve(from, to).expect("a mean exists");
    Ok(finish(from, to, groups, t, 3, solve))
}

fn check(
    from: &[Point3<f64>],
    to: &[Point3<f64>],
    need: usize,
    what: &'static str,
) -> Result<(), RigidError> {
    if from.len() != to.len() {
        return Err(RigidError::Lengths {
            from: from.len(),
            to: to.len(),
        });
    }
    if from.len() < need {
        return Err(RigidError::TooFew {
            got: from.len(),
            need,
            what,
        });
    }
    Ok(())
}

fn centroid(p: &[Point3<f64>]) -> Point3<f64> {
    Point3::from(p.iter().map(|q| q.coords).sum::<Vector3<f64>>() / p.len() as f64)
}

fn kabsch(from: &[Point3<f64>], to: &[Point3<f64>]) -> Result<Isometry3<f64>, RigidError> {
    let (cf, ct) = (centroid(from), centroid(to));
    // Collinearity: the second singular value of the centred known points.
    let mut spread = Matrix3::zeros();
    for p in to {
        let d = p - ct;
        spread += d * d.transpose();
    }
    let sv = spread.symmetric_eigenvalues();
    let mut s = [sv[0], sv[1], sv[2]];
    s.sort_by(f64::total_cmp);
    let across = (s[1].max(0.0) / to.len() as f64).sqrt();
    if across < 1e-3 * (s[2].max(0.0) / to.len() as f64).sqrt().max(1e-9) || across < 1e-6 {
        return Err(RigidError::Collinear {
            spread_mm: across * 1e3,
        });
    }
    let mut h = Matrix3::zeros();
    for (a, b) in from.iter().zip(to) {
        h += (a - cf) * (b - ct).transpose();
    }
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u.expect("asked for U"), svd.v_t.expect("asked for Vᵀ"));
    let mut d = Matrix3::identity();
    // A reflection is the best orthogonal map for mirrored data; force a rotation.
    if (v_t.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = v_t.transpose() * d * u.transpose();
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = ct.coords - rot * cf.coords;
    Ok(Isometry3::from_parts(Translation3::from(t), rot))
}

fn finish(
    from: &[Point3<f64>],
    to: &[Point3<f64>],
    groups: &[usize],
    transform: Isometry3<f64>,
    params: usize,
    refit: impl Fn(&[Point3<f64>], &[Point3<f64>]) -> Option<Isometry3<f64>>,
) -> RigidFit {
    let n = from.len();
    let residuals: Vec<f64> = from
        .iter()
        .zip(to)
        .map(|(a, b)| (transform * a - b).norm())
        .collect();
    let ss: f64 = residuals.iter().map(|r| r * r).sum();
    let dof = (3 * n).saturating_sub(params).max(1) as f64;
    let sigma = (ss / dof).sqrt() / (n as f64).sqrt();
    // Leave one out: a wrong target pulls the fit towards itself, so each target is judged by
    // the fit made without it, against the noise that fit shows (σ̂ per axis of the rest).
    let mut misfits = Vec::new();
    let mut ids: Vec<usize> = groups.to_vec();
    ids.sort_unstable();
    ids.dedup();
    for &g in &ids {
        let keep: Vec<usize> = (0..n).filter(|&j| groups[j] != g).collect();
        let rest_dof = (3 * keep.len()).saturating_sub(params);
        if rest_dof == 0 {
            continue;
        }
        let f: Vec<Point3<f64>> = keep.iter().map(|&j| from[j]).collect();
        let t: Vec<Point3<f64>> = keep.iter().map(|&j| to[j]).collect();
        let Some(without) = refit(&f, &t) else {
            continue;
        };
        let rest: f64 = f
            .iter()
            .zip(&t)
            .map(|(a, b)| (without * a - b).norm_squared())
            .sum();
        let sigma_rest = (rest / rest_dof as f64).sqrt();
        let r = (0..n)
            .filter(|&j| groups[j] == g)
            .map(|j| (without * from[j] - to[j]).norm())
            .fold(0.0, f64::max);
        if r > FLAG_SIGMAS * 3f64.sqrt() * sigma_rest && r > FLAG_FLOOR {
            misfits.push((g, r));
        }
    }
    RigidFit {
        transform,
        rms: (ss / n as f64).sqrt(),
        residuals,
        translation_sigma: Vector3::repeat(sigma),
        misfits,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn targets() -> Vec<Point3<f64>> {
        vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(3.0, 0.2, 0.1),
            Point3::new(0.5, 2.5, 0.3),
            Point3::new(2.8, 2.9, 1.6),
            Point3::new(1.4, 1.1, 2.2),
            Point3::new(-0.7, 1.8, 1.0),
        ]
    }

    #[test]
    fn recovers_a_transform_within_the_expected_sigma() {
        let truth = Isometry3::new(
            Vector3::new(12.0, -3.0, 0.4),
            Vector3::new(0.05, -0.02, 1.1),
        );
        let sigma = 0.001;
        let noise = Normal::new(0.0, sigma).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut errs = Vec::new();
        let mut sigmas = Vec::new();
        for _ in 0..200 {
            let to = targets();
            let from: Vec<_> = to
                .iter()
                .map(|p| truth.inverse() * p + Vector3::from_fn(|_, _| noise.sample(&mut rng)))
                .collect();
            let f = fit(&from, &to).unwrap();
            let c = centroid(&to);
            // The error of the transform where the targets are.
            errs.push((f.transform * (truth.inverse() * c) - c).norm());
            assert!(f.misfits.is_empty(), "{:?}", f.misfits);
            sigmas.push(f.translation_sigma.x);
        }
        sigmas.sort_by(f64::total_cmp);
        let median = sigmas[sigmas.len() / 2];
        assert!(
            (median - sigma / 6f64.sqrt()).abs() < 0.1 * sigma / 6f64.sqrt(),
            "{median}"
        );
        // |3-D error| at the centroid has RMS σ √3 / √n.
        let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
        let expected = sigma * 3f64.sqrt() / 6f64.sqrt();
        assert!(
            (rms - expected).abs() < 0.25 * expected,
            "{rms} vs {expected}"
        );
    }

    #[test]
    fn a_wrong_target_is_flagged_and_collinear_targets_are_refused() {
        let to = targets();
        let noise = Normal::new(0.0, 0.001).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut from: Vec<_> = to
            .iter()
            .map(|p| p + Vector3::from_fn(|_, _| noise.sample(&mut rng)))
            .collect();
        from[3] += Vector3::new(0.02, 0.0, 0.0);
        let f = fit(&from, &to).unwrap();
        assert_eq!(f.misfits.len(), 1, "{:?}", f.misfits);
        assert_eq!(f.misfits[0].0, 3);
        assert!((f.misfits[0].1 - 0.02).abs() < 0.005);

        let line: Vec<_> = (0..4)
            .map(|i| Point3::new(i as f64, 2.0 * i as f64, 0.5))
            .collect();
        assert!(matches!(
            fit(&line, &line),
            Err(RigidError::Collinear { .. })
        ));
        assert!(matches!(
            fit(&line[..2], &line[..2]),
            Err(RigidError::TooFew { .. })
        ));
        // A translation needs no spread.
        let moved: Vec<_> = line
            .iter()
            .map(|p| p + Vector3::new(1.0, 2.0, 3.0))
            .collect();
        let f = fit_translation(&line, &moved, UnitQuaternion::identity()).unwrap();
        assert!((f.transform.translation.vector - Vector3::new(1.0, 2.0, 3.0)).norm() < 1e-12);
    }
}
