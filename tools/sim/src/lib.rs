//! A simulated print cell: a part printed layer by layer with known defects, and a
//! robot-mounted laser scanner that scans it. Pure and seeded, so a test knows the truth the
//! agent should find, and a replay gives the same points. [`run`] sends such a job to a running
//! agent over its iceoryx2 services as a robot cell would.
//!
//! A crate of its own so that the agent, which never simulates, does not link it.

#![warn(missing_docs)]

mod asbuilt;
mod cell;
mod defect_spec;
mod defects;
pub mod lines;
mod part;
mod printing;
pub mod profiler;
mod scanner;
mod spec;

pub use asbuilt::{AsBuilt, as_built, as_built_with};
pub use cell::{PlannedStation, SimError, SimEvent, SimJob, SimOutcome, run, write_stl};
pub use defect_spec::DefectSpecError;
pub use defects::{BuiltLayer, Defect, DefectKind, LayerSettings, Truth, built_layers};
pub use part::{OUTLINE_SPACING, Part, PartError, Ring, resample, signed_area2};
pub use printing::run_printing;
pub use scanner::{Scan, ScannerModel, perturb, scan, stations_around};
pub use spec::{JobSpec, JobSpecError, PartSpec, ProfilerSpec};
