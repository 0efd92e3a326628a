//! Cell addresses from coordinates, for the grids that bucket points.

/// `x.floor() as i64`, without the call into the maths library that `floor` is on a processor
/// without SSE 4.1 (the build's baseline): a cast truncates towards zero and saturates, so only
/// a negative fraction needs one step down. NaN gives 0, as the cast does.
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

#[cfg(test)]
mod tests {
    use super::floor_i64;

    /// The cast and step give the maths library's floor: whole numbers, fractions either side
    /// of zero, the edges of the i64 range and beyond, NaN.
    #[test]
    fn floor_is_the_libm_floor() {
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            -1.0,
            -1.0 - f64::EPSILON,
            1e300,
            -1e300,
            9.3e18,
            -9.3e18,
            i64::MIN as f64,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        xs.extend((-2000..2000).map(|i| f64::from(i) * 0.37));
        for x in xs {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
    }
}
