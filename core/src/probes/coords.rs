//! A chunk's points laid out coordinate by coordinate.
//!
//! A probe tests every point of the fine cells its box touches, and most fail. With the x, y
//! and z of neighbouring points side by side, one vector instruction tests several points.

use std::ops::Range;

use nalgebra::Point3;

/// Points as three arrays of coordinates, reused from chunk to chunk.
#[derive(Debug, Default, Clone, PartialEq)]
pub(crate) struct Coords {
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
}

impl Coords {
    pub(crate) fn clear(&mut self) {
        self.x.clear();
        self.y.clear();
        self.z.clear();
    }

    pub(crate) fn reserve(&mut self, n: usize) {
        self.x.reserve(n);
        self.y.reserve(n);
        self.z.reserve(n);
    }

    /// `n` points, each to be written through [`Self::columns_mut`].
    pub(crate) fn resize(&mut self, n: usize) {
        self.x.resize(n, 0.0);
        self.y.resize(n, 0.0);
        self.z.resize(n, 0.0);
    }

    /// The x, y and z of every point, to be written.
    pub(crate) fn columns_mut(&mut self) -> (&mut [f64], &mut [f64], &mut [f64]) {
        (&mut self.x, &mut self.y, &mut self.z)
    }

    pub(crate) fn extend<'a>(&mut self, points: impl Iterator<Item = &'a Point3<f64>>) {
        for p in points {
            self.x.push(p.x);
            self.y.push(p.y);
            self.z.push(p.z);
        }
    }

    /// Memory held, bytes.
    pub(crate) fn bytes(&self) -> usize {
        (self.x.capacity() + self.y.capacity() + self.z.capacity()) * size_of::<f64>()
    }

    #[inline]
    pub(crate) fn run(&self, r: Range<usize>) -> Run<'_> {
        Run {
            x: &self.x[r.clone()],
            y: &self.y[r.clone()],
            z: &self.z[r],
        }
    }
}

/// Consecutive points of a chunk, coordinate by coordinate: `x[i]`, `y[i]`, `z[i]` is point
/// `i`. The three slices have one length.
#[derive(Debug, Clone, Copy)]
pub struct Run<'a> {
    /// The points' x.
    pub x: &'a [f64],
    /// The points' y.
    pub y: &'a [f64],
    /// The points' z.
    pub z: &'a [f64],
}

impl Run<'_> {
    /// Points in the run.
    #[inline]
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether the run holds no point.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Four points from `at` as offsets v from the probe `p`, in AVX2 registers: their squared
    /// lengths and their offsets along `n`, each as nalgebra evaluates `v.norm_squared()` and
    /// `v.dot(n)`, (vx·vx + vy·vy) + vz·vz. With `valid`, only its lanes are loaded (the
    /// others hold what zeros give).
    ///
    /// # Safety
    /// The CPU must have AVX2, and the four points from `at` (those `valid` keeps) must lie in
    /// the run.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(crate) unsafe fn offsets_avx2(
        &self,
        at: usize,
        valid: Option<std::arch::x86_64::__m256i>,
        p: &[std::arch::x86_64::__m256d; 3],
        n: &[std::arch::x86_64::__m256d; 3],
    ) -> (std::arch::x86_64::__m256d, std::arch::x86_64::__m256d) {
        use std::arch::x86_64::*;
        // SAFETY: as the caller's; a masked load reads only the lanes `valid` keeps.
        unsafe {
            // Written out, not a closure: a closure left out of line runs without AVX2.
            let (x, y, z) = match valid {
                None => (
                    _mm256_loadu_pd(self.x.as_ptr().add(at)),
                    _mm256_loadu_pd(self.y.as_ptr().add(at)),
                    _mm256_loadu_pd(self.z.as_ptr().add(at)),
                ),
                Some(m) => (
                    _mm256_maskload_pd(self.x.as_ptr().add(at), m),
                    _mm256_maskload_pd(self.y.as_ptr().add(at), m),
                    _mm256_maskload_pd(self.z.as_ptr().add(at), m),
                ),
            };
            let (vx, vy, vz) = (
                _mm256_sub_pd(x, p[0]),
                _mm256_sub_pd(y, p[1]),
                _mm256_sub_pd(z, p[2]),
            );
            let d2 = _mm256_add_pd(
                _mm256_add_pd(_mm256_mul_pd(vx, vx), _mm256_mul_pd(vy, vy)),
                _mm256_mul_pd(vz, vz),
            );
            let along = _mm256_add_pd(
                _mm256_add_pd(_mm256_mul_pd(vx, n[0]), _mm256_mul_pd(vy, n[1])),
                _mm256_mul_pd(vz, n[2]),
            );
            (d2, along)
        }
    }

    /// The points in order.
    #[inline]
    pub fn iter(&self) -> impl Iterator<Item = Point3<f64>> + '_ {
        self.x
            .iter()
            .zip(self.y)
            .zip(self.z)
            .map(|((&x, &y), &z)| Point3::new(x, y, z))
    }
}
