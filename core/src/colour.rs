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
    let fade = |x: f64| (255.0 * (1.0 - x)).round() as u8;
    if t >= 0.0 {
        [255, fade(t), fade(t)]
    } else {
        [fade(-t), fade(-t), 255]
    }
}
