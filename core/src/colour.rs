//! The one diverging colour scale of signed deviations, shared by the rerun view and the
//! report's maps, so a colour means the same on screen and on paper.

/// No match within the maximum distance.
pub const NO_MATCH: [u8; 3] = [128, 128, 128];

/// Blue (−tolerance: missing material) through white (on the design) to red (+tolerance:
/// excess), saturated beyond; grey for NaN (no match).
pub fn deviation_colour(d: f64, tolerance: f64) -> [u8; 3] {
    if !d.is_finite() {
        return NO_MATCH;
    }
    let t = (d / tolerance).clamp(-1.0, 1.0);
    if t >= 0.0 {
        let f = fade(t);
        [255, f, f]
    } else {
        let f = fade(-t);
        [f, f, 255]
    }
}

/// `255 (1 - x)` rounded half away from zero, for `x` in [0, 1]: what `f64::round` gives, without
/// its call into libm (the build's baseline x86-64 has no rounding instruction). A recording's
/// Foxglove cloud colours every point it shows, and that call was 14 % of its time per point.
/// A float less its truncation is exact, so the comparison with one half decides as `round`
/// does.
#[inline]
fn fade(x: f64) -> u8 {
    let v = 255.0 * (1.0 - x);
    let whole = v as u8;
    if v - f64::from(whole) >= 0.5 {
        whole + 1
    } else {
        whole
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fade rounds as `f64::round` does over the whole scale, at and beside every half.
    #[test]
    fn fade_rounds_as_round_does() {
        let round = |x: f64| (255.0 * (1.0 - x)).round() as u8;
        let mut xs: Vec<f64> = (0..=1_000_000).map(|i| i as f64 / 1e6).collect();
        for k in 0..=255 {
            let half = (k as f64 + 0.5) / 255.0;
            let exact = k as f64 / 255.0;
            for x in [half, exact] {
                xs.extend([x, x.next_up(), x.next_down()]);
            }
        }
        xs.retain(|x| (0.0..=1.0).contains(x));
        for x in xs {
            assert_eq!(fade(x), round(x), "{x:e}");
        }
        assert_eq!(fade(f64::NAN), round(f64::NAN));
        // A zero tolerance makes 0/0: the NaN fades as `round` made it.
        assert_eq!(deviation_colour(0.0, 0.0), [0, 0, 255]);
    }

    #[test]
    fn scale_ends_and_middle() {
        assert_eq!(deviation_colour(0.0, 0.005), [255, 255, 255]);
        assert_eq!(deviation_colour(0.005, 0.005), [255, 0, 0]);
        assert_eq!(deviation_colour(-0.01, 0.005), [0, 0, 255]);
        assert_eq!(deviation_colour(0.0025, 0.005), [255, 128, 128]);
        assert_eq!(deviation_colour(f64::NAN, 0.005), NO_MATCH);
    }
}
