//! Sphere-target calibration: find spheres of known radius in scans, fit their centres, and
//! estimate the rigid transform that carries measured centres onto known ones.
//!
//! - `sphere`: detection (candidate centres from local normals, scored on a subsampled cloud)
//!   and a geometric least-squares fit of the centre with the radius fixed, with the residual and
//!   the centre's σ.
//! - `rigid`: the closed-form least-squares transform (Kabsch/Horn via SVD), or the translation
//!   alone when the orientation is fixed, with residuals per target, the translation's σ and a
//!   leave-one-out test that names a target that does not fit.
//! - `matching`: which detected sphere is which target, from the distances between them,
//!   which a rigid motion keeps.

pub mod matching;
pub mod rigid;
pub mod sphere;
