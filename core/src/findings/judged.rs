//! What the findings made of each design sample: the maps paint a sample's measured deviation,
//! or missing material, only where the findings judged it so; the rest is "not judged".

use nalgebra::Point3;

use super::{FindingParams, missing_areas, pose_of, reach, sample_count, usable_core_points};
use crate::coverage::SampleOutcome;
use crate::m3c2::streaming::CoreResult;

/// A design sample as the findings judged it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Judged {
    /// Its M3C2 distance counts in the findings.
    Measured,
    /// It lies in a missing area the findings count.
    Missing,
    /// Left out of the findings: within reach of a sharp design edge, on a face no station saw,
    /// without a distance, or in a patch of missing samples too small to count.
    #[default]
    NotJudged,
}

/// Each sample's judgement, by sample number, from the same inputs as [`super::find`] and by
/// its rules: the core points it uses, and the missing areas it counts.
pub fn judged(
    m3c2: &[CoreResult],
    coverage: &[SampleOutcome],
    sharp_edges: &[[Point3<f64>; 2]],
    area_per_sample: f64,
    p: &FindingParams,
    pose_sigma: f64,
) -> Vec<Judged> {
    let samples = sample_count(m3c2, coverage);
    let reach = reach(p, pose_of(pose_sigma));
    let usable = usable_core_points(m3c2, coverage, sharp_edges, samples, reach);
    let mut out = vec![Judged::NotJudged; samples];
    for (r, &u) in m3c2.iter().zip(&usable) {
        if u {
            out[r.sample as usize] = Judged::Measured;
        }
    }
    for group in missing_areas(m3c2, coverage, samples, area_per_sample, p) {
        for (sample, _) in group {
            out[sample as usize] = Judged::Missing;
        }
    }
    out
}
