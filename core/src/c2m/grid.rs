//! A sparse grid of candidate triangles near the design surface.
//!
//! For a cell with centre `c` and half-diagonal `r`, the triangle closest to any point `p` in the
//! cell satisfies `d(c, T) <= U + r`, where `U = min_T' max_corners d(corner, T')` bounds the
//! distance from any point of the cell to the surface (distance to a triangle is convex, so its
//! maximum over the cell is at a corner). Those triangles are the cell's candidates, sorted by
//! `d(c, T)`. At query time `d(p, T) >= d(c, T) - |p - c|`, so the scan over candidates stops as
//! soon as that lower bound exceeds the best distance found: most points test a handful.
//!
//! Cells are kept where `d(c, surface) <= band + r`, so every point within `band` of the surface
//! falls in a kept cell.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

use super::bvh::Bvh;
use super::triangle::Triangle;

/// Cells per axis are addressed with 21 bits each, packed into one u64 key.
const AXIS_BITS: u32 = 21;
const AXIS_MAX: i64 = (1 << AXIS_BITS) - 1;

pub struct Grid {
    origin: Point3<f64>,
    h: f64,
    inv_h: f64,
    band: f64,
    cells: FxHashMap<u64, (u32, u32)>,
    cand_tri: Vec<u32>,
    /// `d(c, T)`, rounded down to f32 so it stays a lower bound.
    cand_dist: Vec<f32>,
}

pub struct GridStats {
    pub cell_size: f64,
    pub band: f64,
    pub cells: usize,
    pub candidates: usize,
    pub bytes: usize,
}

impl Grid {
    pub fn build(triangles: &[Triangle], bvh: &Bvh, h: f64, band: f64) -> Self {
        let half_diag = 0.5 * 3f64.sqrt() * h;
        let reach = band + half_diag;
        let (mut lo, mut hi) = (
            Point3::from([f64::INFINITY; 3]),
            Point3::from([f64::NEG_INFINITY; 3]),
        );
        for t in triangles {
            let (a, b) = t.aabb();
            lo = lo.inf(&a);
            hi = hi.sup(&b);
        }
        let origin = lo - Vector3::repeat(reach + h);
        let inv_h = 1.0 / h;
        let grid = |p: &Point3<f64>| -> [i64; 3] {
            std::array::from_fn(|k| ((p[k] - origin[k]) * inv_h).floor() as i64)
        };
        let extent = grid(&(hi + Vector3::repeat(reach + h)));
        let fits = extent.iter().all(|&e| e <= AXIS_MAX);
        assert!(fits, "cell size too small for the design's extent");

        // Cells within reach of each triangle, found from the triangle's box and kept only if the
        // cell centre is within reach of the triangle itself.
        let mut keys: Vec<u64> = triangles
            .par_chunks(256)
            .flat_map_iter(|chunk| {
                let mut keys = Vec::new();
                for t in chunk {
                    let (a, b) = t.aabb();
                    let i0 = grid(&(a - Vector3::repeat(reach)));
                    let i1 = grid(&(b + Vector3::repeat(reach)));
                    let n = t.ab.cross(&t.ac).normalize();
                    for i in i0[0]..=i1[0] {
                        for j in i0[1]..=i1[1] {
                            for k in i0[2]..=i1[2] {
                                let c = center(&origin, h, [i, j, k]);
                                if n.dot(&(c - t.a)).abs() > reach {
                                    continue;
                                }
                                let (q, _) = t.closest_point(&c);
                                if (c - q).norm() <= reach {
                                    keys.push(pack([i, j, k]));
                                }
                            }
                        }
                    }
                }
                keys.sort_unstable();
                keys.dedup();
                keys
            })
            .collect();
        keys.par_sort_unstable();
        keys.dedup();

        let lists: Vec<Vec<(u32, f32)>> = keys
            .par_iter()
            .map_init(Vec::new, |scratch, &key| {
                candidates(triangles, bvh, &origin, h, half_diag, unpack(key), scratch)
            })
            .collect();

        let total: usize = lists.iter().map(Vec::len).sum();
        let mut cand_tri = Vec::with_capacity(total);
        let mut cand_dist = Vec::with_capacity(total);
        let mut cells = FxHashMap::default();
        cells.reserve(keys.len());
        for (key, list) in keys.iter().zip(lists) {
            cells.insert(*key, (cand_tri.len() as u32, list.len() as u32));
            for (t, d) in list {
                cand_tri.push(t);
                cand_dist.push(d);
            }
        }
        Self {
            origin,
            h,
            inv_h,
            band,
            cells,
            cand_tri,
            cand_dist,
        }
    }

    pub fn stats(&self) -> GridStats {
        GridStats {
            cell_size: self.h,
            band: self.band,
            cells: self.cells.len(),
            candidates: self.cand_tri.len(),
            bytes: self.cells.capacity() * (8 + 8 + 1) + self.cand_tri.len() * 8,
        }
    }

    pub fn band(&self) -> f64 {
        self.band
    }

    /// The key of the cell holding `p`, or `None` outside the grid.
    #[inline]
    pub fn key(&self, p: &Point3<f64>) -> Option<u64> {
        let mut ijk = [0i64; 3];
        for (k, v) in ijk.iter_mut().enumerate() {
            let f = ((p[k] - self.origin[k]) * self.inv_h).floor();
            if !(0.0..=AXIS_MAX as f64).contains(&f) {
                return None;
            }
            *v = f as i64;
        }
        Some(pack(ijk))
    }

    /// The candidate range of a cell, if the cell is near the surface.
    #[inline]
    pub fn cell(&self, key: u64) -> Option<(u32, u32)> {
        self.cells.get(&key).copied()
    }

    #[inline]
    pub fn cell_center(&self, key: u64) -> Point3<f64> {
        center(&self.origin, self.h, unpack(key))
    }

    #[inline]
    pub fn candidates_of(&self, range: (u32, u32)) -> (&[u32], &[f32]) {
        let (s, n) = (range.0 as usize, range.1 as usize);
        (&self.cand_tri[s..s + n], &self.cand_dist[s..s + n])
    }
}

fn candidates(
    triangles: &[Triangle],
    bvh: &Bvh,
    origin: &Point3<f64>,
    h: f64,
    half_diag: f64,
    ijk: [i64; 3],
    scratch: &mut Vec<(u32, f64)>,
) -> Vec<(u32, f32)> {
    let c = center(origin, h, ijk);
    let (_, d2) = bvh
        .closest(triangles, &c, f64::INFINITY, None)
        .expect("a design has at least one triangle");
    scratch.clear();
    bvh.within(triangles, &c, d2.sqrt() + 2.0 * half_diag, scratch);
    scratch.sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    // U: the smallest, over the nearest few triangles, of the farthest corner's distance.
    let corners: [Point3<f64>; 8] = std::array::from_fn(|m| {
        let s = |bit: usize| if m >> bit & 1 == 1 { 0.5 } else { -0.5 };
        c + Vector3::new(s(0), s(1), s(2)) * h
    });
    let mut upper = f64::INFINITY;
    for &(t, _) in scratch.iter().take(8) {
        let far = corners
            .iter()
            .map(|q| (q - triangles[t as usize].closest_point(q).0).norm())
            .fold(0.0, f64::max);
        upper = upper.min(far);
    }
    // Slack of a few ulps keeps rounding from dropping a triangle that ties.
    let limit = (upper + half_diag) * (1.0 + 1e-12) + 1e-15;
    scratch
        .iter()
        .take_while(|&&(_, d)| d <= limit)
        .map(|&(t, d)| (t, round_down(d)))
        .collect()
}

fn round_down(d: f64) -> f32 {
    let f = d as f32;
    if f as f64 > d { f.next_down() } else { f }
}

#[inline]
fn center(origin: &Point3<f64>, h: f64, ijk: [i64; 3]) -> Point3<f64> {
    Point3::new(
        origin.x + (ijk[0] as f64 + 0.5) * h,
        origin.y + (ijk[1] as f64 + 0.5) * h,
        origin.z + (ijk[2] as f64 + 0.5) * h,
    )
}

#[inline]
fn pack(ijk: [i64; 3]) -> u64 {
    (ijk[0] as u64) | ((ijk[1] as u64) << AXIS_BITS) | ((ijk[2] as u64) << (2 * AXIS_BITS))
}

#[inline]
fn unpack(key: u64) -> [i64; 3] {
    let m = AXIS_MAX as u64;
    [
        (key & m) as i64,
        ((key >> AXIS_BITS) & m) as i64,
        ((key >> (2 * AXIS_BITS)) & m) as i64,
    ]
}
