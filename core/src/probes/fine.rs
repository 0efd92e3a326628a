//! Fine cells: a cell split into cells as wide as a cylinder's radius, the integer arithmetic
//! that finds a fine cell's cell without a division, and the columns of a box a probe visits.

use nalgebra::Vector3;

/// For cylinders: the fine cell's width, how many fine cells make a cell along each axis, and
/// each probe's cylinder's bounding box half-widths, in grid order.
pub(super) struct Fine {
    pub(super) width: f64,
    pub(super) per_cell: i64,
    /// For cylinders, each probe's box; empty for narrowing balls, whose box follows the state.
    pub(super) half_box: Vec<Vector3<f64>>,
    /// [`Fine::split`]'s divisor by `per_cell`, as a multiply and a shift.
    pub(super) divide: Divide,
}

impl Fine {
    pub(super) fn new(width: f64, per_cell: i64) -> Self {
        Self {
            width,
            per_cell,
            half_box: Vec::new(),
            divide: Divide::new(per_cell),
        }
    }

    /// The cell a fine cell lies in.
    #[inline]
    pub(super) fn cell_of(&self, c: [i64; 3]) -> [i64; 3] {
        let d = &self.divide;
        [d.split(c[0]).0, d.split(c[1]).0, d.split(c[2]).0]
    }

    /// The cell a fine cell lies in, and the fine cell's index within it (x, then y, then z).
    #[inline]
    pub(super) fn split(&self, c: [i64; 3]) -> ([i64; 3], u32) {
        let d = &self.divide;
        let ((x, lx), (y, ly), (z, lz)) = (d.split(c[0]), d.split(c[1]), d.split(c[2]));
        let m = self.per_cell;
        ([x, y, z], ((lx * m + ly) * m + lz) as u32)
    }
}

/// Floor division of a fine cell coordinate by the fine cells a cell side holds, without an
/// integer division: every point of every batch takes three, and a 64-bit divide costs tens of
/// cycles where a multiply costs three.
#[derive(Clone, Copy)]
pub(super) struct Divide {
    pub(super) m: u64,
    /// A multiple of `m` at least [`AXIS_BIAS`](super::AXIS_BIAS): coordinates plus it are never negative.
    pub(super) bias: u64,
    /// ⌈2^SHIFT / m⌉.
    pub(super) magic: u64,
    /// `bias / m`.
    pub(super) below: i64,
}

impl Divide {
    /// For `m` ≥ 1 below 2^11 (a cell's fine cells number below 2^32) and coordinates within
    /// ±[`AXIS_BIAS`](super::AXIS_BIAS), `n = v + bias` is below 2^22. Then ⌊n·magic / 2^40⌋ is ⌊n / m⌋: magic
    /// exceeds 2^40 / m by less than one, which adds less than n / 2^40 < 2^-18 to n / m, and
    /// n / m's fraction is at most 1 - 1/m ≤ 1 - 2^-11. The product stays below 2^62.
    pub(super) const SHIFT: u32 = 40;

    pub(super) fn new(m: i64) -> Self {
        assert!((1..1 << 11).contains(&m), "fine cells a side: {m}");
        let m = m as u64;
        let below = (super::AXIS_BIAS as u64).div_ceil(m);
        Self {
            m,
            bias: below * m,
            magic: (1u64 << Self::SHIFT).div_ceil(m),
            below: below as i64,
        }
    }

    /// `(v.div_euclid(m), v.rem_euclid(m))` for |v| within [`AXIS_BIAS`](super::AXIS_BIAS).
    #[inline]
    pub(super) fn split(&self, v: i64) -> (i64, i64) {
        debug_assert!(
            v.abs() <= super::AXIS_BIAS,
            "coordinate {v} outside the grid"
        );
        let n = (v + self.bias as i64) as u64;
        let q = (n * self.magic) >> Self::SHIFT;
        (q as i64 - self.below, (n - q * self.m) as i64)
    }
}

/// The y's of a row of a box's columns: all of them, or those whose bits are set.
pub(super) enum Ys {
    Range(std::ops::RangeInclusive<i64>),
    Bits { row: u64, first: i64 },
}

impl Iterator for Ys {
    type Item = i64;

    #[inline]
    fn next(&mut self) -> Option<i64> {
        match self {
            Ys::Range(r) => r.next(),
            Ys::Bits { row, first } => {
                if *row == 0 {
                    return None;
                }
                let y = *first + i64::from(row.trailing_zeros());
                *row &= *row - 1;
                Some(y)
            }
        }
    }
}
