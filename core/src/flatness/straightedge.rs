//! The straightedge laid lane by lane on a face: each lane's profile from the cells, every
//! position the straightedge can rest in ([`super::each_chord`]), and the one that governs the
//! face's verdict, judged at the distance between its supports.

use nalgebra::Point3;
use rayon::prelude::*;

use super::{BLOCK, FlatnessGrid, FlatnessStandard, Half, LANE, MIN_FILLED, MIXED, chords::Chord};

/// A bin's length along the layers, metres.
pub const BIN_ALONG: f64 = 0.01;
/// The least distance from its bin's median cell at which a cell is left out, metres.
const OUTLIER_FLOOR: f64 = 0.001;

/// A lane's profile: per bin along the straightedge, the mean of the lane's points there
/// without the cells far from the median cell (a stray return, a mixed pixel at an edge), the
/// points behind it and the stations that saw them with their shares ([`Shares`]). Across the layers
/// each height is then a local quadratic's ([`smooth_across`]), and `weight` the points a
/// plain mean with the same noise would take.
#[derive(Debug, Clone, Default)]
pub struct Profile {
    pub height: Vec<Option<f64>>,
    pub points: Vec<u32>,
    pub weight: Vec<f64>,
    pub station: Vec<Shares>,
}

/// The stations behind a bin's mean and their shares of its points (summing to 1): a
/// station's pose error moves the mean by its share of it. Beyond three stations the rest
/// count as [`MIXED`] (one more station with the largest σ).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Shares {
    share: [(u8, f64); 3],
    len: u8,
}

impl Shares {
    /// Adds `weight` to `tag`'s share.
    fn add(&mut self, tag: u8, weight: f64) {
        if weight <= 0.0 {
            return;
        }
        let used = &mut self.share[..self.len as usize];
        if let Some(s) = used.iter_mut().find(|s| s.0 == tag) {
            s.1 += weight;
        } else if (self.len as usize) < self.share.len() {
            self.share[self.len as usize] = (tag, weight);
            self.len += 1;
        } else {
            // Full: the last becomes the rest.
            let last = &mut self.share[self.share.len() - 1];
            *last = (MIXED, last.1 + weight);
        }
    }

    /// Each station with its share, the shares summing to 1.
    pub fn iter(&self) -> impl Iterator<Item = (u8, f64)> + '_ {
        let total: f64 = self.share[..self.len as usize].iter().map(|s| s.1).sum();
        self.share[..self.len as usize]
            .iter()
            .map(move |&(t, w)| (t, w / total))
    }
}

/// What every lane of a face, one way, is read with: worked out once per face and direction.
#[derive(Debug, Clone)]
pub(crate) struct Setup {
    /// The face's range noise σ ([`FlatnessGrid::noise_sigma`]).
    pub sigma: f64,
    /// How far from its bin's median cell a cell is left out.
    pub outlier: f64,
    /// Each cell row's level ([`FlatnessGrid::row_levels`]).
    pub levels: Vec<f64>,
}

/// A lane's governing position (with its gap over its limit) and, per class of the table's
/// distances, its deepest position with the supports within that distance and beyond the
/// one before.
struct LaneBest {
    governing: Option<(f64, Located)>,
    by_class: Vec<Option<Located>>,
}

/// A straightedge position found on a face, with where it lies.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Located {
    /// The position, chosen on the [`Half::Choose`] points (its `gap` is theirs).
    pub chord: Chord,
    /// The gap at that position measured on the [`Half::Measure`] points, metres, never below
    /// zero.
    pub gap: f64,
    /// The lane (index across the straightedge, in lanes).
    pub lane: usize,
    pub support_distance: f64,
    pub at: Point3<f64>,
    pub supports: [Point3<f64>; 2],
}

impl FlatnessGrid {
    /// A bin's length along the straightedge and the cells per lane across it, for `axis`
    /// (0: along `u`, where a bin is [`BIN_ALONG`] long; across the layers a bin is a cell).
    pub(crate) fn lane_shape(&self, f: usize, axis: usize) -> (f64, usize) {
        let c = &self.cells[f];
        let across = 1 - axis;
        let lane_cells = (LANE / c.size[across]).round().max(1.0) as usize;
        (
            c.size[axis] * self.cells_per_bin(f, axis) as f64,
            lane_cells,
        )
    }

    /// Cells merged into a bin along the straightedge.
    fn cells_per_bin(&self, f: usize, axis: usize) -> usize {
        if axis == 0 {
            (BIN_ALONG / self.cells[f].size[0]).round().max(1.0) as usize
        } else {
            1
        }
    }

    /// Cells along the straightedge and across it on face `f` for `axis`.
    fn along_across(&self, f: usize, axis: usize) -> (usize, usize) {
        let c = &self.cells[f];
        if axis == 0 {
            (c.nu, c.nv)
        } else {
            (c.nv, c.nu)
        }
    }

    /// Lanes on face `f` for `axis`.
    pub(crate) fn lanes(&self, f: usize, axis: usize) -> usize {
        let c = &self.cells[f];
        let (_, kl) = self.lane_shape(f, axis);
        ([c.nv, c.nu][axis] / kl).max(1)
    }

    /// How face `f`'s lanes along `axis` are read.
    pub(crate) fn setup(&self, f: usize, axis: usize) -> Setup {
        let sigma = self.noise_sigma(f);
        Setup {
            sigma,
            outlier: (3.0 * sigma).max(OUTLIER_FLOOR),
            levels: self.row_levels(f, axis),
        }
    }

    /// Each row of face `f`'s cells (along the layers) at its mean height, to be taken off its
    /// cells for a profile along the layers: a lane 30 mm wide spans several layer ribs, and
    /// which rows the scan lines happen to fill changes along a lane; less each row's level, a
    /// rib's shape across the layers no longer shows up along them. Zeros across the layers.
    pub(crate) fn row_levels(&self, f: usize, axis: usize) -> Vec<f64> {
        let c = &self.cells[f];
        if axis != 0 {
            return vec![0.0; c.nv];
        }
        (0..c.nv)
            .map(|iv| {
                let row = iv * c.nu..(iv + 1) * c.nu;
                let n: u32 = c.cell[row.clone()].iter().map(|x| x.count).sum();
                let sum: f64 = c.cell[row].iter().map(|x| x.sum).sum();
                if n > 0 { sum / n as f64 } else { 0.0 }
            })
            .collect()
    }

    /// The profile of lane `lane` on face `f` along `axis` from the points in `half`, each cell
    /// less its row's level and cells `setup.outlier` or farther from their bin's median cell
    /// left out, into `out`.
    pub(crate) fn profile(
        &self,
        (f, axis, lane): (usize, usize, usize),
        half: Half,
        setup: &Setup,
        out: &mut Profile,
    ) {
        let c = &self.cells[f];
        let (outlier, levels) = (setup.outlier, &setup.levels);
        let level = |k: usize| levels[k / c.nu];
        let (_, kl) = self.lane_shape(f, axis);
        let kb = self.cells_per_bin(f, axis);
        let (along, across) = self.along_across(f, axis);
        // The last lane takes the face's remainder: a narrow strip at the edge would be judged
        // on fewer points than the rest.
        let lane_end = if lane + 1 >= self.lanes(f, axis) {
            across
        } else {
            (lane + 1) * kl
        };
        out.height.clear();
        out.points.clear();
        out.station.clear();
        let mut means: Vec<f64> = Vec::with_capacity(kl);
        let mut ks: Vec<usize> = Vec::with_capacity(kl);
        for b in 0..along.div_ceil(kb) {
            means.clear();
            ks.clear();
            for a in b * kb..((b + 1) * kb).min(along) {
                for l in lane * kl..lane_end {
                    let k = if axis == 0 {
                        l * c.nu + a
                    } else {
                        a * c.nu + l
                    };
                    if let Some(m) = c.mean_of(k, half) {
                        means.push(m - level(k));
                        ks.push(k);
                    }
                }
            }
            let Some(median) = median_in_place(&mut means) else {
                out.height.push(None);
                out.points.push(0);
                out.station.push(Shares::default());
                continue;
            };
            let (mut n, mut sum, mut shares) = (0u32, 0.0, Shares::default());
            for &k in &ks {
                let (s, m) = c.sum_count(k, half);
                if (s / m as f64 - level(k) - median).abs() > outlier {
                    continue;
                }
                n += m;
                sum += s - level(k) * m as f64;
                for (tag, w) in c.cell[k].shares() {
                    shares.add(tag, w * m as f64);
                }
            }
            out.height.push(Some(sum / n as f64));
            out.points.push(n);
            out.station.push(shares);
        }
        // A bin that caught the end of a scan line holds a point or two where its neighbours
        // hold a line's worth: its noise, not the surface, would hold the straightedge up. The
        // measuring half holds nothing up (the positions are chosen on the other), so it keeps
        // every bin it has a point in.
        if half != Half::Measure {
            let mut counts: Vec<u32> = out.points.iter().copied().filter(|&n| n > 0).collect();
            let typical = median_count(&mut counts);
            let least = (2 * typical / 3).max(3).min(typical.max(1));
            for (h, &n) in out.height.iter_mut().zip(&out.points) {
                if n < least {
                    *h = None;
                }
            }
        }
        out.weight.clear();
        out.weight.extend(out.points.iter().map(|&n| n as f64));
        if axis == 1 {
            smooth_across(out);
        }
    }

    /// On face `f` along `axis`: the straightedge position that governs (the largest gap for
    /// its limit at the distance between its supports), and per table distance the deepest gap
    /// with its supports at most that far apart, each chosen on one half of the points and
    /// measured on the other ([`Half`]). `None` where no position counts.
    pub(crate) fn straightedge(
        &self,
        (f, axis): (usize, usize),
        setup: &Setup,
        standard: &FlatnessStandard,
    ) -> Option<(Located, Vec<Option<Located>>)> {
        let (bin, _) = self.lane_shape(f, axis);
        let spans = standard.spans();
        let max_support = standard.max_support();
        let max_bins = if max_support.is_finite() {
            (max_support / bin + 1e-9).floor() as usize
        } else {
            usize::MAX
        };
        let block = (BLOCK / bin).round().max(1.0) as usize;
        // Per distance between the supports, in bins: the limit there, and the first of the
        // table's distances it is within (a chord counts for that one and every longer one).
        let (along, _) = self.along_across(f, axis);
        let bins = along.div_ceil(self.cells_per_bin(f, axis));
        let reach = bins.min(max_bins);
        let limit_at: Vec<f64> = (0..=reach)
            .map(|k| standard.limit(k as f64 * bin))
            .collect();
        let class_at: Vec<Option<usize>> = (0..=reach)
            .map(|k| spans.iter().position(|s| k as f64 * bin <= s + 1e-9))
            .collect();
        // Lanes are independent: read side by side, folded in lane order (the same positions
        // as one after the other).
        let lanes: Vec<LaneBest> = self.each_lane((f, axis), setup, |lane, choose, measure| {
            let mut best = LaneBest {
                governing: None,
                by_class: vec![None; spans.len()],
            };
            super::each_chord(&choose.height, max_bins, block, MIN_FILLED, |chord| {
                // A position counts where both halves measured its supports and its
                // deepest bin.
                let Some(gap) = measured_gap(chord, &measure.height) else {
                    return;
                };
                let k = chord.j - chord.i;
                let ratio = chord.gap / limit_at[k];
                let located = || self.locate((f, axis, lane), chord, gap, k as f64 * bin);
                if best.governing.as_ref().is_none_or(|g| ratio > g.0) {
                    best.governing = Some((ratio, located()));
                }
                if let Some(c) = class_at[k] {
                    let b = &mut best.by_class[c];
                    if b.is_none_or(|b| chord.gap > b.chord.gap) {
                        *b = Some(located());
                    }
                }
            });
            best
        });
        let mut governing: Option<(f64, Located)> = None;
        let mut by_span: Vec<Option<Located>> = vec![None; spans.len()];
        for lane in lanes {
            if let Some(g) = lane.governing
                && governing.as_ref().is_none_or(|best| g.0 > best.0)
            {
                governing = Some(g);
            }
            // A chord within the table's distance c counts for c and every longer one.
            for (c, found) in lane.by_class.into_iter().enumerate() {
                let Some(found) = found else { continue };
                for best in &mut by_span[c..] {
                    if best.is_none_or(|b| found.chord.gap > b.chord.gap) {
                        *best = Some(found);
                    }
                }
            }
        }
        governing.map(|g| (g.1, by_span))
    }

    /// `visit` on every lane of face `f` along `axis` with its choosing and measuring halves'
    /// profiles, lanes side by side, the results in lane order.
    pub(crate) fn each_lane<T: Send>(
        &self,
        (f, axis): (usize, usize),
        setup: &Setup,
        visit: impl Fn(usize, &Profile, &Profile) -> T + Sync,
    ) -> Vec<T> {
        (0..self.lanes(f, axis))
            .into_par_iter()
            .map_init(
                || (Profile::default(), Profile::default()),
                |(choose, measure), lane| {
                    self.profile((f, axis, lane), Half::Choose, setup, choose);
                    self.profile((f, axis, lane), Half::Measure, setup, measure);
                    visit(lane, choose, measure)
                },
            )
            .collect()
    }

    /// Where a position on lane `lane` of face `f` along `axis` lies, design frame, with its
    /// measured `gap`.
    fn locate(
        &self,
        (f, axis, lane): (usize, usize, usize),
        chord: Chord,
        gap: f64,
        d: f64,
    ) -> Located {
        let point = |b: usize| self.bin_point((f, axis, lane), b);
        Located {
            chord,
            gap,
            lane,
            support_distance: d,
            at: point(chord.k),
            supports: [point(chord.i), point(chord.j)],
        }
    }

    /// The centre of bin `b` of lane `lane` on face `f` along `axis`, design frame.
    pub(crate) fn bin_point(
        &self,
        (f, axis, lane): (usize, usize, usize),
        b: usize,
    ) -> Point3<f64> {
        let face = &self.faces.faces[f];
        let (bin, kl) = self.lane_shape(f, axis);
        let across = self.cells[f].size[1 - axis] * kl as f64 * (lane as f64 + 0.5);
        let along = (b as f64 + 0.5) * bin;
        let (u, v) = if axis == 0 {
            (along, across)
        } else {
            (across, along)
        };
        face.point(face.extent[0][0] + u, face.extent[1][0] + v)
    }
}

/// The median of nonzero bin counts (the lower middle), 0 when none.
fn median_count(v: &mut [u32]) -> u32 {
    if v.is_empty() {
        return 0;
    }
    let mid = (v.len() - 1) / 2;
    *v.select_nth_unstable(mid).1
}

/// The median of `v`, reordering it; `None` when empty.
fn median_in_place(v: &mut [f64]) -> Option<f64> {
    let n = v.len();
    if n == 0 {
        return None;
    }
    v.sort_unstable_by(f64::total_cmp);
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// Bins either side of a bin whose points a height across the layers is fitted to.
const SMOOTH_REACH: usize = 3;

/// Each bin of a profile across the layers (1 mm bins, a few points each) as the value at its
/// centre of a quadratic fitted by least squares, weighted by points, to the measured bins
/// within [`SMOOTH_REACH`] of it (a Savitzky-Golay filter over uneven bins): noise falls to
/// about a third of its variance while a rib of 10 mm pitch keeps 94 % of its depth (the
/// filter's response at a tenth of a cycle per bin), a quadratic's crest all of it. A bin with
/// fewer than three measured bins in reach keeps its mean. `weight` becomes the points a mean of
/// the same variance would take (`1 / (XᵀWX)⁻¹₀₀`).
fn smooth_across(profile: &mut Profile) {
    let raw = profile.height.clone();
    for b in 0..raw.len() {
        if raw[b].is_none() {
            continue;
        }
        let mut normal = nalgebra::Matrix3::<f64>::zeros();
        let mut rhs = nalgebra::Vector3::<f64>::zeros();
        let mut used = 0;
        let from = b.saturating_sub(SMOOTH_REACH);
        let reach = &raw[from..(b + SMOOTH_REACH + 1).min(raw.len())];
        for (a, y) in reach.iter().enumerate().map(|(i, y)| (from + i, y)) {
            let Some(y) = *y else { continue };
            let x = a as f64 - b as f64;
            let row = nalgebra::Vector3::new(1.0, x, x * x);
            let w = profile.points[a] as f64;
            normal += row * row.transpose() * w;
            rhs += row * (w * y);
            used += 1;
        }
        if used < 3 {
            continue;
        }
        let Some(inverse) = normal.try_inverse() else {
            continue;
        };
        let fit = inverse * rhs;
        profile.height[b] = Some(fit[0]);
        profile.weight[b] = 1.0 / inverse[(0, 0)];
    }
}

/// `chord`'s gap read on `height` (the measuring half's profile), never below zero; `None`
/// where `height` lacks one of its three bins.
fn measured_gap(chord: Chord, height: &[Option<f64>]) -> Option<f64> {
    let (a, b, y) = (height[chord.i]?, height[chord.j]?, height[chord.k]?);
    let t = (chord.k - chord.i) as f64 / (chord.j - chord.i) as f64;
    Some(((1.0 - t) * a + t * b - y).max(0.0))
}
