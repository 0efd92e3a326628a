//! ACI 117's abrupt irregularities: an offset in the surface within one inch, such as the step
//! where one printed layer stands out from the next. Per face and direction, the largest
//! height difference between two measured bins of a lane at most [`ACI_ABRUPT_WITHIN`] apart,
//! chosen on one half of the points and measured on the other ([`Half`]), as the gaps are.

use nalgebra::Point3;

use super::standard::ACI_ABRUPT_WITHIN;
use super::straightedge::{Profile, Setup};
use super::uncertainty::COVERAGE_FACTOR;
use super::{Direction, FlatnessGrid, Half};

/// The largest abrupt offset on one face, one way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AbruptStep {
    /// The face, an index into [`super::PlanarFaces::faces`].
    pub face: u32,
    /// Which way the bins lie.
    pub direction: Direction,
    /// The offset, metres (never below zero).
    pub step: f64,
    /// How far apart its two bins are, metres.
    pub distance: f64,
    /// The standard's abrupt limit, metres.
    pub limit: f64,
    /// The offset's expanded uncertainty (k = 2), metres.
    pub uncertainty: f64,
    /// Its two bins, lower first along the direction, design frame.
    pub between: [Point3<f64>; 2],
}

impl AbruptStep {
    /// The verdict by `rule`.
    pub fn verdict(&self, rule: crate::verdict::DecisionRule) -> crate::verdict::Verdict {
        rule.decide(self.step, self.uncertainty, self.limit)
    }
}

/// A step found on one lane: its bins, its offset on the choosing half and on the measuring.
#[derive(Debug, Clone, Copy)]
struct Found {
    lane: usize,
    bins: [usize; 2],
    chosen: f64,
    measured: f64,
}

impl FlatnessGrid {
    /// The largest abrupt offset on face `f` along `axis`, held to `limit`; `None` where no two
    /// bins within an inch were measured by both halves.
    pub(crate) fn abrupt(
        &self,
        (f, axis): (usize, usize),
        setup: &Setup,
        limit: f64,
    ) -> Option<AbruptStep> {
        let (bin, _) = self.lane_shape(f, axis);
        let reach = ((ACI_ABRUPT_WITHIN / bin) + 1e-9).floor().max(1.0) as usize;
        let found = self
            .each_lane((f, axis), setup, |lane, choose, measure| {
                largest_offset(&choose.height, &measure.height, reach).map(
                    |(bins, chosen, measured)| Found {
                        lane,
                        bins,
                        chosen,
                        measured,
                    },
                )
            })
            .into_iter()
            .flatten()
            // The first lane's on a tie, as one lane after the other would find it.
            .fold(None::<Found>, |best, x| match best {
                Some(b) if b.chosen >= x.chosen => Some(b),
                _ => Some(x),
            })?;
        let mut profile = Profile::default();
        self.profile((f, axis, found.lane), Half::Measure, setup, &mut profile);
        let [i, j] = found.bins;
        let normal = self.faces.faces[f].normal.into_inner();
        let mut var = 0.0;
        for b in [i, j] {
            var += setup.sigma * setup.sigma / profile.weight[b].max(1.0);
        }
        let pose: Vec<_> = [(i, 1.0), (j, -1.0)]
            .into_iter()
            .flat_map(|(b, c)| {
                profile.station[b]
                    .iter()
                    .map(move |(tag, w)| (tag, c * w, normal))
            })
            .collect();
        var += self.pose_variance(&pose);
        let located = |b: usize| self.bin_point((f, axis, found.lane), b);
        Some(AbruptStep {
            face: f as u32,
            direction: if axis == 0 {
                Direction::Along
            } else {
                Direction::Across
            },
            step: found.measured,
            distance: (j - i) as f64 * bin,
            limit,
            uncertainty: COVERAGE_FACTOR * var.sqrt(),
            between: [located(i), located(j)],
        })
    }
}

/// On a lane: the two bins at most `reach` apart whose heights differ most on `choose`, with
/// that difference and the same bins' on `measure`; only bins both measured count.
fn largest_offset(
    choose: &[Option<f64>],
    measure: &[Option<f64>],
    reach: usize,
) -> Option<([usize; 2], f64, f64)> {
    let both = |b: usize| Some((choose[b]?, measure[b]?));
    let mut best: Option<([usize; 2], f64, f64)> = None;
    for i in 0..choose.len() {
        let Some((ci, mi)) = both(i) else { continue };
        for j in i + 1..(i + reach + 1).min(choose.len()) {
            let Some((cj, mj)) = both(j) else { continue };
            let chosen = (cj - ci).abs();
            if best.is_none_or(|b| chosen > b.1) {
                best = Some(([i, j], chosen, (mj - mi).abs()));
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_largest_offset_within_reach_is_chosen_on_one_half_and_read_on_the_other() {
        // A 4 mm step between bins 3 and 4 (first found of the pairs over it); 4.5 mm between
        // bins 0 and 9, out of reach.
        let choose = [
            Some(0.0),
            Some(0.0),
            None,
            Some(0.0),
            Some(0.004),
            Some(0.004),
            Some(0.004),
            Some(0.004),
            Some(0.004),
            Some(0.0045),
        ];
        let mut measure = choose;
        measure[3] = Some(0.0005);
        let (bins, chosen, measured) = largest_offset(&choose, &measure, 2).unwrap();
        assert_eq!(bins, [3, 4]);
        assert!((chosen - 0.004).abs() < 1e-15);
        assert!((measured - 0.0035).abs() < 1e-15);
        // Nothing within reach both halves measured.
        assert!(largest_offset(&[Some(0.0), None], &[Some(0.0), Some(1.0)], 1).is_none());
    }
}
