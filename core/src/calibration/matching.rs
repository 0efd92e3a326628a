//! Which measured sphere is which target. A rigid motion keeps distances, so a labelling is
//! right when the distances between measured centres equal those between their targets.

use nalgebra::Point3;

/// Assigns measured centres to targets: `result[i]` is the target of measured centre `i`, or
/// `None`. Among labellings whose pairwise distances all agree within `tolerance`, the one with
/// the most matches wins, then the smallest total disagreement. Exhaustive with pruning: for the
/// handful of targets a calibration uses.
pub fn by_distances(
    measured: &[Point3<f64>],
    targets: &[Point3<f64>],
    tolerance: f64,
) -> Vec<Option<usize>> {
    struct Search<'a> {
        m: &'a [Point3<f64>],
        t: &'a [Point3<f64>],
        tol: f64,
        current: Vec<Option<usize>>,
        used: Vec<bool>,
        best: (usize, f64, Vec<Option<usize>>),
    }
    impl Search<'_> {
        fn go(&mut self, i: usize, matched: usize, cost: f64) {
            if i == self.m.len() {
                if matched > self.best.0 || (matched == self.best.0 && cost < self.best.1) {
                    self.best = (matched, cost, self.current.clone());
                }
                return;
            }
            // Even matching every remaining centre cannot beat the best: stop.
            if matched + (self.m.len() - i) < self.best.0 {
                return;
            }
            for k in 0..self.t.len() {
                if self.used[k] {
                    continue;
                }
                let mut extra = 0.0;
                let mut ok = true;
                for j in 0..i {
                    if let Some(kj) = self.current[j] {
                        let dm = (self.m[i] - self.m[j]).norm();
                        let dt = (self.t[k] - self.t[kj]).norm();
                        let e = (dm - dt).abs();
                        if e > self.tol {
                            ok = false;
                            break;
                        }
                        extra += e;
                    }
                }
                if ok {
                    self.used[k] = true;
                    self.current[i] = Some(k);
                    self.go(i + 1, matched + 1, cost + extra);
                    self.used[k] = false;
                    self.current[i] = None;
                }
            }
            self.go(i + 1, matched, cost);
        }
    }
    let mut s = Search {
        m: measured,
        t: targets,
        tol: tolerance,
        current: vec![None; measured.len()],
        used: vec![false; targets.len()],
        best: (0, f64::INFINITY, vec![None; measured.len()]),
    };
    s.go(0, 0, 0.0);
    // A single match says nothing about identity: at least two are needed.
    if s.best.0 < 2 {
        return vec![None; measured.len()];
    }
    s.best.2
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Vector3};

    #[test]
    fn measured_centres_in_another_frame_find_their_targets() {
        let targets = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(3.0, 0.2, 0.1),
            Point3::new(0.5, 2.5, 0.3),
            Point3::new(2.8, 2.9, 1.6),
        ];
        let pose = Isometry3::new(Vector3::new(5.0, 1.0, 0.0), Vector3::new(0.0, 0.0, 2.0));
        // Seen: targets 2, 0, 3 (in that order) plus a stray sphere.
        let mut measured: Vec<_> = [2, 0, 3].iter().map(|&k| pose * targets[k]).collect();
        measured.push(Point3::new(9.0, 9.0, 9.0));
        let m = by_distances(&measured, &targets, 0.01);
        assert_eq!(m, vec![Some(2), Some(0), Some(3), None]);
    }
}
