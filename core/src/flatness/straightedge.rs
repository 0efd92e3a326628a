//! A straightedge laid on a profile: at every position of a given span, it rests on the two
//! highest points around each low one (the profile's upper hull over the span), and the gap is
//! how far the surface lies below it. A crown with no higher point beyond it on either side
//! holds the straightedge on one point and has no gap of its own.

/// The deepest gap under a straightedge of `span` bins (`span + 1` points) slid along
/// `profile` (heights, `None` where nothing was measured), with the index of its deepest
/// point. A position counts only where at least `min_filled` of its points are measured.
pub fn worst_gap(profile: &[Option<f64>], span: usize, min_filled: f64) -> Option<(f64, usize)> {
    if span == 0 || profile.len() <= span {
        return None;
    }
    let mut worst: Option<(f64, usize)> = None;
    let mut hull: Vec<(usize, f64)> = Vec::with_capacity(span + 1);
    for start in 0..profile.len() - span {
        let window = &profile[start..=start + span];
        let filled = window.iter().filter(|p| p.is_some()).count();
        if (filled as f64) < min_filled * window.len() as f64 || filled < 3 {
            continue;
        }
        upper_hull(window, &mut hull);
        if let Some((gap, at)) = deepest_below(window, &hull)
            && worst.is_none_or(|w| gap > w.0)
        {
            worst = Some((gap, start + at));
        }
    }
    worst
}

/// The upper convex hull of the measured points of `window` (Andrew's monotone chain).
fn upper_hull(window: &[Option<f64>], hull: &mut Vec<(usize, f64)>) {
    hull.clear();
    for (i, p) in window.iter().enumerate() {
        let Some(y) = *p else { continue };
        while hull.len() >= 2 {
            let (x1, y1) = hull[hull.len() - 2];
            let (x2, y2) = hull[hull.len() - 1];
            // Drop the middle point when it lies on or below the line from x1 to i.
            let cross = (x2 as f64 - x1 as f64) * (y - y1) - (y2 - y1) * (i as f64 - x1 as f64);
            if cross >= 0.0 {
                hull.pop();
            } else {
                break;
            }
        }
        hull.push((i, y));
    }
}

/// The largest distance of a measured point below the hull, and where.
fn deepest_below(window: &[Option<f64>], hull: &[(usize, f64)]) -> Option<(f64, usize)> {
    let mut best: Option<(f64, usize)> = None;
    let mut seg = 0;
    for (i, p) in window.iter().enumerate() {
        let Some(y) = *p else { continue };
        while seg + 1 < hull.len() && hull[seg + 1].0 < i {
            seg += 1;
        }
        let line = if seg + 1 < hull.len() {
            let (x1, y1) = hull[seg];
            let (x2, y2) = hull[seg + 1];
            y1 + (y2 - y1) * (i as f64 - x1 as f64) / (x2 as f64 - x1 as f64)
        } else {
            hull[seg].1
        };
        let gap = line - y;
        if best.is_none_or(|b| gap > b.0) {
            best = Some((gap, i));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gap by brute force: for every low point, the highest line through one measured point
    /// on each side of it.
    fn brute(window: &[Option<f64>]) -> f64 {
        let pts: Vec<(f64, f64)> = window
            .iter()
            .enumerate()
            .filter_map(|(i, p)| p.map(|y| (i as f64, y)))
            .collect();
        let mut worst = 0.0f64;
        for &(x, y) in &pts {
            // The straightedge over x rests on the hull: the lowest of the lines through a
            // point left and a point right that stay above every point.
            let mut best = f64::INFINITY;
            for &(xa, ya) in pts.iter().filter(|p| p.0 <= x) {
                for &(xb, yb) in pts.iter().filter(|p| p.0 >= x) {
                    let at = |t: f64| {
                        if xb == xa {
                            ya.max(yb)
                        } else {
                            ya + (yb - ya) * (t - xa) / (xb - xa)
                        }
                    };
                    if pts.iter().all(|p| at(p.0) >= p.1 - 1e-12) {
                        best = best.min(at(x));
                    }
                }
            }
            worst = worst.max(best - y);
        }
        worst
    }

    #[test]
    fn the_gap_is_the_deepest_point_below_the_upper_hull_as_brute_force_finds_it() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for _ in 0..200 {
            let n = rng.random_range(4..30);
            let window: Vec<Option<f64>> = (0..n)
                .map(|_| rng.random_bool(0.8).then(|| rng.random_range(-1.0..1.0)))
                .collect();
            if window.iter().filter(|p| p.is_some()).count() < 3 {
                continue;
            }
            let got = worst_gap(&window, n - 1, 0.0).map(|g| g.0).unwrap();
            assert!((got - brute(&window)).abs() < 1e-9, "{window:?}");
        }
    }

    #[test]
    fn a_dip_between_two_supports_is_the_gap_and_a_straight_slope_has_none() {
        let dip: Vec<Option<f64>> = [0.0, -1.0, -3.0, -1.0, 0.0].map(Some).to_vec();
        assert_eq!(worst_gap(&dip, 4, 1.0), Some((3.0, 2)));
        let slope: Vec<Option<f64>> = (0..10).map(|i| Some(0.5 * i as f64)).collect();
        assert!(worst_gap(&slope, 4, 1.0).unwrap().0.abs() < 1e-12);
        // Too few points measured: no position counts.
        let sparse = [Some(0.0), None, None, None, Some(1.0)];
        assert_eq!(worst_gap(&sparse, 4, 0.7), None);
    }
}
