//! A terrestrial laser scanner on the robot: a spherical raster of rays (one vertical profile per
//! azimuth step, as a phase-based scanner turns its head), the nearest as-built surface on each
//! ray, range noise, incidence dropout and mixed pixels at edges.
//!
//! Rays are not cast one by one: each triangle is rasterised into the scanner's angular grid and
//! every pixel under it gets an exact ray–triangle test, keeping the nearest hit. The raster is
//! split into column strips that run in parallel, so a station costs tens of milliseconds.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

use asbuilt_protocol::{ScanPoint, ScanPointFlags};

use super::asbuilt::AsBuilt;

/// The scanner's optics and noise. Defaults follow a Z+F IMAGER 5010 at "middle" resolution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScannerModel {
    /// Angle between neighbouring rays, degrees (10,000 per turn).
    pub step_deg: f64,
    /// Lowest and highest elevation the head sees, degrees.
    pub min_elevation_deg: f64,
    /// Highest elevation the head sees, degrees.
    pub max_elevation_deg: f64,
    /// Closest range that returns, metres.
    pub min_range: f64,
    /// Farthest range that returns, metres.
    pub max_range: f64,
    /// Range noise σ = `range_sigma` + `range_sigma_per_m` · range, metres.
    pub range_sigma: f64,
    /// Range noise growing with range, metres per metre.
    pub range_sigma_per_m: f64,
    /// Returns thin out from this incidence angle on and vanish at `dropout_end_deg`.
    pub dropout_start_deg: f64,
    /// Incidence angle beyond which nothing returns, degrees.
    pub dropout_end_deg: f64,
    /// Probability that a pixel on an edge (a neighbour ≥ `edge_jump` farther or empty)
    /// returns a mixed range between the two surfaces.
    pub mixed_pixel_probability: f64,
    /// Range jump, metres, that makes a pixel an edge.
    pub edge_jump: f64,
}

impl Default for ScannerModel {
    fn default() -> Self {
        Self {
            step_deg: 0.036,
            min_elevation_deg: -60.0,
            max_elevation_deg: 90.0,
            min_range: 0.3,
            max_range: 187.0,
            range_sigma: 0.0003,
            range_sigma_per_m: 0.00002,
            dropout_start_deg: 70.0,
            dropout_end_deg: 88.0,
            mixed_pixel_probability: 0.05,
            edge_jump: 0.05,
        }
    }
}

/// A scan: points in the scanner frame, in scan-line order (column by column, bottom to top).
#[derive(Debug, Clone, Default)]
pub struct Scan {
    /// Points, scanner frame.
    pub points: Vec<ScanPoint>,
    /// Rays cast (pixels in the part's angular window) and how many returned nothing.
    pub rays: u64,
    /// Rays that returned nothing (beyond range, dropout, no surface).
    pub dropped: u64,
    /// Returns mixed between two surfaces at an edge.
    pub mixed: u64,
}

const STRIP: usize = 32;

struct Tri {
    a: Vector3<f64>,
    e1: Vector3<f64>,
    e2: Vector3<f64>,
    n: Vector3<f64>,
    cols: (i64, i64),
    rows: (i64, i64),
}

/// Scans `part` from `t_design_scanner` (the true pose). `seed` makes noise repeatable.
pub fn scan(
    part: &AsBuilt,
    t_design_scanner: &Isometry3<f64>,
    model: &ScannerModel,
    seed: u64,
) -> Scan {
    let inv = t_design_scanner.inverse();
    let v: Vec<Vector3<f64>> = part.vertices.iter().map(|p| (inv * p).coords).collect();
    if v.is_empty() {
        return Scan::default();
    }
    let step = model.step_deg.to_radians();
    let centre: Vector3<f64> = v.iter().sum::<Vector3<f64>>() / v.len() as f64;
    let az0 = centre.y.atan2(centre.x);
    let tris = facing_triangles(part, &v, az0, step, model);
    let Some(grid) = Grid::around(&tris, az0, step) else {
        return Scan::default();
    };
    let (range, hit) = depth_buffer(&tris, &grid, model);
    returns(&tris, &grid, (&range, &hit), model, seed)
}

/// The triangles facing the scanner inside its elevation window, each with the box of
/// pixels it covers in the angular grid (azimuth from `az0`, `step` radians a pixel).
fn facing_triangles(
    part: &AsBuilt,
    v: &[Vector3<f64>],
    az0: f64,
    step: f64,
    model: &ScannerModel,
) -> Vec<Tri> {
    let wrap = |a: f64| {
        let mut d = a - az0;
        while d > std::f64::consts::PI {
            d -= std::f64::consts::TAU;
        }
        while d <= -std::f64::consts::PI {
            d += std::f64::consts::TAU;
        }
        d
    };
    let angles = |p: &Vector3<f64>| (wrap(p.y.atan2(p.x)), p.z.atan2(p.xy().norm()));
    let (el_lo, el_hi) = (
        model.min_elevation_deg.to_radians(),
        model.max_elevation_deg.to_radians(),
    );
    part.triangles
        .par_iter()
        .filter_map(|t| {
            let [a, b, c] = t.map(|i| v[i as usize]);
            let (e1, e2) = (b - a, c - a);
            let n = e1.cross(&e2);
            // Back faces never give the first return of a closed surface.
            if n.dot(&a) >= 0.0 {
                return None;
            }
            let (mut az_lo, mut az_hi, mut el_min, mut el_max) =
                (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            for (p, q) in [(a, b), (b, c), (c, a)] {
                // Edges are arcs in angle space: sample long ones so the box holds them.
                let span = (p.normalize() - q.normalize()).norm();
                let k = (span / 1f64.to_radians()).ceil().max(1.0) as usize;
                for i in 0..k {
                    let (az, el) = angles(&(p + (q - p) * (i as f64 / k as f64)));
                    az_lo = az_lo.min(az);
                    az_hi = az_hi.max(az);
                    el_min = el_min.min(el);
                    el_max = el_max.max(el);
                }
            }
            if az_hi - az_lo > std::f64::consts::PI || el_max < el_lo || el_min > el_hi {
                return None;
            }
            Some(Tri {
                a,
                e1,
                e2,
                n: n.normalize(),
                cols: (
                    (az_lo / step).floor() as i64 - 1,
                    (az_hi / step).ceil() as i64 + 1,
                ),
                rows: (
                    (el_min.max(el_lo) / step).floor() as i64 - 1,
                    (el_max.min(el_hi) / step).ceil() as i64 + 1,
                ),
            })
        })
        .collect()
}

/// The pixels the part can cover: columns `c_lo..` and rows `r_lo..`, with each column's and
/// row's direction (sine, cosine) computed once.
struct Grid {
    step: f64,
    c_lo: i64,
    r_lo: i64,
    ncols: usize,
    nrows: usize,
    col_dir: Vec<(f64, f64)>,
    row_dir: Vec<(f64, f64)>,
}

impl Grid {
    /// The grid over every triangle's box; `None` without triangles.
    fn around(tris: &[Tri], az0: f64, step: f64) -> Option<Self> {
        if tris.is_empty() {
            return None;
        }
        let (mut c_lo, mut c_hi, mut r_lo, mut r_hi) = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
        for t in tris {
            c_lo = c_lo.min(t.cols.0);
            c_hi = c_hi.max(t.cols.1);
            r_lo = r_lo.min(t.rows.0);
            r_hi = r_hi.max(t.rows.1);
        }
        let ncols = (c_hi - c_lo + 1) as usize;
        let nrows = (r_hi - r_lo + 1) as usize;
        Some(Self {
            step,
            c_lo,
            r_lo,
            ncols,
            nrows,
            col_dir: (0..ncols)
                .map(|c| (az0 + (c_lo + c as i64) as f64 * step).sin_cos())
                .collect(),
            row_dir: (0..nrows)
                .map(|r| ((r_lo + r as i64) as f64 * step).sin_cos())
                .collect(),
        })
    }

    /// The ray of pixel (column, row), a unit vector in the scanner frame.
    fn dir(&self, c: usize, r: usize) -> Vector3<f64> {
        let ((sa, ca), (se, ce)) = (self.col_dir[c], self.row_dir[r]);
        Vector3::new(ce * ca, ce * sa, se)
    }
}

/// The nearest hit per pixel, column-major: its range (∞ for none) and its triangle. Column
/// strips run in parallel, each over the triangles whose box reaches it.
fn depth_buffer(tris: &[Tri], grid: &Grid, model: &ScannerModel) -> (Vec<f32>, Vec<u32>) {
    let (ncols, nrows) = (grid.ncols, grid.nrows);
    let mut range = vec![f32::INFINITY; ncols * nrows];
    let mut hit = vec![u32::MAX; ncols * nrows];
    let nstrips = ncols.div_ceil(STRIP);
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); nstrips];
    for (i, t) in tris.iter().enumerate() {
        let s0 = ((t.cols.0 - grid.c_lo).max(0) as usize) / STRIP;
        let s1 = (((t.cols.1 - grid.c_lo) as usize).min(ncols - 1)) / STRIP;
        for b in &mut bins[s0..=s1] {
            b.push(i as u32);
        }
    }
    range
        .par_chunks_mut(STRIP * nrows)
        .zip(hit.par_chunks_mut(STRIP * nrows))
        .zip(bins.par_iter())
        .enumerate()
        .for_each(|(s, ((rng_buf, hit_buf), bin))| {
            let first = s * STRIP;
            let width = rng_buf.len() / nrows;
            for &ti in bin {
                let t = &tris[ti as usize];
                let c0 = ((t.cols.0 - grid.c_lo).max(first as i64) as usize).max(first);
                let c1 = ((t.cols.1 - grid.c_lo) as usize).min(first + width - 1);
                for c in c0..=c1 {
                    let col = &mut rng_buf[(c - first) * nrows..(c - first + 1) * nrows];
                    let hits = &mut hit_buf[(c - first) * nrows..(c - first + 1) * nrows];
                    raster_column(
                        t,
                        ti,
                        grid,
                        c,
                        (model.min_range, model.max_range),
                        col,
                        hits,
                    );
                }
            }
        });
    (range, hit)
}

/// Triangle `t` (number `ti`) down column `c`: an exact ray test at every row it may cover,
/// keeping the nearest hit within `ranges` in the column's `range` and `hit`.
fn raster_column(
    t: &Tri,
    ti: u32,
    grid: &Grid,
    c: usize,
    (min_r, max_r): (f64, f64),
    range: &mut [f32],
    hit: &mut [u32],
) {
    let (sa, ca) = grid.col_dir[c];
    let step = grid.step;
    let r0 = (t.rows.0 - grid.r_lo).max(0) as usize;
    let r1 = ((t.rows.1 - grid.r_lo) as usize).min(grid.nrows - 1);
    // The column's rays lie in one vertical plane: the triangle meets it in a segment, whose
    // ends bound the rows worth testing.
    let m = Vector3::new(-sa, ca, 0.0);
    let vs = [t.a, t.a + t.e1, t.a + t.e2];
    let ds = vs.map(|v| m.dot(&v));
    if ds.iter().all(|&d| d > 0.0) || ds.iter().all(|&d| d < 0.0) {
        return;
    }
    let (mut el_a, mut el_b) = (f64::MAX, f64::MIN);
    for k in 0..3 {
        let (i, j) = (k, (k + 1) % 3);
        if (ds[i] <= 0.0) != (ds[j] <= 0.0) || ds[i] == 0.0 {
            let f = if ds[i] == ds[j] {
                0.0
            } else {
                ds[i] / (ds[i] - ds[j])
            };
            let p = vs[i] + (vs[j] - vs[i]) * f;
            let el = p.z.atan2(ca * p.x + sa * p.y);
            el_a = el_a.min(el);
            el_b = el_b.max(el);
        }
    }
    let lo = ((el_a / step).floor() as i64 - 1 - grid.r_lo).max(r0 as i64) as usize;
    let hi = ((el_b / step).ceil() as i64 + 1 - grid.r_lo).min(r1 as i64);
    if hi < lo as i64 {
        return;
    }
    // A triangle is convex: down a column its pixels are one run.
    let mut inside = false;
    for r in lo..=hi as usize {
        let d = grid.dir(c, r);
        // Möller–Trumbore, origin at the scanner.
        let p = d.cross(&t.e2);
        let det = t.e1.dot(&p);
        let inv_det = 1.0 / det;
        let s = -t.a;
        let u = s.dot(&p) * inv_det;
        let q = s.cross(&t.e1);
        let w = d.dot(&q) * inv_det;
        if det.abs() < 1e-18 || !(0.0..=1.0).contains(&u) || w < 0.0 || u + w > 1.0 {
            if inside {
                break;
            }
            continue;
        }
        inside = true;
        let dist = t.e2.dot(&q) * inv_det;
        if dist > min_r && dist < max_r && (dist as f32) < range[r] {
            range[r] = dist as f32;
            hit[r] = ti;
        }
    }
}

/// The points the scanner returns from the depth buffer: incidence dropout, mixed pixels at
/// edges and range noise, column by column with a generator per column so the result does
/// not depend on how rayon splits the work.
fn returns(
    tris: &[Tri],
    grid: &Grid,
    (range, hit): (&[f32], &[u32]),
    model: &ScannerModel,
    seed: u64,
) -> Scan {
    let (ncols, nrows) = (grid.ncols, grid.nrows);
    let optics = Optics {
        model,
        dropout_lo: model.dropout_start_deg.to_radians().cos(),
        dropout_hi: model.dropout_end_deg.to_radians().cos(),
    };
    let columns: Vec<(Vec<ScanPoint>, u64, u64)> = (0..ncols)
        .into_par_iter()
        .map(|c| {
            let mut rng =
                ChaCha8Rng::seed_from_u64(seed ^ (c as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            let mut pts = Vec::new();
            let (mut dropped, mut mixed) = (0, 0);
            for r in 0..nrows {
                let d0 = range[c * nrows + r];
                if !d0.is_finite() {
                    continue;
                }
                let t = &tris[hit[c * nrows + r] as usize];
                match one_return(t, grid, range, (c, r), d0, &optics, &mut rng) {
                    Return::Dropped => dropped += 1,
                    Return::Point(p, was_mixed) => {
                        mixed += u64::from(was_mixed);
                        pts.push(p);
                    }
                }
            }
            (pts, dropped, mixed)
        })
        .collect();
    let mut out = Scan {
        points: Vec::with_capacity(columns.iter().map(|c| c.0.len()).sum()),
        rays: (ncols * nrows) as u64,
        dropped: 0,
        mixed: 0,
    };
    for (pts, dropped, mixed) in columns {
        out.points.extend(pts);
        out.dropped += dropped;
        out.mixed += mixed;
    }
    out
}

/// What one pixel with a hit returns.
enum Return {
    /// Nothing: the incidence was too grazing.
    Dropped,
    /// A point, and whether it is a mixed pixel.
    Point(ScanPoint, bool),
}

/// The scanner's model, with its dropout bounds as the cosines of their incidence angles.
struct Optics<'m> {
    model: &'m ScannerModel,
    dropout_lo: f64,
    dropout_hi: f64,
}

/// Pixel (column, row) whose nearest hit is `t` at range `d0`: dropout by incidence, a mixed
/// range towards a farther neighbour at an edge, then range noise. Draws from `rng` in this
/// order, which fixes the points a seed gives.
fn one_return(
    t: &Tri,
    grid: &Grid,
    range: &[f32],
    (c, r): (usize, usize),
    d0: f32,
    optics: &Optics<'_>,
    rng: &mut ChaCha8Rng,
) -> Return {
    let (ncols, nrows) = (grid.ncols, grid.nrows);
    let (model, dropout_lo, dropout_hi) = (optics.model, optics.dropout_lo, optics.dropout_hi);
    let d = grid.dir(c, r);
    let cos_i = -t.n.dot(&d);
    if cos_i < dropout_lo {
        let p = ((dropout_lo - cos_i) / (dropout_lo - dropout_hi)).clamp(0.0, 1.0);
        if rng.random::<f64>() < p {
            return Return::Dropped;
        }
    }
    let mut dist = d0 as f64;
    let mut edge: Option<f64> = None;
    for (dc, dr) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
        let (cc, rr) = (c as i64 + dc, r as i64 + dr);
        if cc < 0 || rr < 0 || cc >= ncols as i64 || rr >= nrows as i64 {
            continue;
        }
        let o = range[cc as usize * nrows + rr as usize] as f64;
        if !o.is_finite() {
            edge = Some(edge.unwrap_or(dist + 0.5));
        } else if o - dist >= model.edge_jump {
            edge = Some(edge.map_or(o, |e: f64| e.min(o)));
        }
    }
    let mut mixed = false;
    if let Some(far) = edge
        && rng.random::<f64>() < model.mixed_pixel_probability
    {
        dist += rng.random::<f64>() * (far - dist);
        mixed = true;
    }
    let sigma = model.range_sigma + model.range_sigma_per_m * dist;
    let z: f64 = rand_distr::StandardNormal.sample(rng);
    dist += sigma * z;
    let p = d * dist;
    Return::Point(
        ScanPoint {
            xyz: [p.x as f32, p.y as f32, p.z as f32],
            intensity: (0.6 * cos_i / (1.0 + 0.01 * dist * dist)) as f32,
            flags: ScanPointFlags(0),
            returns: 0x11,
            _reserved: 0,
        },
        mixed,
    )
}

/// Where the robot takes the scanner after printing up to `top` (metres): `count` stations on
/// an ellipse around the part's footprint, `standoff` metres out from it and `lift` above the
/// top, looking level (the scanner's own frame has z up and azimuth zero along design x).
pub fn stations_around(
    lo: Point3<f64>,
    hi: Point3<f64>,
    top: f64,
    count: u32,
    standoff: f64,
    lift: f64,
) -> Vec<Isometry3<f64>> {
    let c = nalgebra::center(&lo, &hi);
    let (rx, ry) = (
        0.5 * (hi.x - lo.x) + standoff,
        0.5 * (hi.y - lo.y) + standoff,
    );
    (0..count)
        .map(|i| {
            let a = std::f64::consts::FRAC_PI_4
                + std::f64::consts::TAU * i as f64 / count.max(1) as f64;
            Isometry3::from_parts(
                Translation3::new(c.x + rx * a.cos(), c.y + ry * a.sin(), top + lift),
                UnitQuaternion::identity(),
            )
        })
        .collect()
}

/// The pose the scanner really had when the robot reports `nominal`: position noise of σ
/// metres, and in six-DoF mode an orientation noise of `sigma_rad`.
pub fn perturb(
    nominal: &Isometry3<f64>,
    sigma: f64,
    sigma_rad: f64,
    rng: &mut impl Rng,
) -> Isometry3<f64> {
    let n = Normal::new(0.0, 1.0).expect("unit normal");
    let mut g = || n.sample(rng);
    let dt = Vector3::new(g(), g(), g()) * sigma;
    let dr = UnitQuaternion::from_scaled_axis(Vector3::new(g(), g(), g()) * sigma_rad);
    Isometry3::from_parts(
        Translation3::from(nominal.translation.vector + dt),
        dr * nominal.rotation,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Part, as_built};

    fn quiet() -> ScannerModel {
        ScannerModel {
            range_sigma: 0.0,
            range_sigma_per_m: 0.0,
            mixed_pixel_probability: 0.0,
            dropout_start_deg: 89.9,
            dropout_end_deg: 90.0,
            ..ScannerModel::default()
        }
    }

    #[test]
    fn noise_free_points_lie_on_the_surface_they_hit() {
        let part = Part::wall();
        let m = as_built(&part, &[], 10).unwrap();
        let pose = Isometry3::translation(0.3, -2.0, 0.7);
        let s = scan(&m, &pose, &quiet(), 1);
        assert!(s.points.len() > 100_000, "{}", s.points.len());
        let (hx, hy, top) = (1.0, 0.0867, 0.2);
        for p in &s.points {
            let q = pose * Point3::new(p.xyz[0] as f64, p.xyz[1] as f64, p.xyz[2] as f64);
            // On the face toward the scanner (y = −hy), the top, or an end: never behind.
            let on_front = (q.y + hy).abs() < 1e-5;
            let on_top = (q.z - top).abs() < 1e-5;
            let on_end = (q.x.abs() - hx).abs() < 1e-5;
            assert!(on_front || on_top || on_end, "{q:?}");
            assert!(q.y < hy - 1e-3 || on_top);
        }
    }

    #[test]
    fn the_scan_matches_brute_force_ray_casting() {
        let part = Part::wall();
        let m = as_built(&part, &[], 5).unwrap();
        let pose = Isometry3::translation(-0.5, 1.5, 0.5);
        let model = ScannerModel {
            step_deg: 0.5,
            ..quiet()
        };
        let s = scan(&m, &pose, &model, 1);
        // Every returned ray, cast again against every triangle, hits at the same range.
        for p in &s.points {
            let d = Vector3::new(p.xyz[0] as f64, p.xyz[1] as f64, p.xyz[2] as f64);
            let r = d.norm();
            let dir = pose.rotation * (d / r);
            let o = pose.translation.vector;
            let mut best = f64::INFINITY;
            for t in &m.triangles {
                let [a, b, c] = t.map(|i| m.vertices[i as usize].coords - o);
                let (e1, e2) = (b - a, c - a);
                let pv = dir.cross(&e2);
                let det = e1.dot(&pv);
                if det.abs() < 1e-18 {
                    continue;
                }
                let u = (-a).dot(&pv) / det;
                let q = (-a).cross(&e1);
                let w = dir.dot(&q) / det;
                let tt = e2.dot(&q) / det;
                if (0.0..=1.0).contains(&u) && w >= 0.0 && u + w <= 1.0 && tt > 0.0 {
                    best = best.min(tt);
                }
            }
            assert!((best - r).abs() < 1e-5, "{best} vs {r}");
        }
        assert!(s.points.len() > 1000);
    }

    #[test]
    fn range_noise_has_the_configured_sigma_and_the_seed_repeats() {
        let part = Part::wall();
        let m = as_built(&part, &[], 10).unwrap();
        let pose = Isometry3::translation(0.0, -2.0, 0.15);
        let model = ScannerModel {
            range_sigma: 0.001,
            range_sigma_per_m: 0.0,
            mixed_pixel_probability: 0.0,
            ..ScannerModel::default()
        };
        let s = scan(&m, &pose, &model, 7);
        let front: Vec<f64> = s
            .points
            .iter()
            .map(|p| pose * Point3::new(p.xyz[0] as f64, p.xyz[1] as f64, p.xyz[2] as f64))
            .filter(|q| q.x.abs() < 0.3 && q.z > 0.05 && q.z < 0.15)
            .map(|q| q.y + 0.0867)
            .collect();
        let n = front.len() as f64;
        let mean = front.iter().sum::<f64>() / n;
        let sd = (front.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / n).sqrt();
        // Near-normal incidence: the range noise shows almost whole in y.
        assert!((sd - 0.001).abs() < 0.0001, "σ {sd}");
        assert!(mean.abs() < 0.0001);
        let again = scan(&m, &pose, &model, 7);
        assert_eq!(again.points, s.points);
    }
}
