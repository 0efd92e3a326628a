//! A job's report: the sections `report.json` holds (per station, overall, per layer band, the
//! findings), the offline deviation suite that fills them beside C2M (`suite`: C2C, coverage
//! and M3C2 through core's scan-layer pipeline, two-cloud M3C2, layer tables), the summary
//! table, and `report.html`, one page that opens without a network. `asbuilt inspect` and
//! `asbuilt report` write it; the computations are asbuilt-core's.

#![warn(missing_docs)]

mod assessment;
pub mod export;
pub mod flatness;
mod history;
pub mod html;
pub mod maps;
mod markup;
mod sections;
mod short;
pub mod suite;

pub use assessment::{
    Assessment, Change, Item, ItemKind, LayerHistory, LayerScan, LayerVerdict, LimitsSection,
    ScanLayerVerdicts, StationVerdict, VerdictCounts, assess, job_verdicts,
};
pub use sections::*;
