//! Multiscale Model to Model Cloud Comparison (M3C2; Lague, Brodu and Leroux 2013).
//!
//! At each core point with normal `n`, the points of a cloud inside a cylinder of radius `d/2`
//! (the projection scale) along `n`, reaching `h` (the maximum depth) to either side, are
//! projected on the axis. The distance is the difference of the two clouds' mean (or median)
//! positions along the axis, and the level of detection at 95 % is
//!
//! ```text
//! LoD95 = 1.96 · ( sqrt(σ1² / n1 + σ2² / n2) + reg )
//! ```
//!
//! with σ the spread of each cloud's projections, n their counts and reg the registration error.
//! A change is significant when |distance| exceeds the LoD.
//!
//! - [`streaming`]: against the design. Core points and normals come from the design, whose
//!   side is exact (σ1 = 0, position 0), and scan points arrive chunk by chunk.
//! - [`classic`]: two clouds, normals by PCA, as CloudCompare and PDAL compute it.

pub mod classic;
pub mod streaming;

/// A station's values along one cylinder, as sums about the first of them: taking a value is
/// additions and a multiplication, where [`Running::push`] divides, and that division's latency
/// chained every value a cylinder takes. A station's values lie within the cylinder's length of
/// each other, so the sums lose nothing that matters; the station ends as a [`Running`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Shifted {
    n: u32,
    first: f64,
    /// Σ (x − first).
    s1: f64,
    /// Σ (x − first)².
    s2: f64,
}

impl Shifted {
    /// Takes one value.
    #[inline]
    pub fn push(&mut self, x: f64) {
        if self.n == 0 {
            self.first = x;
        }
        self.n += 1;
        let d = x - self.first;
        self.s1 += d;
        self.s2 += d * d;
    }

    /// The values taken, as a count, mean and sum of squared deviations.
    pub fn running(&self) -> Running {
        if self.n == 0 {
            return Running::default();
        }
        let shift = self.s1 / f64::from(self.n);
        Running {
            n: self.n,
            mean: self.first + shift,
            m2: (self.s2 - self.s1 * shift).max(0.0),
        }
    }
}

/// A count, mean and sum of squared deviations (Welford 1962), mergeable across chunks and
/// threads (Chan, Golub and LeVeque 1979).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Running {
    /// Values taken.
    pub n: u32,
    /// Their mean.
    pub mean: f64,
    /// The sum of their squared deviations from the mean.
    pub m2: f64,
}

impl Running {
    /// Takes one value.
    #[inline]
    pub fn push(&mut self, x: f64) {
        self.n += 1;
        let d = x - self.mean;
        self.mean += d / self.n as f64;
        self.m2 += d * (x - self.mean);
    }

    /// Takes another run's values, as if pushed here.
    pub fn merge(&mut self, o: &Self) {
        if o.n == 0 {
            return;
        }
        if self.n == 0 {
            *self = *o;
            return;
        }
        let n = self.n + o.n;
        let d = o.mean - self.mean;
        self.mean += d * o.n as f64 / n as f64;
        self.m2 += o.m2 + d * d * self.n as f64 * o.n as f64 / n as f64;
        self.n = n;
    }

    /// Sample standard deviation (n − 1); `None` below two values.
    pub fn std(&self) -> Option<f64> {
        (self.n >= 2).then(|| (self.m2 / (self.n - 1) as f64).max(0.0).sqrt())
    }
}

/// The 95 % level of detection of Lague et al. (2013), eq. 1.
pub fn lod95(std1: f64, n1: u32, std2: f64, n2: u32, registration: f64) -> f64 {
    let term = |s: f64, n: u32| if n == 0 { 0.0 } else { s * s / n as f64 };
    1.96 * ((term(std1, n1) + term(std2, n2)).sqrt() + registration)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shifted sums give a cylinder's mean to 1e-12 of its values' size and its squared
    /// deviations to 1e-10 (Welford's updates did about 1e-15; report.json allows 1e-9):
    /// values spread over a cylinder's length, a tight cluster whose first value is an outlier
    /// (the sums' worst case), one value, none.
    #[test]
    fn shifted_sums_give_the_two_pass_mean_and_spread() {
        use rand::Rng;
        let mut rng = crate::test_points::seeded(5);
        let mut cases: Vec<Vec<f64>> = (0..200)
            .map(|k| {
                let n = rng.random_range(2..2000);
                let centre = rng.random_range(-0.01..0.01);
                let spread = 10f64.powi(-rng.random_range(3..6));
                let mut xs: Vec<f64> = (0..n)
                    .map(|_| centre + rng.random_range(-spread..spread))
                    .collect();
                if k % 2 == 0 {
                    xs[0] = if centre > 0.0 { -0.01 } else { 0.01 };
                }
                xs
            })
            .collect();
        cases.push(vec![0.003]);
        cases.push(vec![]);
        for xs in cases {
            let mut s = Shifted::default();
            xs.iter().for_each(|&x| s.push(x));
            let r = s.running();
            assert_eq!(r.n as usize, xs.len());
            if xs.is_empty() {
                assert_eq!(r, Running::default());
                continue;
            }
            // The truth from compensated two-pass sums.
            let exact = |v: &mut dyn Iterator<Item = f64>| {
                let (mut sum, mut c) = (0.0f64, 0.0f64);
                for x in v {
                    let t = sum + x;
                    c += if sum.abs() >= x.abs() {
                        (sum - t) + x
                    } else {
                        (x - t) + sum
                    };
                    sum = t;
                }
                sum + c
            };
            let mean = exact(&mut xs.iter().copied()) / xs.len() as f64;
            let m2 = exact(&mut xs.iter().map(|x| (x - mean) * (x - mean)));
            let scale = xs.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            assert!((r.mean - mean).abs() <= 1e-12 * scale, "{} {mean}", r.mean);
            assert!((r.m2 - m2).abs() <= 1e-10 * m2, "{} {m2}", r.m2);
        }
    }

    #[test]
    fn running_statistics_merge_like_one_pass() {
        let xs: Vec<f64> = (0..1000)
            .map(|i| ((i * 37) % 101) as f64 * 0.01 - 0.3)
            .collect();
        let mut all = Running::default();
        xs.iter().for_each(|&x| all.push(x));
        let mut a = Running::default();
        let mut b = Running::default();
        xs[..313].iter().for_each(|&x| a.push(x));
        xs[313..].iter().for_each(|&x| b.push(x));
        a.merge(&b);
        assert_eq!(a.n, all.n);
        assert!((a.mean - all.mean).abs() < 1e-12);
        assert!((a.m2 - all.m2).abs() < 1e-9);
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (xs.len() - 1) as f64;
        assert!((all.std().unwrap() - var.sqrt()).abs() < 1e-12);
    }
}
