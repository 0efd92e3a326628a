//! The options that say what a report judges by, shared by `inspect` and `report` (where they
//! go over the recording's `[tolerances]`).

use asbuilt_core::flatness::{DimensionsStandard, FlatnessStandard};
use asbuilt_core::verdict::{DecisionRule, LayerLimit};
use clap::Args;

/// Verdict limits, standards and the maps as PNG files.
#[derive(Args, Clone, Default)]
pub struct Judging {
    /// A verdict limit, repeatable: KIND=VALUE or KIND=VALUE@FIRST-LAST (layers), KIND one of
    /// width, top_height, position, surface, missing_area (m², or with cm2), creep; lengths in
    /// metres or with mm. Kinds left out are held to the tolerance (`report`: the recording's
    /// [tolerances]).
    #[arg(long = "limit", value_name = "KIND=VALUE[@LAYERS]")]
    pub limits: Vec<LayerLimit>,
    /// Also write every map of report.html as a PNG file into OUT/maps (for a site diary or a
    /// printed page).
    #[arg(long)]
    pub png: bool,
    /// Judge every planar face's flatness with a virtual straightedge by a standard:
    /// din18202:1..7 (DIN 18202:2019-07 Table 3; rows 5-7 walls, 1-4 floors) or aci117:A|B|C|D (ACI 117, 5 ft
    /// straightedge). `report` judges the latest scan layer, over the recording's [tolerances].
    #[arg(long, value_name = "STANDARD:ROW")]
    pub flatness: Option<FlatnessStandard>,
    /// Judge the element's dimensions (between opposite faces, and to a top seen) and each
    /// upright face's plumb by a standard: din18202 (Tables 1 and 2). `report` judges the
    /// latest scan layer, over the recording's [tolerances].
    #[arg(long, value_name = "STANDARD")]
    pub dimensions: Option<DimensionsStandard>,
    /// How the standards' verdicts weigh the measurement's expanded uncertainty U (k = 2):
    /// iso14253-1 (the default: pass only when value + U is within the limit, fail only when
    /// value - U is beyond it, inconclusive between) or simple (the value alone). `report`:
    /// over the recording's [tolerances] decision_rule.
    #[arg(long, value_name = "RULE")]
    pub decision_rule: Option<DecisionRule>,
}
