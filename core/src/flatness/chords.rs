//! Every position a straightedge can rest in on a profile, as DIN 18202 lays it: on two high
//! points of the surface with nothing higher between them. The gap is measured at the deepest
//! point under it and judged at the distance between the two supports, not at the
//! straightedge's length.
//!
//! A pair of measured points `(i, j)` can hold the straightedge exactly when every point between
//! them lies on or below the line through them, that is when the slope from `i` to `j` is at
//! least the slope from `i` to every point between (`j` is visible from `i` over the profile).
//! Walking `j` to the right of each `i` with the running maximum slope finds every such pair in
//! O(n²); the deepest point under each is a tangent query on the lower convex hull of the points
//! between, kept as `j` advances (O(log n) a pair).

/// A straightedge's position: resting on bins `i` and `j`, deepest `gap` at bin `k`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Chord {
    /// The left support's bin.
    pub i: usize,
    /// The right support's bin.
    pub j: usize,
    /// The deepest point's bin, strictly between.
    pub k: usize,
    /// How far bin `k` lies below the line from `i` to `j`, in the profile's height unit.
    pub gap: f64,
}

/// Every straightedge position on `profile` (heights per bin, `None` where unmeasured) whose
/// supports are at most `max_bins` apart and whose blocks of `block` bins between the supports
/// are measured to at least `min_filled`, handed to `visit`.
pub fn each_chord(
    profile: &[Option<f64>],
    max_bins: usize,
    block: usize,
    min_filled: f64,
    mut visit: impl FnMut(Chord),
) {
    let block = block.max(1);
    // Measured blocks, as a prefix count: a straightedge over a hole rests on nothing seen.
    let blocks = profile.len().div_ceil(block);
    let mut filled = vec![0u32; blocks + 1];
    for b in 0..blocks {
        let any = profile[b * block..((b + 1) * block).min(profile.len())]
            .iter()
            .any(Option::is_some);
        filled[b + 1] = filled[b] + u32::from(any);
    }
    let fill_ok = |i: usize, j: usize| {
        let (a, b) = (i / block, j / block + 1);
        (filled[b] - filled[a]) as f64 >= min_filled * (b - a) as f64
    };
    // The highest measured point from each bin on: once the steepest slope from `i` so far is
    // not negative and even that point lies below its line, nothing farther can hold the
    // straightedge (every later slope is smaller), and the walk from `i` stops.
    let mut highest = vec![f64::NEG_INFINITY; profile.len() + 1];
    for b in (0..profile.len()).rev() {
        highest[b] = profile[b].map_or(highest[b + 1], |y| y.max(highest[b + 1]));
    }
    let mut hull: Vec<(f64, f64)> = Vec::new();
    let mut hull_at: Vec<usize> = Vec::new();
    for (i, yi) in profile.iter().enumerate() {
        let Some(yi) = *yi else { continue };
        hull.clear();
        hull_at.clear();
        let mut steepest = f64::NEG_INFINITY;
        let end = profile
            .len()
            .min(i.saturating_add(max_bins).saturating_add(1));
        for (j, yj) in profile.iter().enumerate().take(end).skip(i + 1) {
            if steepest >= 0.0 && highest[j] - yi < steepest * (j - i) as f64 {
                break;
            }
            let Some(yj) = *yj else { continue };
            let slope = (yj - yi) / (j - i) as f64;
            if slope >= steepest && !hull.is_empty() && fill_ok(i, j) {
                let (k, lowest) = lowest_under(&hull, &hull_at, slope);
                // The line at x is yi + slope (x - i); the hull's least y - slope x is its
                // deepest point below it.
                let gap = yi - slope * i as f64 - lowest;
                visit(Chord { i, j, k, gap });
            }
            steepest = steepest.max(slope);
            push_lower(&mut hull, &mut hull_at, (j as f64, yj), j);
        }
    }
}

/// Adds a point to the right end of a lower convex hull (Andrew's monotone chain).
fn push_lower(hull: &mut Vec<(f64, f64)>, at: &mut Vec<usize>, p: (f64, f64), index: usize) {
    while hull.len() >= 2 {
        let (x1, y1) = hull[hull.len() - 2];
        let (x2, y2) = hull[hull.len() - 1];
        // Drop the middle point when it lies on or above the line from x1 to p.
        if (x2 - x1) * (p.1 - y1) - (y2 - y1) * (p.0 - x1) <= 0.0 {
            hull.pop();
            at.pop();
        } else {
            break;
        }
    }
    hull.push(p);
    at.push(index);
}

/// The hull vertex with the least `y - slope·x` (where a line of `slope` touches the hull from
/// below), as its bin and that value.
fn lowest_under(hull: &[(f64, f64)], at: &[usize], slope: f64) -> (usize, f64) {
    // The hull's edge slopes increase: the touching vertex is the first whose next edge climbs
    // faster than `slope`.
    let (mut lo, mut hi) = (0, hull.len() - 1);
    while lo < hi {
        let e = (lo + hi) / 2;
        let (a, b) = (hull[e], hull[e + 1]);
        if (b.1 - a.1) / (b.0 - a.0) < slope {
            lo = e + 1;
        } else {
            hi = e;
        }
    }
    let v = lo;
    let (x, y) = hull[v];
    (at[v], y - slope * x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Every chord by brute force: each pair with every point between on or below its line,
    /// and its deepest gap.
    fn brute(p: &[Option<f64>], max_bins: usize) -> Vec<Chord> {
        let mut out = Vec::new();
        for i in 0..p.len() {
            for j in i + 2..p.len().min(i + max_bins + 1) {
                let (Some(yi), Some(yj)) = (p[i], p[j]) else {
                    continue;
                };
                let line = |x: usize| yi + (yj - yi) * (x - i) as f64 / (j - i) as f64;
                let between: Vec<(usize, f64)> =
                    (i + 1..j).filter_map(|k| p[k].map(|y| (k, y))).collect();
                if between.is_empty() || between.iter().any(|&(k, y)| y > line(k) + 1e-12) {
                    continue;
                }
                let (k, gap) = between
                    .iter()
                    .map(|&(k, y)| (k, line(k) - y))
                    .fold((0, f64::NEG_INFINITY), |a, b| if b.1 > a.1 { b } else { a });
                out.push(Chord { i, j, k, gap });
            }
        }
        out
    }

    #[test]
    fn every_resting_position_and_its_deepest_gap_as_brute_force_finds_them() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for _ in 0..300 {
            let n = rng.random_range(3..40);
            let p: Vec<Option<f64>> = (0..n)
                .map(|_| rng.random_bool(0.8).then(|| rng.random_range(-1.0..1.0)))
                .collect();
            let max_bins = rng.random_range(2..45);
            let mut got = Vec::new();
            each_chord(&p, max_bins, 1, 0.0, |c| got.push(c));
            let want = brute(&p, max_bins);
            assert_eq!(got.len(), want.len(), "{p:?}");
            for (g, w) in got.iter().zip(&want) {
                assert_eq!((g.i, g.j), (w.i, w.j), "{p:?}");
                assert!((g.gap - w.gap).abs() < 1e-9, "{p:?}: {g:?} against {w:?}");
            }
        }
    }

    #[test]
    fn a_dent_is_measured_from_its_rims_and_a_hole_holds_nothing() {
        // A dent 3 deep between rims 6 bins apart, on a flat profile.
        let p: Vec<Option<f64>> = [0.0, 0.0, 0.0, -1.0, -2.0, -3.0, -2.0, -1.0, 0.0, 0.0, 0.0]
            .map(Some)
            .to_vec();
        let mut deepest = None::<Chord>;
        each_chord(&p, 100, 1, 0.0, |c| {
            if deepest.is_none_or(|d| c.gap > d.gap || (c.gap == d.gap && c.j - c.i < d.j - d.i)) {
                deepest = Some(c);
            }
        });
        let d = deepest.unwrap();
        assert_eq!((d.k, d.gap), (5, 3.0));
        assert_eq!((d.i, d.j), (2, 8), "{d:?}");
        // Half the blocks unmeasured: no position counts at 70 %.
        let holes: Vec<Option<f64>> = (0..20).map(|i| (i % 4 < 2).then_some(0.0)).collect();
        let mut n = 0;
        each_chord(&holes, 100, 2, 0.7, |_| n += 1);
        assert_eq!(n, 0);
    }
}
