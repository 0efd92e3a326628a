//! Signed cloud-to-mesh distance (C2M).
//!
//! The distance of a point to the design is the distance to its closest point on the surface;
//! the sign comes from the angle-weighted pseudo-normal of the feature (face, edge or vertex)
//! holding that closest point, so it is right at edges and corners. Positive is outside (excess
//! material), negative inside. Beyond the maximum distance a point has no match.
//!
//! Queries are exact: among equally close triangles the lowest index wins, in every path, so the
//! result is the same as [`C2mIndex::brute_force`] bit for bit and does not depend on how points
//! are split into chunks or threads.
//!
//! One index serves every printed height: [`C2mIndex::section`] prepares the cut at a height
//! (the triangles that cross it, clipped, and the cap that closes it), and
//! [`C2mIndex::query_cut`] answers as if the design had been cut there and indexed anew.

mod bvh;
mod grid;
mod mesh;
mod normals;
mod section;
#[cfg(test)]
mod tests;
pub mod triangle;

use std::borrow::Cow;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::design::Design;
use crate::order;
use bvh::{All, Below, Bvh, Filter};
use grid::{AXIS_MAX, Cell, Grid};
use mesh::{Mesh, NormalSource};
use triangle::Region;

pub use section::Section;

/// The closest design feature of a matched point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Closest {
    /// Signed distance, metres: positive outside the design, negative inside.
    pub distance: f64,
    /// The closest point on the design.
    pub point: Point3<f64>,
    /// The design's triangle; for a cut design, the triangle a clipped piece came from, or
    /// the design's triangle count plus the cap triangle's number.
    pub triangle: u32,
    /// Where on the triangle the closest point lies: its face, an edge or a vertex.
    pub region: Region,
}

/// The parameters of a C2M index.
#[derive(Debug, Clone, Copy)]
pub struct C2mParams {
    /// Points farther than this from the design have no match. Metres.
    pub max_distance: f64,
    /// Grid cell size, metres; `None` picks one from the design's triangle density.
    pub cell_size: Option<f64>,
}

impl C2mParams {
    /// Points matched up to `max_distance` metres, the cell size picked from the design.
    pub fn within(max_distance: f64) -> Self {
        Self {
            max_distance,
            cell_size: None,
        }
    }
}

impl Default for C2mParams {
    fn default() -> Self {
        Self::within(0.05)
    }
}

/// A design that cannot be indexed with the parameters given.
#[derive(Debug, thiserror::Error)]
pub enum C2mError {
    /// The maximum distance is not a positive number.
    #[error("maximum distance must be a positive number of metres, got {0}")]
    MaxDistance(f64),
    /// The cell size is not a positive number.
    #[error("cell size must be a positive number of metres, got {0}")]
    CellSize(f64),
    /// The design is too large for the grid's cell addresses (wrong units, most likely).
    #[error(
        "the design is {extent} m across: coordinates that large cannot be indexed; check the \
         design's units"
    )]
    Extent {
        /// The design's largest extent, metres.
        extent: f64,
    },
}

/// What the index costs; reported so that a memory budget can be checked.
#[derive(Debug, Clone, Copy)]
pub struct IndexStats {
    /// Triangles indexed.
    pub triangles: usize,
    /// The grid's cell size, metres.
    pub cell_size: f64,
    /// Points within this distance of the design are answered by the grid.
    pub band: f64,
    /// Cells the grid keeps.
    pub cells: usize,
    /// Candidate triangles over every kept cell's list.
    pub candidates: usize,
    /// Cells whose candidate list was too long to keep (the BVH answers them).
    pub bvh_cells: usize,
    /// Memory of the whole index (grid, lists, BVH, mesh), bytes.
    pub bytes: usize,
}

#[derive(Debug, Clone, Copy, Default)]
struct CellCache {
    key: u64,
    cell: Option<Cell>,
    center: Point3<f64>,
    valid: bool,
}

/// Per-thread state that lets consecutive, nearby points reuse the previous lookup.
#[derive(Debug, Clone, Copy, Default)]
pub struct Cursor {
    cell: CellCache,
    /// Internal triangle of the previous match.
    last: Option<u32>,
    section_cell: CellCache,
    section_last: Option<u32>,
    /// Whether a cell's list keeps any triangle wholly below a cut: cell key, the cut's bits.
    kept_below: Option<(u64, u64, bool)>,
}

/// A design prepared for C2M queries. Built once per design and maximum distance.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct C2mIndex {
    mesh: Mesh,
    bvh: Bvh,
    grid: Grid,
    max_distance: f64,
    lowest: f64,
    highest: f64,
}

/// Whether an index keeps a grid of candidate lists or answers every point from its BVH.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum GridUse {
    Cells,
    /// The reference the grid's answers are checked against.
    #[cfg(test)]
    BvhOnly,
}

/// Batches smaller than this are queried as they come; larger ones in no spatial order are
/// sorted in blocks of `SORT_BLOCK` points (256 k: 4.1 M points/s on a shuffled bunny where 64 k
/// blocks give 3.8 M, about 20 MB held beside the batch).
const SORT_MIN: usize = 1 << 15;
const SORT_BLOCK: usize = 1 << 18;

/// Cells of this many times the triangles' mean size: lists of a few candidates.
const CELL_PER_TRIANGLE: f64 = 1.5;
/// At most this many cells on the surface per triangle, whatever the triangles look like
/// (slivers, duplicates, long thin faces): the cell size grows until it holds.
const SURFACE_CELLS_PER_TRIANGLE: f64 = 0.5;
/// At least about this many cells on the surface, however few and large the triangles.
const MIN_SURFACE_CELLS: f64 = 2048.0;
/// At most this many candidates in the cells' lists per triangle (5 bytes each): the longest
/// lists are left to the BVH beyond it.
const CANDIDATES_PER_TRIANGLE: f64 = 14.0;

impl C2mIndex {
    /// Indexes `design` for queries up to `params.max_distance` from it, in parallel.
    pub fn build(design: &Design, params: C2mParams) -> Result<Self, C2mError> {
        Self::build_mesh(
            design.vertices.clone(),
            Cow::Borrowed(&design.triangles),
            NormalSource::Own,
            params,
            GridUse::Cells,
        )
    }

    /// [`C2mIndex::build`] for a caller done with the design: its vertices become the index's
    /// and its triangles go once the index has its own copy, so a large design is not held
    /// twice while the grid is built (24 bytes a triangle less at the peak).
    pub fn from_design(design: Design, params: C2mParams) -> Result<Self, C2mError> {
        Self::build_mesh(
            design.vertices,
            Cow::Owned(design.triangles),
            NormalSource::Own,
            params,
            GridUse::Cells,
        )
    }

    fn build_mesh(
        vertices: Vec<Point3<f64>>,
        triangles: Cow<'_, [[u32; 3]]>,
        normals: NormalSource,
        params: C2mParams,
        grid_use: GridUse,
    ) -> Result<Self, C2mError> {
        if !(params.max_distance > 0.0 && params.max_distance.is_finite()) {
            return Err(C2mError::MaxDistance(params.max_distance));
        }
        if let Some(h) = params.cell_size
            && !(h > 0.0 && h.is_finite())
        {
            return Err(C2mError::CellSize(h));
        }
        let (bvh, order) = Bvh::build(&vertices, &triangles);
        let mesh = Mesh::new(vertices, &triangles, &order, normals);
        drop((order, triangles));
        let (lo, hi) = bounds(&mesh);
        let extent = (hi - lo).max();
        if !extent.is_finite() || extent > 1e7 {
            return Err(C2mError::Extent { extent });
        }
        let grid = match grid_use {
            GridUse::Cells => {
                let h = cell_size(&mesh, params.cell_size, extent);
                let budget = if params.cell_size.is_some() {
                    usize::MAX
                } else {
                    (SURFACE_CELLS_PER_TRIANGLE * mesh.len() as f64) as usize + 4096
                };
                let candidates = (CANDIDATES_PER_TRIANGLE * mesh.len() as f64) as usize + 65_536;
                Grid::build(&mesh, &bvh, h, lo, hi, budget, candidates)
            }
            #[cfg(test)]
            GridUse::BvhOnly => Grid::empty(),
        };
        Ok(Self {
            mesh,
            bvh,
            grid,
            max_distance: params.max_distance,
            lowest: lo.z,
            highest: hi.z,
        })
    }

    /// Points farther than this from the design have no match, metres.
    pub fn max_distance(&self) -> f64 {
        self.max_distance
    }

    /// Number of design triangles.
    pub fn triangles(&self) -> usize {
        self.mesh.len()
    }

    /// The design's lowest and highest z, metres.
    pub fn z_range(&self) -> (f64, f64) {
        (self.lowest, self.highest)
    }

    /// What the index holds and costs.
    pub fn stats(&self) -> IndexStats {
        let g = self.grid.stats();
        IndexStats {
            triangles: self.mesh.len(),
            cell_size: g.cell_size,
            band: self.grid.band(),
            cells: g.cells,
            candidates: g.candidates,
            bvh_cells: g.bvh_cells,
            bytes: g.bytes + self.mesh.bytes() + self.bvh.bytes(),
        }
    }

    /// The closest design feature of `p`, or `None` when it is farther than the maximum
    /// distance (or not finite).
    #[inline(never)]
    pub fn query(&self, p: &Point3<f64>, cursor: &mut Cursor) -> Option<Closest> {
        crate::simd::avx2!([
            index: &C2mIndex = self,
            p: &Point3<f64> = p,
            cursor: &mut Cursor = cursor,
        ] -> Option<Closest> {
            index.query_inline(p, cursor)
        })
    }

    /// [`C2mIndex::query`], compiled into its caller.
    #[inline(always)]
    fn query_inline(&self, p: &Point3<f64>, cursor: &mut Cursor) -> Option<Closest> {
        let limit2 = self.max_distance * self.max_distance;
        let (t, d2) = self.closest(p, &mut cursor.cell, cursor.last, limit2)?;
        if d2 > limit2 {
            return None;
        }
        cursor.last = Some(t);
        Some(self.signed(p, t))
    }

    /// The closest triangle (internal) and squared distance, from the grid where `p` is near
    /// the surface, else from the BVH under `limit2`.
    #[inline(always)]
    fn closest(
        &self,
        p: &Point3<f64>,
        cache: &mut CellCache,
        hint: Option<u32>,
        limit2: f64,
    ) -> Option<(u32, f64)> {
        match self.cell_of(p, cache) {
            Some(cell) if cell.has_list() => {
                let best = self.grid.closest(&self.mesh, &cell, &cache.center, p, &All);
                self.confirm(p, &cache.center, best, hint, limit2, &All)
            }
            found => self.closest_far(p, found.is_some(), hint, limit2, &All),
        }
    }

    /// The kept cell holding `p`, through the cache.
    #[inline(always)]
    fn cell_of(&self, p: &Point3<f64>, cache: &mut CellCache) -> Option<Cell> {
        let key = self.grid.key(p)?;
        if !(cache.valid && cache.key == key) {
            *cache = CellCache {
                key,
                cell: self.grid.cell(key),
                center: self.grid.cell_center(key),
                valid: true,
            };
        }
        cache.cell
    }

    /// A cell's best candidate (of those `filter` keeps) is the closest when it lies within the
    /// grid's band, or deeper in the cell by as much as `p` is ([`Grid::sure_within`]): every
    /// triangle left out of the list is farther. So when even `limit2` is that near, nothing
    /// beyond the list can come under it. Otherwise the BVH searches, bounded by the best.
    #[inline]
    fn confirm<F: bvh::Filter>(
        &self,
        p: &Point3<f64>,
        center: &Point3<f64>,
        best: Option<(u32, f64)>,
        hint: Option<u32>,
        limit2: f64,
        filter: &F,
    ) -> Option<(u32, f64)> {
        let band = self.grid.band();
        if let Some((_, d2)) = best
            && d2 <= band * band
        {
            return best;
        }
        let sure = self.grid.sure_within(center, p);
        let sure2 = sure * sure;
        match best {
            Some((_, d2)) if d2 <= sure2 => best,
            // The list's best is beyond `sure` too, so beyond the limit.
            _ if limit2 <= sure2 => None,
            Some((t, d2)) => self
                .bvh
                .closest(&self.mesh, p, limit2.min(d2), Some(t), filter),
            None => self.bvh.closest(&self.mesh, p, limit2, hint, filter),
        }
    }

    /// The BVH's answer for a point the grid's lists do not cover. A point outside every kept
    /// cell is farther than the grid's band from the surface.
    fn closest_far<F: bvh::Filter>(
        &self,
        p: &Point3<f64>,
        in_kept_cell: bool,
        hint: Option<u32>,
        limit2: f64,
        filter: &F,
    ) -> Option<(u32, f64)> {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return None;
        }
        let band = self.grid.band();
        if !in_kept_cell && band * band >= limit2 {
            return None;
        }
        self.bvh.closest(&self.mesh, p, limit2, hint, filter)
    }

    /// The closest feature of `p` on the design cut at `section`'s height and closed by its
    /// cap: what [`C2mIndex::query`] on an index of `crate::layers::cut_at`'s mesh gives, to
    /// rounding.
    #[inline(never)]
    pub fn query_cut(
        &self,
        p: &Point3<f64>,
        cursor: &mut Cursor,
        section: &Section,
    ) -> Option<Closest> {
        crate::simd::avx2!([
            index: &C2mIndex = self,
            p: &Point3<f64> = p,
            cursor: &mut Cursor = cursor,
            section: &Section = section,
        ] -> Option<Closest> {
            index.query_cut_inline(p, cursor, section)
        })
    }

    /// [`C2mIndex::query_cut`], compiled into its caller.
    #[inline(always)]
    fn query_cut_inline(
        &self,
        p: &Point3<f64>,
        cursor: &mut Cursor,
        section: &Section,
    ) -> Option<Closest> {
        let h = section.height();
        let limit2 = self.max_distance * self.max_distance;
        // The cut design lies at or below the cut.
        if p.z - h > self.max_distance || p.z.is_nan() {
            return None;
        }
        let cap = section.closest(p, cursor, limit2);
        let bound2 = cap.map_or(limit2, |c| c.1);
        // The design's triangles that cross the cut are the section's, clipped: the whole
        // design answers for those wholly below it.
        let below = Below(h);
        let whole = match self.cell_of(p, &mut cursor.cell) {
            Some(cell) if cell.has_list() => {
                let center = &cursor.cell.center;
                // Every candidate below the cut needs no filter; with none below, the filtered
                // search would measure every candidate to keep none.
                let best = if self.grid.top(&cell) < h {
                    self.grid.closest(&self.mesh, &cell, center, p, &All)
                } else if self.keeps_below(&cell, cursor.cell.key, &below, &mut cursor.kept_below) {
                    self.grid.closest(&self.mesh, &cell, center, p, &below)
                } else {
                    None
                };
                // The cap, when it is nearer, bounds the search: ties go to it anyway.
                self.confirm(p, center, best, cursor.last, bound2, &below)
            }
            found => self.closest_far(p, found.is_some(), cursor.last, bound2, &below),
        };
        // Ties go to the section: its normals know the cut.
        match (whole, cap) {
            (Some((t, d2)), c) if d2 <= limit2 && c.is_none_or(|c| d2 < c.1) => {
                cursor.last = Some(t);
                Some(self.signed(p, t))
            }
            (_, Some((t, d2))) if d2 <= limit2 => {
                cursor.section_last = Some(t);
                Some(section.signed(p, t))
            }
            _ => None,
        }
    }

    /// Whether `below` keeps any candidate of `cell` (key `key`), through the cursor's cache:
    /// a scan's points come cell by cell, so a cell's list is read once for many points.
    #[inline]
    fn keeps_below(
        &self,
        cell: &Cell,
        key: u64,
        below: &Below,
        cache: &mut Option<(u64, u64, bool)>,
    ) -> bool {
        let cut = below.0.to_bits();
        match *cache {
            Some((k, c, any)) if k == key && c == cut => any,
            _ => {
                let any = self
                    .grid
                    .candidates(cell)
                    .iter()
                    .any(|&t| below.triangle(&self.mesh, t as usize));
                *cache = Some((key, cut, any));
                any
            }
        }
    }

    /// Unit normal of design triangle `t`, outward for a consistently oriented mesh.
    pub fn face_normal(&self, t: u32) -> Vector3<f64> {
        match self.mesh.internal.get(t as usize) {
            Some(&i) => self.mesh.face_normal(i as usize),
            // A cap triangle of a cut design faces up.
            None => Vector3::z(),
        }
    }

    /// Whether the design blocks the line of sight from `eye` to `target`. Surface within
    /// `margin` of either end does not count, so a point on the design sees past its own face.
    pub fn blocks_sight(&self, eye: &Point3<f64>, target: &Point3<f64>, margin: f64) -> bool {
        self.blocks_sight_filtered(eye, target, margin, &All)
    }

    /// [`C2mIndex::blocks_sight`] for the design cut at `section`'s height.
    pub fn blocks_sight_cut(
        &self,
        eye: &Point3<f64>,
        target: &Point3<f64>,
        margin: f64,
        section: &Section,
    ) -> bool {
        self.blocks_sight_filtered(eye, target, margin, &Below(section.height()))
            || section.blocks_sight(eye, target, margin)
    }

    fn blocks_sight_filtered<F: bvh::Filter>(
        &self,
        eye: &Point3<f64>,
        target: &Point3<f64>,
        margin: f64,
        filter: &F,
    ) -> bool {
        let d = target - eye;
        let len = d.norm();
        if len.partial_cmp(&(2.0 * margin)) != Some(std::cmp::Ordering::Greater) {
            return false;
        }
        let dir = d / len;
        self.bvh
            .segment_blocked(&self.mesh, eye, &dir, margin, len - margin, filter)
    }

    /// Every triangle tested: the reference the fast path is checked against.
    pub fn brute_force(&self, p: &Point3<f64>) -> Option<Closest> {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return None;
        }
        let mut best: Option<(u32, f64)> = None;
        for t in 0..self.mesh.len() {
            let d2 = self.mesh.triangle(t).dist2(p);
            if better_internal(&self.mesh, t as u32, d2, best) {
                best = Some((t as u32, d2));
            }
        }
        let (t, d2) = best?;
        (d2 <= self.max_distance * self.max_distance).then(|| self.signed(p, t))
    }

    /// Queries a batch in parallel; `out[i]` answers `points[i]`. A batch in no spatial order
    /// (a merged or shuffled cloud) is queried block by block along a Morton curve, with the
    /// same results.
    pub fn query_batch(&self, points: &[Point3<f64>], out: &mut [Option<Closest>]) {
        assert_eq!(points.len(), out.len(), "one output per point");
        let position = |p: &Point3<f64>| {
            (p.x.is_finite() && p.y.is_finite() && p.z.is_finite()).then_some([p.x, p.y, p.z])
        };
        if points.len() < SORT_MIN || order::in_spatial_order(points, position) {
            return self.query_in_order(points, out);
        }
        let block = points.len().min(SORT_BLOCK);
        let mut sorted = Vec::with_capacity(block);
        let mut results = Vec::with_capacity(block);
        for (ps, os) in points.chunks(SORT_BLOCK).zip(out.chunks_mut(SORT_BLOCK)) {
            let order = order::morton_order(ps, position);
            order::gather(ps, &order, &mut sorted);
            results.clear();
            results.resize(ps.len(), None);
            self.query_in_order(&sorted, &mut results);
            order::put_back(&results, &order, os);
        }
    }

    fn query_in_order(&self, points: &[Point3<f64>], out: &mut [Option<Closest>]) {
        const TASK: usize = 4096;
        points
            .par_chunks(TASK)
            .zip(out.par_chunks_mut(TASK))
            .for_each(|(ps, os)| {
                crate::simd::avx2!([
                    index: &C2mIndex = self,
                    ps: &[Point3<f64>] = ps,
                    os: &mut [Option<Closest>] = os,
                ] -> () {
                    let mut cursor = Cursor::default();
                    for (p, o) in ps.iter().zip(os) {
                        *o = index.query_inline(p, &mut cursor);
                    }
                })
            });
    }

    /// The signed result for internal triangle `t`. Inlined, so that it is compiled for AVX2
    /// inside the query loop.
    #[inline(always)]
    fn signed(&self, p: &Point3<f64>, t: u32) -> Closest {
        let tri = self.mesh.triangle(t as usize);
        let (q, region) = tri.closest_point(p);
        let d = (p - q).norm();
        // A face's pseudo-normal is its unit normal: the unnormalised one gives the same sign
        // (p - q lies along it), without a square root and a division.
        let n = match region {
            Region::Face => tri.ab.cross(&tri.ac),
            _ => self.mesh.pseudo_normal(t as usize, region),
        };
        let distance = if (p - q).dot(&n) < 0.0 { -d } else { d };
        Closest {
            distance,
            point: q,
            triangle: self.mesh.ids[t as usize],
            region,
        }
    }
}

fn bounds(mesh: &Mesh) -> (Point3<f64>, Point3<f64>) {
    let mut lo = Point3::from([f64::INFINITY; 3]);
    let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
    for f in &mesh.faces {
        for &i in f {
            let v = mesh.vertices[i as usize];
            lo = lo.inf(&v);
            hi = hi.sup(&v);
        }
    }
    (lo, hi)
}

/// The first cell size tried: about the triangles' size, and never so small the extent
/// overflows the key. The grid grows it where the surface would take too many cells.
fn cell_size(mesh: &Mesh, given: Option<f64>, extent: f64) -> f64 {
    let min_address = extent / ((AXIS_MAX - 8) as f64) * 1.01;
    if let Some(h) = given {
        return h.max(min_address);
    }
    // Summed in order, on one thread: a parallel sum rounds by how the threads split it, and
    // moved the cell size, and with it the whole grid, from one run to the next.
    let area: f64 = (0..mesh.len())
        .map(|t| {
            let tri = mesh.triangle(t);
            0.5 * tri.ab.cross(&tri.ac).norm()
        })
        .sum();
    let h = CELL_PER_TRIANGLE * (area / mesh.len() as f64).sqrt();
    // A design of a few large faces (a wall of twelve triangles) would get cells as large as
    // its faces, each listing every face: cells small enough to tile its surface a few
    // thousand times tell a face from its neighbours at the cost of a few hundred kilobytes.
    let h = h.min((area / MIN_SURFACE_CELLS).sqrt());
    let h = h.max(min_address);
    if h > 0.0 && h.is_finite() {
        h
    } else {
        extent.max(1e-9)
    }
}

/// A surface that points are compared with: the whole design, or the design as printed up to a
/// height.
pub trait Surface: Sync {
    /// The closest feature of `p`, or `None` beyond the maximum distance (or not finite).
    fn closest(&self, p: &Point3<f64>, cursor: &mut Cursor) -> Option<Closest>;
    /// Points farther than this from the surface have no match, metres.
    fn max_distance(&self) -> f64;
    /// Whether the surface blocks the line of sight from `eye` to `target`, surface within
    /// `margin` of either end aside.
    fn blocks_sight(&self, eye: &Point3<f64>, target: &Point3<f64>, margin: f64) -> bool;
}

impl Surface for C2mIndex {
    #[inline]
    fn closest(&self, p: &Point3<f64>, cursor: &mut Cursor) -> Option<Closest> {
        self.query(p, cursor)
    }
    fn max_distance(&self) -> f64 {
        self.max_distance
    }
    fn blocks_sight(&self, eye: &Point3<f64>, target: &Point3<f64>, margin: f64) -> bool {
        C2mIndex::blocks_sight(self, eye, target, margin)
    }
}

/// Closer wins; among equally close triangles the lowest design id, so results never depend on
/// the order in which triangles are visited.
#[inline]
pub(crate) fn better_internal(mesh: &Mesh, t: u32, d2: f64, best: Option<(u32, f64)>) -> bool {
    match best {
        None => true,
        Some((bt, bd2)) => d2 < bd2 || (d2 == bd2 && mesh.ids[t as usize] < mesh.ids[bt as usize]),
    }
}
