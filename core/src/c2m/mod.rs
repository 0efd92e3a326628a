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

mod bvh;
mod grid;
mod normals;
pub mod triangle;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::design::Design;
use bvh::Bvh;
use grid::Grid;
use normals::PseudoNormals;
use triangle::{Region, Triangle};

/// The closest design feature of a matched point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Closest {
    /// Signed distance, metres: positive outside the design, negative inside.
    pub distance: f64,
    /// The closest point on the design.
    pub point: Point3<f64>,
    pub triangle: u32,
    pub region: Region,
}

#[derive(Debug, Clone, Copy)]
pub struct C2mParams {
    /// Points farther than this from the design have no match. Metres.
    pub max_distance: f64,
    /// Grid cell size, metres; `None` picks one from the design's edge length.
    pub cell_size: Option<f64>,
}

impl Default for C2mParams {
    fn default() -> Self {
        Self {
            max_distance: 0.05,
            cell_size: None,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum C2mError {
    #[error("maximum distance must be a positive number of metres, got {0}")]
    MaxDistance(f64),
    #[error("cell size must be a positive number of metres, got {0}")]
    CellSize(f64),
}

/// What the acceleration structure costs; reported so that a memory budget can be checked.
#[derive(Debug, Clone, Copy)]
pub struct IndexStats {
    pub triangles: usize,
    pub cell_size: f64,
    pub band: f64,
    pub cells: usize,
    pub candidates: usize,
    pub bytes: usize,
}

/// Per-thread state that lets consecutive, nearby points reuse the previous lookup.
#[derive(Debug, Clone, Copy, Default)]
pub struct Cursor {
    key: u64,
    range: Option<(u32, u32)>,
    valid: bool,
    last_triangle: Option<u32>,
}

/// A design prepared for C2M queries. Built once per design and maximum distance.
pub struct C2mIndex {
    triangles: Vec<Triangle>,
    faces: Vec<[u32; 3]>,
    normals: PseudoNormals,
    bvh: Bvh,
    grid: Grid,
    max_distance: f64,
}

/// The grid's band in cells: points this close to the surface take the grid path.
const BAND_CELLS: f64 = 1.5;
/// A cell budget that keeps the index within a few hundred MB for any design.
const MAX_CELLS: f64 = 4.0e6;

impl C2mIndex {
    pub fn build(design: &Design, params: C2mParams) -> Result<Self, C2mError> {
        if !(params.max_distance > 0.0 && params.max_distance.is_finite()) {
            return Err(C2mError::MaxDistance(params.max_distance));
        }
        if let Some(h) = params.cell_size
            && !(h > 0.0 && h.is_finite())
        {
            return Err(C2mError::CellSize(h));
        }
        let triangles: Vec<Triangle> = design
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| design.vertices[i as usize]);
                Triangle::new(a, b, c)
            })
            .collect();
        let normals = PseudoNormals::new(&design.vertices, &design.triangles);
        let bvh = Bvh::new(&triangles);

        let (lo, hi) = design.bounds();
        let extent = (hi - lo).max();
        let area = design.surface_area();
        let mut h = params
            .cell_size
            .unwrap_or_else(|| 0.5 * design.median_edge());
        // Cells ≈ area · 2 (band + r) / h³ with band = 1.5 h and r = 0.87 h.
        let min_h_budget = (2.0 * (BAND_CELLS + 0.87) * area / MAX_CELLS).sqrt();
        // 21 bits per axis address the cells; leave room for the margins.
        let min_h_address = (extent + 4.0 * params.max_distance) / ((1u64 << 20) as f64);
        h = h
            .max(min_h_budget)
            .max(min_h_address)
            .max(f64::MIN_POSITIVE);
        let band = (BAND_CELLS * h).min(params.max_distance);
        let grid = Grid::build(&triangles, &bvh, h, band);
        Ok(Self {
            triangles,
            faces: design.triangles.clone(),
            normals,
            bvh,
            grid,
            max_distance: params.max_distance,
        })
    }

    pub fn max_distance(&self) -> f64 {
        self.max_distance
    }

    pub fn stats(&self) -> IndexStats {
        let g = self.grid.stats();
        IndexStats {
            triangles: self.triangles.len(),
            cell_size: g.cell_size,
            band: g.band,
            cells: g.cells,
            candidates: g.candidates,
            bytes: g.bytes
                + self.triangles.len()
                    * (size_of::<Triangle>()
                        + size_of::<[u32; 3]>()
                        + size_of::<Vector3<f64>>() * 4)
                + self.normals.vertex.len() * size_of::<Vector3<f64>>()
                + self.bvh.bytes(),
        }
    }

    /// The closest design feature of `p`, or `None` when it is farther than the maximum
    /// distance (or not finite).
    #[inline]
    pub fn query(&self, p: &Point3<f64>, cursor: &mut Cursor) -> Option<Closest> {
        let key = self.grid.key(p);
        let found = match key {
            Some(key) => {
                if !(cursor.valid && cursor.key == key) {
                    cursor.key = key;
                    cursor.range = self.grid.cell(key);
                    cursor.valid = true;
                }
                match cursor.range {
                    Some(range) => Some(self.closest_in_cell(p, key, range)),
                    None => self.closest_far(p, cursor.last_triangle),
                }
            }
            None => self.closest_far(p, cursor.last_triangle),
        };
        let (t, d2) = found?;
        if d2 > self.max_distance * self.max_distance {
            return None;
        }
        cursor.last_triangle = Some(t);
        Some(self.signed(p, t))
    }

    /// Unit normal of design triangle `t`, outward for a consistently oriented mesh.
    pub fn face_normal(&self, t: u32) -> Vector3<f64> {
        self.normals.face[t as usize]
    }

    /// Whether the design blocks the line of sight from `eye` to `target`. Surface within
    /// `margin` of either end does not count, so a point on the design sees past its own face.
    pub fn blocks_sight(&self, eye: &Point3<f64>, target: &Point3<f64>, margin: f64) -> bool {
        let d = target - eye;
        let len = d.norm();
        if len.partial_cmp(&(2.0 * margin)) != Some(std::cmp::Ordering::Greater) {
            return false;
        }
        let dir = d / len;
        self.bvh
            .segment_blocked(&self.triangles, eye, &dir, margin, len - margin)
    }

    /// Every triangle tested: the reference the fast path is checked against.
    pub fn brute_force(&self, p: &Point3<f64>) -> Option<Closest> {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return None;
        }
        let mut best: Option<(u32, f64)> = None;
        for (t, tri) in self.triangles.iter().enumerate() {
            let d2 = (p - tri.closest_point(p).0).norm_squared();
            if better(t as u32, d2, best) {
                best = Some((t as u32, d2));
            }
        }
        let (t, d2) = best?;
        (d2 <= self.max_distance * self.max_distance).then(|| self.signed(p, t))
    }

    /// Queries a batch in parallel; `out[i]` answers `points[i]`.
    pub fn query_batch(&self, points: &[Point3<f64>], out: &mut [Option<Closest>]) {
        assert_eq!(points.len(), out.len(), "one output per point");
        const TASK: usize = 4096;
        points
            .par_chunks(TASK)
            .zip(out.par_chunks_mut(TASK))
            .for_each(|(ps, os)| {
                let mut cursor = Cursor::default();
                for (p, o) in ps.iter().zip(os) {
                    *o = self.query(p, &mut cursor);
                }
            });
    }

    #[inline]
    fn closest_in_cell(&self, p: &Point3<f64>, key: u64, range: (u32, u32)) -> (u32, f64) {
        let c = self.grid.cell_center(key);
        let dc = (p - c).norm();
        let (tris, dists) = self.grid.candidates_of(range);
        let mut best: Option<(u32, f64)> = None;
        let mut best_d = f64::INFINITY;
        for (&t, &lower) in tris.iter().zip(dists) {
            if lower as f64 - dc > best_d {
                break;
            }
            let d2 = (p - self.triangles[t as usize].closest_point(p).0).norm_squared();
            if better(t, d2, best) {
                best = Some((t, d2));
                best_d = d2.sqrt();
            }
        }
        best.expect("every kept cell has a candidate")
    }

    fn closest_far(&self, p: &Point3<f64>, hint: Option<u32>) -> Option<(u32, f64)> {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return None;
        }
        let limit = self.max_distance * self.max_distance;
        // A point outside the grid's band is at least `band` away: beyond the maximum distance
        // when the band reaches it.
        if self.grid.band() >= self.max_distance {
            return None;
        }
        self.bvh.closest(&self.triangles, p, limit, hint)
    }

    fn signed(&self, p: &Point3<f64>, t: u32) -> Closest {
        let (q, region) = self.triangles[t as usize].closest_point(p);
        let ti = t as usize;
        let n: Vector3<f64> = match region {
            Region::Face => self.normals.face[ti],
            Region::Edge(i) => self.normals.edge[ti][i as usize],
            Region::Vertex(i) => self.normals.vertex[self.faces[ti][i as usize] as usize],
        };
        let d = (p - q).norm();
        let distance = if (p - q).dot(&n) < 0.0 { -d } else { d };
        Closest {
            distance,
            point: q,
            triangle: t,
            region,
        }
    }
}

/// Closer wins; among equally close triangles the lowest index, so results never depend on the
/// order in which triangles are visited.
#[inline]
pub(crate) fn better(t: u32, d2: f64, best: Option<(u32, f64)>) -> bool {
    match best {
        None => true,
        Some((bt, bd2)) => d2 < bd2 || (d2 == bd2 && t < bt),
    }
}
