//! The transform chain from the scanner to the design: `T_design_scanner = T_design_base ·
//! T_base_flange · T_flange_scanner`, the outer two calibrated, the middle one each pose snapshot. `T_a_b` maps coordinates in frame `b` to frame `a`.

use asbuilt_protocol::{PoseMode, PoseSnapshot};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};

/// A pose that cannot place points.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FrameError {
    #[error(
        "rotation quaternion [x, y, z, w] = {0:?} has norm {1:.6}, not 1: send a unit quaternion, \
         scalar last"
    )]
    /// The rotation is not a unit quaternion.
    NotUnit([f64; 4], f64),
    /// A translation or rotation value is NaN or infinite.
    #[error("pose has a non-finite translation or rotation: {0:?} / {1:?}")]
    NonFinite([f64; 3], [f64; 4]),
    #[error(
        "pose mode {0} is unknown to this build (0: 6-DoF, 1: fixed orientation, 2: design-scanner)"
    )]
    /// The pose's mode is not one this build knows.
    UnknownMode(u8),
}

/// Norms this close to 1 are rounding (a controller printing four decimals); farther is an error.
const UNIT_TOLERANCE: f64 = 1e-3;

/// A rigid transform from a translation (metres) and a unit quaternion `[x, y, z, w]`.
pub fn isometry(
    translation: [f64; 3],
    rotation_xyzw: [f64; 4],
) -> Result<Isometry3<f64>, FrameError> {
    if !translation
        .iter()
        .chain(&rotation_xyzw)
        .all(|v| v.is_finite())
    {
        return Err(FrameError::NonFinite(translation, rotation_xyzw));
    }
    let [x, y, z, w] = rotation_xyzw;
    let q = Quaternion::new(w, x, y, z);
    let norm = q.norm();
    if (norm - 1.0).abs() > UNIT_TOLERANCE {
        return Err(FrameError::NotUnit(rotation_xyzw, norm));
    }
    Ok(Isometry3::from_parts(
        Translation3::from(Vector3::from(translation)),
        UnitQuaternion::new_normalize(q),
    ))
}

/// How poses from the robot become scanner poses in the design frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameChain {
    /// Calibration: robot base in the design frame.
    pub t_design_base: Isometry3<f64>,
    /// Calibration: scanner on the flange.
    pub t_flange_scanner: Isometry3<f64>,
    /// Calibration for fixed-orientation mode: the flange's orientation in the base frame, which
    /// the robot holds at every station.
    pub r_base_flange: UnitQuaternion<f64>,
}

impl Default for FrameChain {
    fn default() -> Self {
        Self {
            t_design_base: Isometry3::identity(),
            t_flange_scanner: Isometry3::identity(),
            r_base_flange: UnitQuaternion::identity(),
        }
    }
}

impl FrameChain {
    /// `T_design_scanner` for a pose snapshot, according to the snapshot's mode.
    pub fn t_design_scanner(&self, pose: &PoseSnapshot) -> Result<Isometry3<f64>, FrameError> {
        let mode = pose.mode().ok_or(FrameError::UnknownMode(pose.mode))?;
        match mode {
            PoseMode::DesignScanner => isometry(pose.translation, pose.rotation_xyzw),
            PoseMode::SixDof => {
                let t_base_flange = isometry(pose.translation, pose.rotation_xyzw)?;
                Ok(self.t_design_base * t_base_flange * self.t_flange_scanner)
            }
            PoseMode::FixedOrientation => {
                if !pose.translation.iter().all(|v| v.is_finite()) {
                    return Err(FrameError::NonFinite(pose.translation, pose.rotation_xyzw));
                }
                // The snapshot's rotation is ignored: the orientation is the calibrated one.
                let t_base_flange = Isometry3::from_parts(
                    Translation3::from(Vector3::from(pose.translation)),
                    self.r_base_flange,
                );
                Ok(self.t_design_base * t_base_flange * self.t_flange_scanner)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use std::f64::consts::FRAC_1_SQRT_2;

    fn close(a: Point3<f64>, b: [f64; 3]) {
        assert!((a - Point3::from(b)).norm() < 1e-12, "{a:?} != {b:?}");
    }

    /// 90° about z, scalar last.
    const RZ90: [f64; 4] = [0.0, 0.0, FRAC_1_SQRT_2, FRAC_1_SQRT_2];

    #[test]
    fn design_scanner_pose_is_used_as_is() {
        let mut pose = PoseSnapshot::new(1, 1, PoseMode::DesignScanner);
        pose.translation = [1.0, 2.0, 3.0];
        pose.rotation_xyzw = RZ90;
        let t = FrameChain::default().t_design_scanner(&pose).unwrap();
        // Rz(90°)·(1, 0, 0) = (0, 1, 0), then + t.
        close(t * Point3::new(1.0, 0.0, 0.0), [1.0, 3.0, 3.0]);
    }

    #[test]
    fn six_dof_chain_by_hand() {
        // Base sits 10 m along x in the design, rotated 90° about z. Scanner is 0.1 m along the
        // flange's z. The flange is at (1, 0, 2) in the base, rotated 90° about z.
        let chain = FrameChain {
            t_design_base: isometry([10.0, 0.0, 0.0], RZ90).unwrap(),
            t_flange_scanner: isometry([0.0, 0.0, 0.1], [0.0, 0.0, 0.0, 1.0]).unwrap(),
            r_base_flange: UnitQuaternion::identity(),
        };
        let mut pose = PoseSnapshot::new(1, 1, PoseMode::SixDof);
        pose.translation = [1.0, 0.0, 2.0];
        pose.rotation_xyzw = RZ90;
        let t = chain.t_design_scanner(&pose).unwrap();
        // Scanner point (1, 0, 0): in flange (1, 0, 0.1); in base Rz·(1,0,0.1) + (1,0,2) =
        // (1, 1, 2.1); in design Rz·(1,1,2.1) + (10,0,0) = (-1+10, 1, 2.1).
        close(t * Point3::new(1.0, 0.0, 0.0), [9.0, 1.0, 2.1]);
        // The scanner origin: flange (0,0,0.1) → base (1,0,2.1) → design (10, 1, 2.1).
        close(t * Point3::origin(), [10.0, 1.0, 2.1]);
    }

    #[test]
    fn fixed_orientation_ignores_the_snapshot_rotation() {
        let chain = FrameChain {
            t_design_base: isometry([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]).unwrap(),
            t_flange_scanner: isometry([0.0, 0.0, -0.2], [0.0, 0.0, 0.0, 1.0]).unwrap(),
            r_base_flange: UnitQuaternion::from_axis_angle(
                &Vector3::x_axis(),
                std::f64::consts::PI,
            ),
        };
        let mut a = PoseSnapshot::new(1, 1, PoseMode::FixedOrientation);
        a.translation = [1.0, 2.0, 3.0];
        let mut b = a;
        b.rotation_xyzw = RZ90; // whatever the controller reports
        let ta = chain.t_design_scanner(&a).unwrap();
        let tb = chain.t_design_scanner(&b).unwrap();
        assert_eq!(ta, tb);
        // Flange turned upside down (180° about x): the scanner hangs 0.2 m *above* the flange.
        close(ta * Point3::origin(), [1.0, 2.0, 3.2]);
        close(ta * Point3::new(0.0, 1.0, 0.0), [1.0, 1.0, 3.2]);
        // Between two stations only the translation changes.
        let mut c = a;
        c.translation = [4.0, 2.0, 3.0];
        let tc = chain.t_design_scanner(&c).unwrap();
        assert_eq!(tc.rotation, ta.rotation);
        close(tc * Point3::origin(), [4.0, 2.0, 3.2]);
    }

    #[test]
    fn bad_quaternions_are_errors() {
        assert!(matches!(
            isometry([0.0; 3], [0.0, 0.0, 0.0, 2.0]),
            Err(FrameError::NotUnit(_, n)) if (n - 2.0).abs() < 1e-12
        ));
        assert!(matches!(
            isometry([f64::NAN, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]),
            Err(FrameError::NonFinite(..))
        ));
        // Four printed decimals are accepted and normalised.
        let printed = (FRAC_1_SQRT_2 * 1e4).round() / 1e4;
        let t = isometry([0.0; 3], [0.0, 0.0, printed, printed]).unwrap();
        assert!((t.rotation.quaternion().norm() - 1.0).abs() < 1e-15);
        let mut pose = PoseSnapshot::new(1, 1, PoseMode::SixDof);
        pose.mode = 7;
        assert_eq!(
            FrameChain::default().t_design_scanner(&pose),
            Err(FrameError::UnknownMode(7))
        );
    }
}
