//! What the findings made of each design sample: the maps paint a sample's measured deviation,
//! or missing material, only where the findings judged it so; the rest is "not judged".

use nalgebra::Point3;

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

/// Each of `samples` samples' judgement, by sample number: the core points the findings use
/// (`usable`) and the missing areas they count.
pub(super) fn judgement(
    samples: usize,
    m3c2: &[CoreResult],
    usable: &[bool],
    missing: &[Vec<(u32, Point3<f64>)>],
) -> Vec<Judged> {
    let mut out = vec![Judged::NotJudged; samples];
    for (r, &u) in m3c2.iter().zip(usable) {
        if u {
            out[r.sample as usize] = Judged::Measured;
        }
    }
    for &(sample, _) in missing.iter().flatten() {
        out[sample as usize] = Judged::Missing;
    }
    out
}
