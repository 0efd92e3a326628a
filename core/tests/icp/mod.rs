//! Point-to-plane ICP against the design (Chen and Medioni 1992), with a Huber kernel.
//!
//! asbuilt never registers with it: the robot's pose places every scan. It exists to show what
//! registration would do to the inspection: ICP moves the scan until its deviations are as
//! small as possible, so real defects leak into the recovered transform.

use nalgebra::{Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6};
use rayon::prelude::*;

use asbuilt_core::c2m::{C2mIndex, Cursor};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IcpParams {
    pub max_iterations: u32,
    /// Residuals beyond this weigh `k / |r|` instead of 1 (Huber), metres.
    pub huber_k: f64,
    /// Stop when an update moves by less than this (translation in metres plus rotation in
    /// radians). Correspondences switching between faces keep steps of about 1e-7 going
    /// forever, so ask for no less than a micrometre.
    pub tolerance: f64,
}

impl Default for IcpParams {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            huber_k: 0.002,
            tolerance: 1e-6,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IcpResult {
    /// Maps the input points onto the design: `p_design = transform · p`.
    pub transform: Isometry3<f64>,
    /// Root mean square of the point-to-plane residuals at the result, metres.
    pub rms: f64,
    pub iterations: u32,
    pub converged: bool,
    /// Points with a design surface within the index's maximum distance at the result.
    pub correspondences: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum IcpError {
    #[error(
        "ICP found {0} points within the maximum distance of the design; at least 6 are needed: \
         check the starting pose"
    )]
    TooFewCorrespondences(usize),
    #[error(
        "ICP's normal equations are singular: the points do not constrain all six degrees of freedom (a plane, a line)"
    )]
    Degenerate,
}

#[derive(Clone, Copy)]
struct Normal6 {
    a: Matrix6<f64>,
    b: Vector6<f64>,
    r2: f64,
    n: usize,
}

impl Normal6 {
    fn zero() -> Self {
        Self {
            a: Matrix6::zeros(),
            b: Vector6::zeros(),
            r2: 0.0,
            n: 0,
        }
    }

    fn add(mut self, o: Self) -> Self {
        self.a += o.a;
        self.b += o.b;
        self.r2 += o.r2;
        self.n += o.n;
        self
    }
}

/// Registers `points` to the design from `initial`. Correspondences are the closest design
/// points within the index's maximum distance, so that distance is the capture range.
pub fn register(
    design: &C2mIndex,
    points: &[Point3<f64>],
    initial: Isometry3<f64>,
    params: &IcpParams,
) -> Result<IcpResult, IcpError> {
    let mut t = initial;
    let mut iterations = 0;
    let mut converged = false;
    loop {
        let sums = accumulate(design, points, &t, params.huber_k);
        if sums.n < 6 {
            return Err(IcpError::TooFewCorrespondences(sums.n));
        }
        if iterations == params.max_iterations || converged {
            return Ok(IcpResult {
                transform: t,
                rms: (sums.r2 / sums.n as f64).sqrt(),
                iterations,
                converged,
                correspondences: sums.n,
            });
        }
        let x = sums
            .a
            .cholesky()
            .ok_or(IcpError::Degenerate)?
            .solve(&sums.b);
        let w = Vector3::new(x[0], x[1], x[2]);
        let step = Isometry3::from_parts(
            Translation3::new(x[3], x[4], x[5]),
            UnitQuaternion::from_scaled_axis(w),
        );
        t = step * t;
        iterations += 1;
        converged = w.norm() + Vector3::new(x[3], x[4], x[5]).norm() < params.tolerance;
    }
}

/// The weighted normal equations of the linearised residuals
/// `r + (p × n) · ω + n · t` at the current transform.
fn accumulate(design: &C2mIndex, points: &[Point3<f64>], t: &Isometry3<f64>, k: f64) -> Normal6 {
    points
        .par_chunks(4096)
        .map(|chunk| {
            let mut s = Normal6::zero();
            let mut cursor = Cursor::default();
            for p in chunk {
                let q = t * p;
                let Some(c) = design.query(&q, &mut cursor) else {
                    continue;
                };
                let n = design.face_normal(c.triangle);
                let r = (q - c.point).dot(&n);
                let w = if r.abs() <= k { 1.0 } else { k / r.abs() };
                let pn = q.coords.cross(&n);
                let j = Vector6::new(pn.x, pn.y, pn.z, n.x, n.y, n.z);
                s.a += w * j * j.transpose();
                s.b -= w * r * j;
                s.r2 += r * r;
                s.n += 1;
            }
            s
        })
        .reduce(Normal6::zero, Normal6::add)
}

#[cfg(test)]
mod tests {
    use super::*;
    use asbuilt_core::c2m::C2mParams;
    use asbuilt_core::design::shapes;
    use asbuilt_core::sampling::DesignSamples;

    #[test]
    fn recovers_a_known_offset_of_a_box() {
        let d = shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.6, 0.4));
        let index = C2mIndex::build(&d, C2mParams::within(0.1)).unwrap();
        let pts = DesignSamples::generate(&d, 0.01, 4).unwrap().points;
        let truth = Isometry3::new(
            Vector3::new(0.01, -0.02, 0.015),
            Vector3::new(0.01, -0.02, 0.03),
        );
        // Points displaced by the inverse: ICP must find `truth` to put them back.
        let moved: Vec<_> = pts.iter().map(|p| truth.inverse() * p).collect();
        let r = register(&index, &moved, Isometry3::identity(), &IcpParams::default()).unwrap();
        assert!(r.converged, "{r:?}");
        let err = r.transform * truth.inverse();
        assert!(err.translation.vector.norm() < 1e-7, "{r:?}");
        assert!(err.rotation.angle() < 1e-7, "{r:?}");
        assert!(r.rms < 1e-7);
        assert_eq!(r.correspondences, moved.len());
    }

    #[test]
    fn a_plane_alone_is_degenerate() {
        let d = shapes::sheet(1.0, 0.0, 4);
        let index = C2mIndex::build(&d, C2mParams::default()).unwrap();
        let pts = DesignSamples::generate(&d, 0.05, 4).unwrap().points;
        assert!(matches!(
            register(&index, &pts, Isometry3::identity(), &IcpParams::default()),
            Err(IcpError::Degenerate)
        ));
        let far: Vec<_> = pts
            .iter()
            .map(|p| p + Vector3::new(0.0, 0.0, 1.0))
            .collect();
        assert!(matches!(
            register(&index, &far, Isometry3::identity(), &IcpParams::default()),
            Err(IcpError::TooFewCorrespondences(0))
        ));
    }
}
