//! A simulated print cell: a part printed layer by layer with known defects, and a
//! robot-mounted laser scanner that scans it. Pure and seeded, so a test knows the truth the
//! agent should find, and a replay gives the same points.

mod asbuilt;
mod defects;
mod part;
mod scanner;

pub use asbuilt::{AsBuilt, as_built};
pub use defects::{Defect, Truth};
pub use part::{OUTLINE_SPACING, Part, PartError, Ring, resample, signed_area2};
pub use scanner::{Scan, ScannerModel, perturb, scan, stations_around};
