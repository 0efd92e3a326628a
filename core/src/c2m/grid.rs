//! A sparse grid of candidate triangles for the points near the design surface.
//!
//! Scan points lie within a few millimetres of the surface. A cell of size `h` lists the
//! triangles that can be closest to a point of the cell within the band `b` (half a cell) of the
//! surface: a triangle closer than `b` to such a point is closer than `b` to the cell, and three
//! exact lower bounds of the distance from the cell to a triangle (from the centre less the
//! half-diagonal, between their boxes, from the triangle's plane) prune the rest. So a query whose
//! best candidate is within `b` is exact; beyond `b`, the best candidate bounds a BVH search. A
//! list valid for every point of the cell would have to reach as far as the farthest point of the
//! cell is from the surface, four to ten times as many candidates.
//!
//! Cells are kept where a point within `b` of the surface can fall: among the cells a triangle's
//! box and plane touch and their 26 neighbours, those whose list is not empty. Lists are sorted
//! by `d(c, T)`, kept in a byte rounded down, so a query stops as soon as `d(c, T) - |p - c|`
//! exceeds the best distance found. Each cell also keeps the top of its candidates, so a query
//! against the design cut at a height above it can use the list as it is.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

use super::bvh::{Bvh, Filter};
use super::mesh::Mesh;
use super::triangle::Lanes;
use crate::simd::avx2;

/// Cells per axis are addressed with 21 bits each, packed into one u64 key.
const AXIS_BITS: u32 = 21;
pub const AXIS_MAX: i64 = (1 << AXIS_BITS) - 1;
/// Longer lists are not kept: their cell is answered by the BVH, which bounds the memory of
/// pathological designs (hundreds of duplicates or slivers on one spot).
const MAX_LIST: usize = 255;
/// Cells whose lists are made at once: the block's lists are held beside the index until
/// appended (about 5 MB for a million-triangle design at this size).
const BUILD_BLOCK: usize = 16_384;
/// One cell in this many is sampled for the lengths of the lists.
const SAMPLE_EVERY: usize = 16;
/// Cells are kept where a point within this many cell sizes of the surface can fall; farther
/// points (a defect's, or the surroundings') go to the BVH.
pub const BAND: f64 = 0.5;

#[derive(Debug, Clone, Copy)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Cell {
    start: u32,
    /// 0: no list; the cell is answered by the BVH.
    len: u16,
    /// The highest vertex of the candidates, in steps of the design's height over 65,535 from
    /// its lowest point, rounded up (eight bytes a cell).
    top: u16,
}

impl Cell {
    #[inline]
    pub fn has_list(&self) -> bool {
        self.len > 0
    }
}

#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Grid {
    origin: Point3<f64>,
    /// The design's lowest z and the step of a cell's `top`.
    z0: f64,
    z_step: f64,
    h: f64,
    inv_h: f64,
    /// Candidate distance bytes per metre.
    inv_step: f64,
    cells: FxHashMap<u64, Cell>,
    cand: Vec<u32>,
    dist: Vec<u8>,
}

pub struct GridStats {
    pub cell_size: f64,
    pub cells: usize,
    pub candidates: usize,
    /// Cells whose list was too long to keep; the BVH answers them.
    pub bvh_cells: usize,
    pub bytes: usize,
}

impl Grid {
    /// Cells of size `h` or larger: the size grows by half until the surface takes at most
    /// `max_surface_cells` cells (and enumerating them stays within a multiple of that), so the
    /// memory is bounded whatever the triangles look like. The caller sized `h` so that the
    /// design's extent fits the key.
    pub fn build(
        mesh: &Mesh,
        bvh: &Bvh,
        mut h: f64,
        lo: Point3<f64>,
        hi: Point3<f64>,
        max_surface_cells: usize,
        max_candidates: usize,
    ) -> Self {
        // Sizes below `least` cannot hold the budget: they are stepped over without
        // enumerating their cells, through the same sizes, so the grid is the one the loop
        // would have built.
        let least = smallest_fitting(mesh, max_surface_cells);
        while h < least {
            h *= 1.5;
        }
        let (origin, keys) = loop {
            let origin = lo - Vector3::repeat(2.0 * h);
            let limit = 64.0 * max_surface_cells as f64;
            let emitted = emitted_estimate(mesh, &origin, h, limit);
            if emitted <= limit {
                let surface = surface_cells(mesh, &origin, h, limit);
                if surface.len() <= max_surface_cells {
                    break (origin, dilate(&surface));
                }
            }
            h *= 1.5;
        };
        let half_diag = 0.5 * 3f64.sqrt() * h;
        let inv_h = 1.0 / h;
        let z0 = lo.z;
        let z_step = ((hi.z - lo.z) / 65_000.0).max(f64::MIN_POSITIVE);
        let step = (BAND * h + half_diag) / 255.0;

        // The longest lists cost the most and save the least over the BVH: a sample of the
        // cells sets the longest list kept so that all of them fit the budget.
        let sample: Vec<usize> = keys
            .par_iter()
            .step_by(SAMPLE_EVERY)
            .map_init(Vec::new, |scratch, &key| {
                let c = center(&origin, h, unpack(key));
                candidates(mesh, bvh, &c, h, half_diag, step, MAX_LIST, scratch)
                    .map_or(0, |(t, _, _)| {
                        t.len().max(if t.is_empty() { MAX_LIST + 1 } else { 0 })
                    })
            })
            .collect();
        let kept = sample.iter().filter(|&&n| n > 0).count();
        let cells_expected = (kept * keys.len()).div_ceil(sample.len().max(1)) + 64;
        let (longest, expected) = longest_list(sample, keys.len(), max_candidates);
        // Lists are made a block of cells at a time and appended, so the build holds one
        // block's lists beside the index, not a second copy of all of them.
        let mut cand = Vec::with_capacity(expected + expected / 16 + 1024);
        let mut dist = Vec::with_capacity(cand.capacity());
        let mut cells = FxHashMap::default();
        cells.reserve(cells_expected);
        for block in keys.chunks(BUILD_BLOCK) {
            let lists: Vec<(u64, Vec<u32>, Vec<u8>, f32)> = block
                .par_iter()
                .map_init(Vec::new, |scratch, &key| {
                    let c = center(&origin, h, unpack(key));
                    candidates(mesh, bvh, &c, h, half_diag, step, longest, scratch)
                        .map(|(t, d, top)| (key, t, d, top))
                })
                .flatten()
                .collect();
            for (key, t, d, top) in lists {
                let cell = Cell {
                    start: cand.len() as u32,
                    len: t.len() as u16,
                    top: quantize_up(top as f64, z0, z_step),
                };
                cand.extend_from_slice(&t);
                dist.extend_from_slice(&d);
                cells.insert(key, cell);
            }
        }
        drop(keys);
        cand.shrink_to_fit();
        dist.shrink_to_fit();
        Self {
            origin,
            z0,
            z_step,
            h,
            inv_h,
            inv_step: 1.0 / step,
            cells,
            cand,
            dist,
        }
    }

    /// No cells: every key finds no cell and the band is empty, so every query goes to the BVH
    /// (the reference the grid is checked against).
    #[cfg(test)]
    pub fn empty() -> Self {
        Self {
            origin: Point3::origin(),
            z0: 0.0,
            z_step: f64::MIN_POSITIVE,
            h: 0.0,
            inv_h: 0.0,
            inv_step: 0.0,
            cells: FxHashMap::default(),
            cand: Vec::new(),
            dist: Vec::new(),
        }
    }

    pub fn stats(&self) -> GridStats {
        GridStats {
            cell_size: self.h,
            cells: self.cells.len(),
            candidates: self.cand.len(),
            bvh_cells: self.cells.values().filter(|c| !c.has_list()).count(),
            // hashbrown: a key, a value and a control byte per bucket.
            bytes: self.cells.capacity() * (size_of::<u64>() + size_of::<Cell>() + 1)
                + self.cand.len() * (size_of::<u32>() + size_of::<u8>()),
        }
    }

    /// A cell's candidates (internal triangles), nearest to its centre first.
    #[inline]
    pub fn candidates(&self, cell: &Cell) -> &[u32] {
        &self.cand[cell.start as usize..cell.start as usize + cell.len as usize]
    }

    /// The highest vertex of a cell's candidates, or above it.
    #[inline]
    pub fn top(&self, cell: &Cell) -> f64 {
        self.z0 + cell.top as f64 * self.z_step
    }

    /// Points within this distance of the surface always fall in a kept cell.
    pub fn band(&self) -> f64 {
        BAND * self.h
    }

    /// How far from `p` (in the cell with centre `c`) a list's best candidate is sure to be
    /// the closest triangle: a triangle left out of the list is farther than the band from the
    /// cell, and a path from `p` to it leaves the cell first, so it is farther from `p` than the
    /// band plus `p`'s depth in the cell. A margin far above rounding keeps the test exact.
    #[inline]
    pub fn sure_within(&self, c: &Point3<f64>, p: &Point3<f64>) -> f64 {
        let off = (p - c).abs().max();
        let depth = (0.5 * self.h - off).max(0.0);
        let margin = 1e-9 * (self.h + c.coords.amax());
        (BAND * self.h + depth - margin).max(BAND * self.h)
    }

    /// The key of the cell holding `p`, or `None` outside the grid (or not finite).
    #[inline]
    pub fn key(&self, p: &Point3<f64>) -> Option<u64> {
        let mut ijk = [0i64; 3];
        for (k, v) in ijk.iter_mut().enumerate() {
            let f = (p[k] - self.origin[k]) * self.inv_h;
            // Truncation is the floor from zero up, and needs no call into libm.
            if !(0.0..AXIS_MAX as f64 + 1.0).contains(&f) {
                return None;
            }
            *v = f as i64;
        }
        Some(pack(ijk))
    }

    #[inline]
    pub fn cell(&self, key: u64) -> Option<Cell> {
        self.cells.get(&key).copied()
    }

    #[inline]
    pub fn cell_center(&self, key: u64) -> Point3<f64> {
        center(&self.origin, self.h, unpack(key))
    }

    /// The closest candidate of `cell` to `p` (which lies in the cell with centre `c`) that
    /// `filter` keeps: internal triangle and squared distance, `None` when it keeps none. Ties go
    /// to the lowest design id. Candidates four at a time, nearest to the cell's centre first,
    /// until the next four cannot beat the best found. Measuring a few past that point changes
    /// nothing: the best is the closest, ties to the lowest id, whichever candidates were
    /// measured. A candidate is put to the filter only when it would beat the best, so `All`
    /// costs nothing and a cut a few triangles. Kept out of line: inlined into the query loop,
    /// the loop ran 20 % slower.
    #[inline(never)]
    pub fn closest<F: Filter>(
        &self,
        mesh: &Mesh,
        cell: &Cell,
        c: &Point3<f64>,
        p: &Point3<f64>,
        filter: &F,
    ) -> Option<(u32, f64)> {
        avx2!(<F: Filter> [
            grid: &Grid = self,
            mesh: &Mesh = mesh,
            cell: &Cell = cell,
            c: &Point3<f64> = c,
            p: &Point3<f64> = p,
            filter: &F = filter,
        ] -> Option<(u32, f64)> {
            const L: usize = 4;
            let dc = (p - c).norm();
            let (s, n) = (cell.start as usize, cell.len as usize);
            let (cand, dist) = (&grid.cand[s..s + n], &grid.dist[s..s + n]);
            let mut best: Option<(u32, f64)> = None;
            // The last distance byte that can still beat the best: `d(c, T) - |p - c| <= best` in
            // bytes, with margins of rounding so that a triangle that ties is not cut off. The loop
            // compares bytes, not metres.
            let mut last = u8::MAX;
            let mut lanes = Lanes::<L>::default();
            let mut i = 0;
            while i < n && dist[i] <= last {
                let m = (n - i).min(L);
                mesh.load(&mut lanes, &cand[i..i + m]);
                let d2 = lanes.dist2(p);
                // Most groups beat nothing: one comparison of the four says so, before the
                // lanes are taken in turn (a lane beats the best only at or under its d², and
                // a NaN never does).
                let beats = best.is_none_or(|(_, b)| d2[..m].iter().any(|&d| d <= b));
                if beats {
                    let mut improved = false;
                    for (&t, &d2) in cand[i..i + m].iter().zip(&d2) {
                        if super::better_internal(mesh, t, d2, best)
                            && filter.triangle(mesh, t as usize)
                        {
                            best = Some((t, d2));
                            improved = true;
                        }
                    }
                    // The bound follows the group's best, once a group: the last lane's
                    // improvement is the one that counted, and a root is slow.
                    if let Some((_, d2)) = best.filter(|_| improved) {
                        let stop = d2.sqrt() * (1.0 + 1e-12) + 1e-15;
                        let bytes = (stop + dc) * grid.inv_step * (1.0 + 1e-9) + 1e-9;
                        last = bytes.min(255.0) as u8;
                    }
                }
                i += m;
            }
            best
        })
    }
}

/// How many cell keys enumerating the surface would emit, at most (before duplicates go):
/// the cells of every piece's box.
fn emitted_estimate(mesh: &Mesh, origin: &Point3<f64>, h: f64, limit: f64) -> f64 {
    (0..mesh.len())
        .into_par_iter()
        .map_init(Vec::new, |stack, t| {
            let mut emitted = 0.0;
            pieces(mesh, t, origin, h, limit, stack, |_, i0, i1| {
                emitted += (0..3).map(|k| (i1[k] - i0[k] + 1) as f64).product::<f64>();
            });
            emitted
        })
        .sum()
}

/// A cell size below which the surface takes more than `max_surface_cells` cells for sure, so
/// the cells need not be enumerated to know it: a triangle's longest edge `L` crosses at least
/// `L / (√3 h)` cells (no cell holds more of a segment than its diagonal), and its area `A` at
/// least `A / (√2 h²)` (no plane cuts a cube in more than `√2 h²`). A slack of a millionth keeps
/// rounding on the safe side. Slivers and needles make the loop start far below it: a 12-
/// triangle STL of denormal needles spent half a second enumerating sizes that could not fit.
pub(super) fn smallest_fitting(mesh: &Mesh, max_surface_cells: usize) -> f64 {
    let cells = max_surface_cells as f64;
    let (longest, largest) = (0..mesh.len()).fold((0.0f64, 0.0f64), |(l, a), t| {
        let tri = mesh.triangle(t);
        let edge = tri
            .ab
            .norm()
            .max(tri.ac.norm())
            .max((tri.ac - tri.ab).norm());
        (l.max(edge), a.max(0.5 * tri.ab.cross(&tri.ac).norm()))
    });
    let by_edge = longest / (3f64.sqrt() * cells);
    let by_area = (largest / (2f64.sqrt() * cells)).sqrt();
    let least = by_edge.max(by_area) * (1.0 - 1e-6);
    if least.is_finite() { least } else { 0.0 }
}

/// The pieces a triangle's cells are enumerated in, each with the first and last cell of its
/// box. A sliver's box holds far more cells than the triangle meets (a 1 m needle on a
/// diagonal: 10^8 cells of 0.1 mm, where it meets 10^4), so a piece whose box holds more than
/// 8 times the cells it can meet is halved at its longest edge, until it is under a cell. A
/// triangle that can meet more than `limit` cells is not split: the cells are too small anyway.
fn pieces(
    mesh: &Mesh,
    t: usize,
    origin: &Point3<f64>,
    h: f64,
    limit: f64,
    stack: &mut Vec<[Point3<f64>; 3]>,
    mut each: impl FnMut(&[Point3<f64>; 3], [i64; 3], [i64; 3]),
) {
    let inv_h = 1.0 / h;
    let cell_of = |p: &Point3<f64>| -> [i64; 3] {
        std::array::from_fn(|k| ((p[k] - origin[k]) * inv_h).floor() as i64)
    };
    let tri = mesh.triangle(t);
    stack.clear();
    stack.push([tri.a, tri.a + tri.ab, tri.a + tri.ac]);
    let mut split = true;
    while let Some(p) = stack.pop() {
        let lo = p[0].inf(&p[1]).inf(&p[2]);
        let hi = p[0].sup(&p[1]).sup(&p[2]);
        let (i0, i1) = (cell_of(&lo), cell_of(&hi));
        let boxed: f64 = (0..3).map(|k| (i1[k] - i0[k] + 1) as f64).product();
        let edges = [p[1] - p[0], p[2] - p[1], p[0] - p[2]];
        let lengths = edges.map(|e| e.norm());
        let area = 0.5 * edges[0].cross(&edges[2]).norm();
        let meets = area * inv_h * inv_h + lengths.iter().sum::<f64>() * inv_h + 1.0;
        let longest = (0..3)
            .max_by(|&x, &y| lengths[x].total_cmp(&lengths[y]))
            .expect("three edges");
        // Whole, the triangle says whether splitting it could pay.
        split &= meets <= limit;
        if split && boxed > 8.0 * meets && lengths[longest] > h {
            let (u, v, w) = (longest, (longest + 1) % 3, (longest + 2) % 3);
            let mid = p[u] + 0.5 * (p[v] - p[u]);
            stack.push([p[u], mid, p[w]]);
            stack.push([mid, p[v], p[w]]);
        } else {
            each(&p, i0, i1);
        }
    }
}

/// The keys of the cells a triangle's box and plane both reach (a superset of the cells it
/// meets), sorted; a sliver by pieces (see [`pieces`]).
pub(super) fn surface_cells(mesh: &Mesh, origin: &Point3<f64>, h: f64, limit: f64) -> Vec<u64> {
    let mut surface: Vec<u64> = (0..mesh.len())
        .into_par_iter()
        .chunks(512)
        .flat_map_iter(|chunk| {
            let mut keys = Vec::new();
            let mut stack = Vec::new();
            for t in chunk {
                let tri = mesh.triangle(t);
                let n = tri.ab.cross(&tri.ac);
                // A face on a cell boundary (the design's lowest face always is) lies half a
                // cell from the centres on either side: a hair of slack keeps rounding from
                // dropping both, and the whole face's cells with them.
                let reach = 0.5 * h * (n.x.abs() + n.y.abs() + n.z.abs()) * (1.0 + 1e-9);
                pieces(mesh, t, origin, h, limit, &mut stack, |_, i0, i1| {
                    for i in i0[0]..=i1[0] {
                        for j in i0[1]..=i1[1] {
                            for k in i0[2]..=i1[2] {
                                let c = center(origin, h, [i, j, k]);
                                // A NaN from a huge design keeps the cell.
                                let off = n.dot(&(c - tri.a)).abs();
                                if off <= reach || off.is_nan() {
                                    keys.push(pack([i, j, k]));
                                }
                            }
                        }
                    }
                });
            }
            keys.sort_unstable();
            keys.dedup();
            keys
        })
        .collect();
    surface.par_sort_unstable();
    surface.dedup();
    surface
}

/// The cells a point within `h` of the surface can fall in: the surface cells and their 26
/// neighbours, sorted.
fn dilate(surface: &[u64]) -> Vec<u64> {
    let mut near: Vec<u64> = surface
        .par_chunks(4096)
        .flat_map_iter(|chunk| {
            let mut keys = Vec::with_capacity(chunk.len() * 27);
            for &key in chunk {
                let [i, j, k] = unpack(key);
                for di in -1..=1 {
                    for dj in -1..=1 {
                        for dk in -1..=1 {
                            keys.push(pack([i + di, j + dj, k + dk]));
                        }
                    }
                }
            }
            keys.sort_unstable();
            keys.dedup();
            keys
        })
        .collect();
    near.par_sort_unstable();
    near.dedup();
    near
}

/// The candidate list of the cell centred at `c`: the triangles that can be within the band
/// of some point of the cell (three exact lower bounds of their distance to the cell: from the
/// centre, between boxes, from the plane), sorted by distance from the centre, with their distance
/// bytes and the top of their vertices. `None` when no point of the cell is within the band, and
/// an empty list when the list would be longer than `longest`.
#[allow(clippy::too_many_arguments)]
fn candidates(
    mesh: &Mesh,
    bvh: &Bvh,
    c: &Point3<f64>,
    h: f64,
    half_diag: f64,
    step: f64,
    longest: usize,
    scratch: &mut Vec<(u32, f64)>,
) -> Option<(Vec<u32>, Vec<u8>, f32)> {
    let band = BAND * h;
    // Slack of a few ulps keeps rounding from dropping a triangle that ties.
    let reach = band * (1.0 + 1e-12) + 1e-15;
    let half = Vector3::repeat(0.5 * h);
    let (cell_lo, cell_hi) = (c - half, c + half);
    // Nodes are pruned against the cell grown by the reach, and a little more: the tests below
    // measure triangles rebuilt from a vertex and two edges, which can round past the vertices.
    let slack = Vector3::repeat(1.01 * reach + 1e-9 * (1.0 + c.coords.amax()));
    scratch.clear();
    bvh.within(
        mesh,
        c,
        band + half_diag,
        (cell_lo - slack, cell_hi + slack),
        scratch,
    );
    // The exact tests first, the sort over the triangles that pass: the list is the same.
    let mut top = f32::NEG_INFINITY;
    scratch.retain(|&(t, d)| {
        if d - half_diag > reach {
            return false;
        }
        let tri = mesh.triangle(t as usize);
        let (lo, hi) = tri.aabb();
        let gap2 = (0..3)
            .map(|k| {
                let g = (lo[k] - cell_hi[k]).max(cell_lo[k] - hi[k]).max(0.0);
                g * g
            })
            .sum::<f64>();
        if gap2 > reach * reach {
            return false;
        }
        let kept = match tri.ab.cross(&tri.ac).try_normalize(0.0) {
            Some(n) => {
                let slab = 0.5 * h * (n.x.abs() + n.y.abs() + n.z.abs());
                n.dot(&(c - tri.a)).abs() - slab <= reach
            }
            None => true,
        };
        if kept {
            top = top.max(round_up(hi.z));
        }
        kept
    });
    if scratch.len() > longest {
        return Some((Vec::new(), Vec::new(), f32::INFINITY));
    }
    scratch.sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    let mut tris = Vec::with_capacity(scratch.len());
    let mut dist = Vec::with_capacity(scratch.len());
    for &(t, d) in scratch.iter() {
        tris.push(t);
        dist.push((d / step).floor().min(255.0) as u8);
    }
    (!tris.is_empty()).then_some((tris, dist, top))
}

/// The longest list to keep so that the lists of all `cells` hold at most `budget` candidates,
/// and how many candidates they will hold, from the lengths of an even sample of them (a length
/// past [`MAX_LIST`] counts as too long).
fn longest_list(mut sample: Vec<usize>, cells: usize, budget: usize) -> (usize, usize) {
    if sample.is_empty() {
        return (MAX_LIST, 0);
    }
    sample.sort_unstable();
    let scale = cells as f64 / sample.len() as f64;
    let mut total = 0.0;
    let mut longest = 0;
    for &len in &sample {
        if len > MAX_LIST || total + len as f64 * scale > budget as f64 {
            break;
        }
        total += len as f64 * scale;
        longest = len;
    }
    (longest.max(1), total as usize)
}

/// `z` in steps of `step` above `z0`, rounded up: decoding gives `z` or more; `u16::MAX` (and
/// so every height) for what the steps do not reach.
fn quantize_up(z: f64, z0: f64, step: f64) -> u16 {
    let q = ((z - z0) / step).ceil() + 1.0;
    if q.is_finite() && q < u16::MAX as f64 {
        q.max(0.0) as u16
    } else {
        u16::MAX
    }
}

fn round_up(v: f64) -> f32 {
    let f = v as f32;
    if (f as f64) < v { f.next_up() } else { f }
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
    let m = AXIS_MAX as u64;
    (ijk[0] as u64 & m)
        | ((ijk[1] as u64 & m) << AXIS_BITS)
        | ((ijk[2] as u64 & m) << (2 * AXIS_BITS))
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
