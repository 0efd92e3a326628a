//! How well each judged quantity was measured: its expanded uncertainty U (k = 2, GUM), from
//! what the job knows.
//!
//! - **Range noise**: estimated from the scan itself, as the pooled spread of the points within
//!   the face's cells (a cell is 5 × 1 mm: its spread is the scanner's, not the surface's). A
//!   bin's mean then carries σ²/n for its n points.
//! - **Pose**: each station's position σ per axis (its pose's `position_sigma`: configuration or
//!   calibration). A station's translation error moves all its points alike, so it cancels in a
//!   gap measured on one station's points and in a thickness seen by one station from both
//!   sides; it enters where stations meet. A quantity `Σ c_b y_b` over bins seen by stations
//!   `s` takes `Σ_s σ_s² (Σ_b c_b w_{b,s} n̂_b)²`, with `w_{b,s}` station `s`'s share of bin
//!   `b`'s points (a bin's mean moves by each station's error times its share); a cell keeps
//!   its first station's count and one other, more than two stations in a cell count as one
//!   more station with the largest σ. Orientation errors are not modelled (the pose carries no
//!   angular σ).
//! - **Resolution**: a bin may miss the true crest or trough inside it by up to an eighth of
//!   the local second difference (the curvature over half a bin); a rectangular distribution.

use nalgebra::Vector3;

use super::straightedge::{Located, Profile, Setup};
use super::{FlatnessGrid, Half, MIXED};

pub(crate) use crate::verdict::COVERAGE_FACTOR;

impl FlatnessGrid {
    /// The range noise σ of face `f`'s points, from their spread within its cells; where no
    /// cell holds two points (a sparse scan), within blocks of cells 5 mm, then 25 mm, high,
    /// which also take in the surface's own shape there (so U errs large). NaN when no block
    /// holds two.
    pub fn noise_sigma(&self, f: usize) -> f64 {
        let c = &self.cells[f];
        let pooled = |group: usize| {
            let (mut ss, mut dof) = (0.0, 0u64);
            for iv in (0..c.nv).step_by(group) {
                for iu in 0..c.nu {
                    let (mut n, mut sum, mut sq) = (0u32, 0.0, 0.0);
                    for k in (iv..(iv + group).min(c.nv)).map(|v| v * c.nu + iu) {
                        let x = &c.cell[k];
                        n += x.count;
                        sum += x.sum;
                        sq += x.sq;
                    }
                    if n >= 2 {
                        ss += (sq - sum * sum / n as f64).max(0.0);
                        dof += u64::from(n - 1);
                    }
                }
            }
            (dof > 0).then(|| (ss / dof as f64).sqrt())
        };
        let block = (c.size[0] / c.size[1]).round().max(1.0) as usize;
        pooled(1)
            .or_else(|| pooled(block))
            .or_else(|| pooled(5 * block))
            .unwrap_or(f64::NAN)
    }

    /// A station tag's position σ; a mixed cell takes the largest of the scan layer's.
    fn sigma_of(&self, tag: u8) -> f64 {
        if tag == MIXED {
            return self
                .stations
                .iter()
                .map(|s| s.1)
                .fold(0.0, |a, b| if b.is_nan() { f64::NAN } else { a.max(b) });
        }
        self.stations.get(tag as usize).map_or(f64::NAN, |s| s.1)
    }

    /// The variance pose errors add to `Σ coefficient · (pose error of tag) · direction`, each
    /// term `(tag, coefficient, direction)` (a bin's coefficient times each station's share):
    /// a station's terms add up before squaring. [`MIXED`] stands for several stations at once
    /// and takes the largest σ (their errors add up rather than average out).
    pub(crate) fn pose_variance(&self, terms: &[(u8, f64, Vector3<f64>)]) -> f64 {
        let mut tags: Vec<u8> = terms.iter().map(|t| t.0).collect();
        tags.sort_unstable();
        tags.dedup();
        tags.into_iter()
            .map(|tag| {
                let v: Vector3<f64> = terms.iter().filter(|t| t.0 == tag).map(|t| t.2 * t.1).sum();
                self.sigma_of(tag).powi(2) * v.norm_squared()
            })
            .sum()
    }

    /// U of a gap found on face `f` along `axis`, read with `setup`.
    pub(crate) fn gap_uncertainty(
        &self,
        (f, axis): (usize, usize),
        setup: &Setup,
        at: &Located,
    ) -> f64 {
        let mut profile = Profile::default();
        self.profile((f, axis, at.lane), Half::Measure, setup, &mut profile);
        let (i, j, k) = (at.chord.i, at.chord.j, at.chord.k);
        let t = (k - i) as f64 / (j - i) as f64;
        let sigma = setup.sigma;
        let normal = self.faces.faces[f].normal.into_inner();
        let mut var = 0.0;
        let mut pose = Vec::with_capacity(3);
        for (b, c) in [(i, 1.0 - t), (j, t), (k, -1.0)] {
            let n = profile.weight[b].max(1.0);
            var += c * c * sigma * sigma / n;
            var += c * c * resolution(&profile.height, b).powi(2) / 3.0;
            pose.extend(
                profile.station[b]
                    .iter()
                    .map(|(tag, w)| (tag, c * w, normal)),
            );
        }
        var += self.pose_variance(&pose);
        COVERAGE_FACTOR * var.sqrt()
    }
}

/// How far bin `b`'s height may miss the profile's extreme inside it: the second difference
/// over its nearest measured neighbours (within 3 bins each side), scaled to half a bin
/// (`κ (h/2)² / 2` with `κ = Δ² / h²`: `|Δ²| / 8`); 0 without both neighbours.
fn resolution(height: &[Option<f64>], b: usize) -> f64 {
    let Some(y) = height[b] else { return 0.0 };
    let left = (1..=3).find_map(|d| b.checked_sub(d).and_then(|a| height[a].map(|v| (d, v))));
    let right = (1..=3).find_map(|d| height.get(b + d).copied().flatten().map(|v| (d, v)));
    let (Some((dl, yl)), Some((dr, yr))) = (left, right) else {
        return 0.0;
    };
    // The second difference at unequal spacing, in units of one bin squared.
    let (dl, dr) = (dl as f64, dr as f64);
    let second = 2.0 * (dl * yr + dr * yl - (dl + dr) * y) / (dl * dr * (dl + dr));
    second.abs() / 8.0
}
