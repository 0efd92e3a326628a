//! What the printer says it applied, layer by layer: the corrector estimates the process from
//! what was printed, not from what it advised (the cell decides whether to apply advice, and
//! how much). A layer the printer said nothing of is taken as printed as designed.

use std::collections::BTreeMap;
use std::ops::Range;

use asbuilt_protocol::LayerApplied;

use crate::stats::median;

/// Layers of one job's answers kept at most: a job's layers since the advice the next builds
/// on, with room to spare (a cell that answers for layers far ahead cannot grow it).
const MAX_LAYERS: usize = 4096;

/// The printer's answers for one job, by layer.
#[derive(Debug, Clone, Default)]
pub struct PrintedLayers {
    job: Option<u64>,
    layers: BTreeMap<u32, LayerApplied>,
}

/// What was printed over a range of layers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PrintedOver {
    /// The z offsets printed, summed over the layers (nominal where unanswered).
    pub z: f64,
    /// The median flow printed.
    pub flow: f64,
    /// The median path offset printed, x and y.
    pub path: [f64; 2],
    /// Layers of the range the printer said nothing of.
    pub unanswered: u32,
}

impl PrintedLayers {
    /// Takes an answer; one of another job starts that job's. Answers that are not valid
    /// (`LayerApplied::is_valid`) are left out; false then.
    pub fn take(&mut self, a: &LayerApplied) -> bool {
        if !a.is_valid() {
            return false;
        }
        if self.job != Some(a.job) {
            self.job = Some(a.job);
            self.layers.clear();
        }
        self.layers.insert(a.layer, *a);
        while self.layers.len() > MAX_LAYERS {
            self.layers.pop_first();
        }
        true
    }

    /// Forgets the layers below `layer` of `job`: no advice builds on them any more.
    pub fn forget_below(&mut self, job: u64, layer: u32) {
        if self.job == Some(job) {
            self.layers = self.layers.split_off(&layer);
        }
    }

    /// What was printed over `layers` of `job`.
    pub fn over(&self, job: u64, layers: Range<u32>) -> PrintedOver {
        let answer = |j: u32| {
            (self.job == Some(job))
                .then(|| self.layers.get(&j))
                .flatten()
        };
        let mut out = PrintedOver {
            z: 0.0,
            flow: 1.0,
            path: [0.0; 2],
            unanswered: 0,
        };
        let (mut flows, mut xs, mut ys) = (Vec::new(), Vec::new(), Vec::new());
        for j in layers {
            let a = match answer(j) {
                Some(a) => *a,
                None => {
                    out.unanswered += 1;
                    LayerApplied::nominal(job, j)
                }
            };
            out.z += a.z_offset;
            flows.push(a.flow);
            xs.push(a.path_offset[0]);
            ys.push(a.path_offset[1]);
        }
        out.flow = median(flows).unwrap_or(1.0);
        out.path = [median(xs).unwrap_or(0.0), median(ys).unwrap_or(0.0)];
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn applied(job: u64, layer: u32, z: f64, flow: f64) -> LayerApplied {
        LayerApplied {
            z_offset: z,
            flow,
            path_offset: [z, -z],
            ..LayerApplied::nominal(job, layer)
        }
    }

    #[test]
    fn sums_z_takes_median_flow_and_path_and_counts_the_unanswered() {
        let mut p = PrintedLayers::default();
        for j in 0..4 {
            assert!(p.take(&applied(1, j, 0.001, 0.9 + 0.01 * f64::from(j))));
        }
        let o = p.over(1, 2..6);
        assert!((o.z - 0.002).abs() < 1e-15);
        // Layers 2, 3 at 0.92 and 0.93; 4, 5 unanswered, nominal 1.0: median 0.965.
        assert!((o.flow - 0.965).abs() < 1e-12, "{o:?}");
        assert_eq!(o.unanswered, 2);
        // Another job's answers say nothing of this one.
        assert_eq!(p.over(2, 0..3).unanswered, 3);
        p.forget_below(1, 3);
        assert_eq!(p.over(1, 0..4).unanswered, 3);
    }

    #[test]
    fn a_bad_answer_is_left_out_and_memory_is_bounded() {
        let mut p = PrintedLayers::default();
        assert!(!p.take(&applied(1, 0, f64::NAN, 1.0)));
        assert!(!p.take(&applied(1, 0, 0.0, 0.0)));
        for j in 0..(MAX_LAYERS as u32 + 10) {
            p.take(&applied(1, j, 0.0, 1.0));
        }
        assert_eq!(p.layers.len(), MAX_LAYERS);
        assert_eq!(p.over(1, 0..10).unanswered, 10, "the oldest went first");
    }
}
