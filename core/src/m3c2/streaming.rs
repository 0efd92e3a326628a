//! M3C2 against the design, one chunk at a time.
//!
//! Core points and their normals are design samples. Every scan point updates the running
//! statistics of each cylinder it falls in, so memory is fixed by the number of core points
//! whatever the number of scan points. The design side of the comparison is exact (position 0,
//! no spread), so the distance is the mean offset of the scan along the design normal: positive
//! where the print stands outside the design.

use nalgebra::{Point3, Vector3};

use super::{Running, Shifted, lod95};
use crate::probes::{ProbeGrid, Region, Run, Scratch};
use crate::sampling::DesignSamples;

/// The parameters of M3C2 at design samples, along the design's normals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamingParams {
    /// Cylinder diameter, metres.
    pub projection_diameter: f64,
    /// Cylinder half-length along the normal, metres: the largest deviation that can be found.
    pub max_depth: f64,
    /// Fewer points than this in a cylinder give a distance but never a significant change.
    pub min_points: u32,
}

#[derive(Debug, thiserror::Error)]
#[error(
    "M3C2 projection diameter ({projection_diameter} m) and maximum depth ({max_depth} m) must be \
     positive numbers of metres"
)]
/// M3C2 scales that cannot be used.
pub struct StreamingError {
    /// The projection diameter given.
    pub projection_diameter: f64,
    /// The maximum depth given.
    pub max_depth: f64,
}

/// One core point's result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoreResult {
    /// This core point's index in the samples M3C2 was built from.
    pub sample: u32,
    /// The core point, design frame.
    pub position: Point3<f64>,
    /// The design's outward unit normal there.
    pub normal: Vector3<f64>,
    /// Mean offset of the scan along the normal, metres; `None` with no point in the cylinder.
    pub distance: Option<f64>,
    /// Standard deviation of the offsets, metres.
    pub spread: Option<f64>,
    /// Scan points in the cylinder.
    pub count: u32,
    /// Level of detection at 95 %, metres.
    pub lod95: Option<f64>,
    /// Whether |distance| exceeds the level of detection.
    pub significant: bool,
}

/// M3C2 over a station, or over the job so far.
#[derive(Debug, Clone, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct StreamingSummary {
    /// Core points.
    pub core_points: u64,
    /// Core points with at least one scan point in their cylinder.
    pub with_points: u64,
    /// Core points whose distance exceeds their level of detection.
    pub significant: u64,
    /// Mean and extremes of the distances of core points with points, metres.
    pub mean_distance: Option<f64>,
    /// Smallest distance, metres.
    pub min_distance: Option<f64>,
    /// Largest distance, metres.
    pub max_distance: Option<f64>,
}

/// Lanes of a cylinder's sums over a run: each value goes to the lane of its place in the run,
/// and the lanes are added in a fixed order at the run's end.
const LANES: usize = 8;

/// Adds to `st` the offsets along `n` of the points `qs` inside the cylinder of squared
/// radius `r2` and half-length `h` around `p`.
///
/// Most points offered lie outside: a tilted cylinder's box holds several times its volume,
/// and on the bunny job about 1 point in 4 that the columns' cut leaves is inside. A take per
/// insider was a branch the CPU could not foresee, once per value. So every point is tested
/// and summed in lanes side by side, an outsider adding nothing: no branch per point. The count
/// is exact; the sums take the same values in another order (a lane per place in the run).
#[inline]
fn add_inside(st: &mut Shifted, p: &Point3<f64>, n: &Vector3<f64>, qs: Run<'_>, r2: f64, h: f64) {
    add_inside_in(st, (p, n, r2, h), qs, crate::simd::has_avx2());
}

/// [`add_inside`], its whole groups of lanes in AVX2 registers when `vector` (which the CPU
/// must have) or one lane after another: the same bits either way.
#[inline]
fn add_inside_in(
    st: &mut Shifted,
    (p, n, r2, h): (&Point3<f64>, &Vector3<f64>, f64, f64),
    qs: Run<'_>,
    vector: bool,
) {
    // As nalgebra evaluates `v.dot(n)` and `v.norm_squared()` for v = q − p.
    #[inline(always)]
    fn test(p: &Point3<f64>, n: &Vector3<f64>, r2: f64, h: f64, q: [f64; 3]) -> (f64, bool) {
        let (vx, vy, vz) = (q[0] - p.x, q[1] - p.y, q[2] - p.z);
        let a = vx * n.x + vy * n.y + vz * n.z;
        let d2 = vx * vx + vy * vy + vz * vz;
        (a, (a.abs() <= h) & (d2 - a * a <= r2))
    }
    let mut from = 0;
    if st.n == 0 {
        // The first value taken is the shift of the sums.
        while from < qs.len() {
            let q = [qs.x[from], qs.y[from], qs.z[from]];
            from += 1;
            let (a, inside) = test(p, n, r2, h, q);
            if inside {
                st.push(a);
                break;
            }
        }
    }
    if from == qs.len() {
        return;
    }
    let (count, s1, s2) = crate::simd::avx2!([
        p: &Point3<f64> = p,
        n: &Vector3<f64> = n,
        r2: f64 = r2,
        h: f64 = h,
        first: f64 = st.first,
        qs: Run<'_> = Run {
            x: &qs.x[from..],
            y: &qs.y[from..],
            z: &qs.z[from..],
        },
        vector: bool = vector,
    ] -> (u32, f64, f64) {
        let mut count = [0u32; LANES];
        let mut s1 = [0.0f64; LANES];
        let mut s2 = [0.0f64; LANES];
        // What a point adds to lane k (a function, not a closure: compiled with AVX2).
        #[inline(always)]
        fn lane(
            sums: (&mut [u32; LANES], &mut [f64; LANES], &mut [f64; LANES]),
            k: usize,
            (a, inside): (f64, bool),
            first: f64,
        ) {
            let d = if inside { a - first } else { 0.0 };
            sums.0[k] += u32::from(inside);
            sums.1[k] += d;
            sums.2[k] += d * d;
        }
        // The points the AVX2 lanes took (all of them), or none.
        #[cfg(target_arch = "x86_64")]
        let done = if vector {
            // SAFETY: `vector` only where the CPU has AVX2.
            unsafe { groups_avx2((p, n, r2, h, first), qs, (&mut count, &mut s1, &mut s2)) }
        } else {
            0
        };
        #[cfg(not(target_arch = "x86_64"))]
        let done = {
            let _ = vector;
            0
        };
        let (x, y, z) = (&qs.x[done..], &qs.y[done..], &qs.z[done..]);
        let (x, y, z) = (x.chunks_exact(LANES), y.chunks_exact(LANES), z.chunks_exact(LANES));
        let (rx, ry, rz) = (x.remainder(), y.remainder(), z.remainder());
        for ((x, y), z) in x.zip(y).zip(z) {
            for k in 0..LANES {
                let t = test(p, n, r2, h, [x[k], y[k], z[k]]);
                lane((&mut count, &mut s1, &mut s2), k, t, first);
            }
        }
        for k in 0..rx.len() {
            let t = test(p, n, r2, h, [rx[k], ry[k], rz[k]]);
            lane((&mut count, &mut s1, &mut s2), k, t, first);
        }
        let sum = |l: [f64; LANES]| ((l[0] + l[1]) + (l[2] + l[3])) + ((l[4] + l[5]) + (l[6] + l[7]));
        (count.iter().sum(), sum(s1), sum(s2))
    });
    st.n += count;
    st.s1 += s1;
    st.s2 += s2;
}

/// [`add_inside`]'s lanes in AVX2 registers, four at a time: the same arithmetic in the same
/// order as its lanes, so the same bits. Takes every point of `qs`; returns how many. Written
/// out because the compiler's own vectors of the lanes moved with unrelated code: a change
/// elsewhere in this file once made them spill, and the test took 0.60 s of the bunny job's
/// CPU instead of 0.32 s.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn groups_avx2(
    (p, n, r2, h, first): (&Point3<f64>, &Vector3<f64>, f64, f64, f64),
    qs: Run<'_>,
    (count, s1, s2): (&mut [u32; LANES], &mut [f64; LANES], &mut [f64; LANES]),
) -> usize {
    use std::arch::x86_64::*;
    let len = qs.x.len().min(qs.y.len()).min(qs.z.len());
    let groups = len / LANES;
    // SAFETY: the CPU has AVX2; every load reads four f64 within the first `len` values of a
    // slice (the last group's masked to them), and every store writes four lanes of an array
    // of eight.
    unsafe {
        let [px, py, pz] = [p.x, p.y, p.z].map(|v| _mm256_set1_pd(v));
        let [nx, ny, nz] = [n.x, n.y, n.z].map(|v| _mm256_set1_pd(v));
        let (r2, h, first) = (_mm256_set1_pd(r2), _mm256_set1_pd(h), _mm256_set1_pd(first));
        let sign = _mm256_set1_pd(-0.0);
        let k = [px, py, pz, nx, ny, nz, r2, h, first, sign];
        // Four points from `at`: the mask of those inside and their offsets (0 outside). A
        // function, not a closure: a closure left out of line runs without AVX2.
        #[inline(always)]
        unsafe fn four(
            qs: &Run<'_>,
            at: usize,
            valid: Option<__m256i>,
            k: &[__m256d; 10],
        ) -> (__m256d, __m256d) {
            let [px, py, pz, nx, ny, nz, r2, h, first, sign] = *k;
            // SAFETY: as the caller's.
            unsafe {
                let (d2, a) = qs.offsets_avx2(at, valid, &[px, py, pz], &[nx, ny, nz]);
                let along = _mm256_cmp_pd::<_CMP_LE_OQ>(_mm256_andnot_pd(sign, a), h);
                let across =
                    _mm256_cmp_pd::<_CMP_LE_OQ>(_mm256_sub_pd(d2, _mm256_mul_pd(a, a)), r2);
                let mut inside = _mm256_and_pd(along, across);
                if let Some(m) = valid {
                    inside = _mm256_and_pd(inside, _mm256_castsi256_pd(m));
                }
                (inside, _mm256_and_pd(inside, _mm256_sub_pd(a, first)))
            }
        }
        // The count, sums and squares of four lanes with four more points added.
        #[inline(always)]
        unsafe fn add(
            (c, t1, t2): (__m256i, __m256d, __m256d),
            (inside, d): (__m256d, __m256d),
        ) -> (__m256i, __m256d, __m256d) {
            // SAFETY: as the caller's. A mask's lane is −1 where inside.
            unsafe {
                (
                    _mm256_sub_epi64(c, _mm256_castpd_si256(inside)),
                    _mm256_add_pd(t1, d),
                    _mm256_add_pd(t2, _mm256_mul_pd(d, d)),
                )
            }
        }
        // Lanes 0–3, then lanes 4–7: one half's sums at a time leave registers for the
        // constants (both at once spilled the sums to the stack on every step).
        let mut lanes = [0u64; LANES];
        for half in [0, 4] {
            let c = _mm256_setzero_si256();
            let t1 = _mm256_loadu_pd(s1.as_ptr().add(half));
            let t2 = _mm256_loadu_pd(s2.as_ptr().add(half));
            let mut sums = (c, t1, t2);
            for g in 0..groups {
                sums = add(sums, four(&qs, g * LANES + half, None, &k));
            }
            // The last points, fewer than a group, in the lanes of their places; the others
            // load nothing and add +0, which leaves a sum's bits as they are (a sum from +0
            // never becomes −0).
            let rest = (len - groups * LANES).saturating_sub(half).min(4) as i64;
            if rest > 0 {
                let valid = _mm256_setr_epi64x(
                    -i64::from(rest > 0),
                    -i64::from(rest > 1),
                    -i64::from(rest > 2),
                    -i64::from(rest > 3),
                );
                sums = add(sums, four(&qs, groups * LANES + half, Some(valid), &k));
            }
            let (c, t1, t2) = sums;
            _mm256_storeu_pd(s1.as_mut_ptr().add(half), t1);
            _mm256_storeu_pd(s2.as_mut_ptr().add(half), t2);
            _mm256_storeu_si256(lanes.as_mut_ptr().add(half).cast(), c);
        }
        for (k, l) in count.iter_mut().zip(lanes) {
            // At most a run's length, a u32.
            *k += l as u32;
        }
    }
    len
}

/// M3C2 streamed chunk by chunk at fixed core points (design samples) with the design's
/// normals, in memory proportional to the core points, never to the scan.
pub struct StreamingM3c2 {
    grid: ProbeGrid,
    params: StreamingParams,
    station: Vec<Shifted>,
    total: Vec<Running>,
    scratch: Scratch,
}

impl StreamingM3c2 {
    /// M3C2 at the samples of `core`, nothing seen yet.
    pub fn new(core: &DesignSamples, params: StreamingParams) -> Result<Self, StreamingError> {
        let ok = |v: f64| v > 0.0 && v.is_finite();
        if !ok(params.projection_diameter) || !ok(params.max_depth) {
            return Err(StreamingError {
                projection_diameter: params.projection_diameter,
                max_depth: params.max_depth,
            });
        }
        let grid = ProbeGrid::around(
            &core.points,
            &core.normals,
            Region::Cylinder {
                radius: 0.5 * params.projection_diameter,
                half_length: params.max_depth,
            },
        );
        let n = grid.len();
        Ok(Self {
            grid,
            params,
            station: vec![Shifted::default(); n],
            total: vec![Running::default(); n],
            scratch: Scratch::default(),
        })
    }

    /// The parameters it was made with.
    pub fn params(&self) -> &StreamingParams {
        &self.params
    }

    /// Core points.
    pub fn len(&self) -> usize {
        self.grid.len()
    }

    /// Whether there is no core point.
    pub fn is_empty(&self) -> bool {
        self.grid.is_empty()
    }

    /// Memory held for the whole job: per-core-point state plus the largest chunk's scratch.
    pub fn bytes(&self) -> usize {
        self.grid.bytes()
            + self.station.capacity() * size_of::<Shifted>()
            + self.total.capacity() * size_of::<Running>()
            + self.scratch.bytes()
    }

    /// Starts a station: its cylinders begin empty.
    pub fn begin_station(&mut self) {
        self.station.fill(Shifted::default());
    }

    /// Takes a chunk of scan points already in the design frame.
    pub fn ingest(&mut self, points: &[Point3<f64>]) {
        let r = 0.5 * self.params.projection_diameter;
        let (r2, h) = (r * r, self.params.max_depth);
        self.grid.offer_slices(
            &mut self.scratch,
            &mut self.station,
            points,
            |p, n, qs, st| {
                add_inside(st, p, n, qs, r2, h);
            },
        );
    }

    /// The job's cylinders over the closed stations, in core point order (not the grid's, so
    /// that a state recorded by one build fits another): what [`Self::restore`] takes to go on
    /// from here.
    pub fn total_state(&self) -> Vec<Running> {
        let mut out = vec![Running::default(); self.total.len()];
        for (&id, r) in self.grid.ids().iter().zip(&self.total) {
            out[id as usize] = *r;
        }
        out
    }

    /// Goes on from `total`, a [`Self::total_state`] of the same core points; false (and
    /// nothing changed) when it has another length.
    pub fn restore(&mut self, total: &[Running]) -> bool {
        if total.len() != self.total.len() {
            return false;
        }
        for (&id, r) in self.grid.ids().iter().zip(self.total.iter_mut()) {
            *r = total[id as usize];
        }
        true
    }

    /// Closes a station: adds its cylinders to the job's and summarises the station alone.
    pub fn end_station(&mut self, registration_sigma: f64) -> StreamingSummary {
        let station: Vec<Running> = self.station.iter().map(Shifted::running).collect();
        for (t, s) in self.total.iter_mut().zip(&station) {
            t.merge(s);
        }
        self.summary_of(&station, registration_sigma)
    }

    /// The job's M3C2 over every closed station, with `registration_sigma` in the level of
    /// detection.
    pub fn total(&self, registration_sigma: f64) -> StreamingSummary {
        self.summary_of(&self.total, registration_sigma)
    }

    /// Every core point over the job so far, in core point order.
    pub fn results(&self, registration_sigma: f64) -> Vec<CoreResult> {
        // The grid's ids are the samples' indices in another order: placed back by them, not
        // sorted (sorting 100 k results was a fifth of the bunny job's serial end).
        let mut at = vec![0u32; self.grid.len()];
        for (i, &id) in self.grid.ids().iter().enumerate() {
            at[id as usize] = i as u32;
        }
        at.iter()
            .map(|&i| self.result(i as usize, &self.total[i as usize], registration_sigma))
            .collect()
    }

    fn result(&self, i: usize, r: &Running, reg: f64) -> CoreResult {
        let distance = (r.n > 0).then_some(r.mean);
        let spread = r.std();
        let lod = spread.map(|s| lod95(0.0, 0, s, r.n, reg));
        let significant = match (distance, lod) {
            (Some(d), Some(l)) => r.n >= self.params.min_points && d.abs() > l,
            _ => false,
        };
        CoreResult {
            sample: self.grid.ids()[i],
            position: self.grid.points()[i],
            normal: self.grid.normals()[i],
            distance,
            spread,
            count: r.n,
            lod95: lod,
            significant,
        }
    }

    fn summary_of(&self, state: &[Running], reg: f64) -> StreamingSummary {
        let mut s = StreamingSummary {
            core_points: state.len() as u64,
            ..Default::default()
        };
        let mut sum = 0.0;
        for (i, r) in state.iter().enumerate() {
            let c = self.result(i, r, reg);
            let Some(d) = c.distance else { continue };
            s.with_points += 1;
            s.significant += c.significant as u64;
            sum += d;
            s.min_distance = Some(s.min_distance.map_or(d, |m: f64| m.min(d)));
            s.max_distance = Some(s.max_distance.map_or(d, |m: f64| m.max(d)));
        }
        if s.with_points > 0 {
            s.mean_distance = Some(sum / s.with_points as f64);
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::shapes;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// The lanes count exactly what a test per point takes, and sum the same values (the AVX2
    /// lanes to the bit of the lanes one point at a time): runs of every length around the
    /// lanes', along random and axis normals, with points exactly on the caps and the rim
    /// (dyadic values, so that the ties are exact), and NaN; taken whole and cut in two, so
    /// that a run may start the sums or go on with them.
    #[test]
    fn lanes_take_what_point_tests_take() {
        let mut rng = crate::test_points::seeded(11);
        // Powers of two: on an axis normal a point on the rim or a cap ties exactly.
        let (r, h) = (2f64.powi(-9), 2f64.powi(-7));
        let p = Point3::new(0.25, -0.5, 1.0);
        let mut ties = 0;
        for trial in 0..400 {
            let axes = [Vector3::x(), -Vector3::y(), Vector3::z()];
            let n = match trial % 4 {
                0 => axes[trial / 4 % 3],
                _ => crate::test_points::random_points(&mut rng, 1, -1.0..1.0)[0]
                    .coords
                    .try_normalize(1e-6)
                    .unwrap_or(Vector3::z()),
            };
            let side = n
                .cross(&Vector3::x())
                .try_normalize(1e-6)
                .unwrap_or(Vector3::y());
            let len = trial % 101;
            let mut points = crate::test_points::random_points(&mut rng, len, -0.012..0.012)
                .into_iter()
                .map(|q| p + q.coords)
                .collect::<Vec<_>>();
            for (k, q) in points.iter_mut().enumerate().filter(|(k, _)| k % 7 == 3) {
                *q = match k % 4 {
                    0 => p + n * h,
                    1 => p - n * h + side * r,
                    2 => p + side * r + n * (h * 0.5),
                    _ => p + side * (r * 1.000001),
                };
            }
            if len > 5 {
                points[5] = Point3::new(f64::NAN, p.y, p.z);
            }
            let mut want = Shifted::default();
            for q in &points {
                let v = q - p;
                let a = v.dot(&n);
                if a.abs() <= h && v.norm_squared() - a * a <= r * r {
                    ties += usize::from(a.abs() == h || v.norm_squared() - a * a == r * r);
                    want.push(a);
                }
            }
            let mut coords = crate::probes::Coords::default();
            coords.extend(points.iter());
            for cut in [len, len / 3] {
                let run = |vector| {
                    let mut st = Shifted::default();
                    add_inside_in(&mut st, (&p, &n, r * r, h), coords.run(0..cut), vector);
                    add_inside_in(&mut st, (&p, &n, r * r, h), coords.run(cut..len), vector);
                    st
                };
                let got = run(crate::simd::has_avx2());
                // The AVX2 lanes give the bits of the lanes one point at a time.
                let bits = |s: &Shifted| (s.n, s.first.to_bits(), s.s1.to_bits(), s.s2.to_bits());
                assert_eq!(bits(&got), bits(&run(false)), "trial {trial}");
                assert_eq!((got.n, got.first.to_bits()), (want.n, want.first.to_bits()));
                // Values lie within 2h of the first: sums in another order agree to rounding.
                let tol = 1e-14 * f64::from(want.n) * h * h;
                assert!((got.s1 - want.s1).abs() <= tol * h.recip(), "trial {trial}");
                assert!((got.s2 - want.s2).abs() <= tol, "trial {trial}");
            }
        }
        assert!(ties > 100, "only {ties} points on a rim or cap");
    }

    /// M3C2 at samples `spacing` apart on a 1 m × 1 m box `height` high, at least 5 points a
    /// cylinder.
    fn on_box(
        height: f64,
        spacing: f64,
        projection_diameter: f64,
        max_depth: f64,
    ) -> StreamingM3c2 {
        let d = shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 1.0, height));
        let core = DesignSamples::generate(&d, spacing, 3).unwrap();
        let params = StreamingParams {
            projection_diameter,
            max_depth,
            min_points: 5,
        };
        StreamingM3c2::new(&core, params).unwrap()
    }

    #[test]
    fn a_raised_box_top_is_found_with_the_offset_and_a_lod_from_the_noise() {
        let mut m = on_box(0.5, 0.05, 0.04, 0.02);
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let sigma = 0.001;
        let noise = Normal::new(0.0, sigma).unwrap();
        // The top raised by 6 mm on x < 0.5, exact elsewhere; the sides are not scanned.
        let mut scan = Vec::new();
        for i in 0..500 {
            for j in 0..500 {
                let (x, y) = (i as f64 * 0.002 + 0.001, j as f64 * 0.002 + 0.001);
                let z = 0.5 + if x < 0.5 { 0.006 } else { 0.0 } + noise.sample(&mut rng);
                scan.push(Point3::new(x, y, z));
            }
        }
        m.begin_station();
        for c in scan.chunks(30_000) {
            m.ingest(c);
        }
        let reg = 0.0005;
        let summary = m.end_station(reg);
        let mut seen = 0;
        for r in m.results(reg) {
            let p = r.position;
            let on_top = (p.z - 0.5).abs() < 1e-9;
            if !on_top {
                // Sides: the top's points are out of their cylinders except at the rim.
                if p.z < 0.45 {
                    assert_eq!(r.count, 0, "{p}");
                }
                continue;
            }
            if (p.x - 0.5).abs() < 0.03 || p.x < 0.03 || p.x > 0.97 || p.y < 0.03 || p.y > 0.97 {
                continue;
            }
            seen += 1;
            let d = r.distance.unwrap();
            let truth = if p.x < 0.5 { 0.006 } else { 0.0 };
            // About 300 points per cylinder: the mean is good to a few σ/√n.
            assert!((d - truth).abs() < 0.0004, "{d} at {p}");
            let lod = r.lod95.unwrap();
            let expected = 1.96 * (sigma / (r.count as f64).sqrt() + reg);
            assert!(
                (lod - expected).abs() < 0.2 * expected,
                "{lod} vs {expected}"
            );
            assert_eq!(r.significant, p.x < 0.5, "at {p}");
            assert!((r.spread.unwrap() - sigma).abs() < 0.2 * sigma);
        }
        assert!(seen > 200);
        assert!(summary.significant > 0 && summary.with_points < summary.core_points);
        assert_eq!(m.total(reg), summary);
    }

    #[test]
    fn points_outside_the_cylinder_do_not_count_and_nothing_grows_with_the_scan() {
        let mut m = on_box(1.0, 0.1, 0.02, 0.01);
        let c = m.grid.points()[0];
        let n = m.grid.normals()[0];
        let t = n.cross(&Vector3::new(0.3, 0.5, 0.7)).normalize();
        let pts = [
            c + n * 0.005,             // inside
            c + n * 0.0101,            // beyond the depth
            c + t * 0.0099,            // on the rim, inside
            c + t * 0.0101,            // outside the radius
            c - n * 0.009 + t * 0.005, // inside, below
        ];
        m.begin_station();
        m.ingest(&pts);
        let before = m.bytes();
        for _ in 0..50 {
            m.ingest(&pts);
        }
        assert_eq!(m.bytes(), before);
        m.end_station(0.0);
        let id = m.grid.ids()[0];
        let r = m.results(0.0)[id as usize];
        assert_eq!(r.sample, id);
        assert_eq!(r.count, 51 * 3);
        let mean = (0.005 + 0.0 - 0.009) / 3.0;
        assert!((r.distance.unwrap() - mean).abs() < 1e-12);
    }
}
