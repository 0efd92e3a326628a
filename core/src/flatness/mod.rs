//! Flatness as a surveyor measures it: a virtual straightedge laid on every planar face the
//! scans saw, along the layers and across them, at a standard's spans, and the gap under it
//! judged by the standard's table (DIN 18202 Table 3, ACI 117).
//!
//! Scan points matched to a face's triangles are averaged in cells of 5 mm in the face's plane
//! (memory grows with the face's area, never with the scan). The straightedge rests on bins
//! 10 mm long and 30 mm wide (a straightedge's width): each bin's mean height is the profile,
//! so a bin of n points carries the scanner's noise divided by √n and no single point can hold
//! the straightedge up, while a dent of a few centimetres keeps its depth. A position of the
//! straightedge counts where at least 70 % of its bins were measured.

mod dimensions;
mod faces;
mod standard;
mod straightedge;

pub use dimensions::{Dimension, DimensionKind, Plumb};
pub use faces::{Face, PlanarFaces};
pub use standard::{
    ACCEPTED, DimensionsStandard, FlatnessStandard, UnknownDimensionsStandard, UnknownStandard,
};
pub use straightedge::worst_gap;

use asbuilt_protocol::{DeviationFlags, PointDeviation};
use nalgebra::Point3;

/// The cell points are averaged in, metres.
pub const CELL: f64 = 0.005;
/// Faces smaller than this are not judged, m².
pub const MIN_FACE_AREA: f64 = 0.01;
/// The length of a bin along the straightedge, metres.
pub const BIN: f64 = 0.01;
/// The width of a lane the straightedge lies in, metres.
pub const LANE: f64 = 0.03;
/// The share of a straightedge's bins that must be measured for its position to count.
pub const MIN_FILLED: f64 = 0.7;
/// Views steeper than this (between the face's normal and the ray from the scanner) are left
/// out: at grazing incidence a point's range noise and mixed returns land across the surface.
pub const MAX_INCIDENCE_DEG: f64 = 75.0;
/// A face's cells at most; a larger face takes larger cells.
const MAX_CELLS: usize = 4 << 20;

/// Which way the straightedge lies on a face.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Along the layers (horizontal on a wall).
    Along,
    /// Across the layers.
    Across,
}

impl Direction {
    /// As report.json spells it.
    pub fn as_str(self) -> &'static str {
        match self {
            Direction::Along => "along_layers",
            Direction::Across => "across_layers",
        }
    }
}

/// The deepest gap under the straightedge at one span on one face and direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlatnessGap {
    /// The face, an index into [`PlanarFaces::faces`].
    pub face: u32,
    /// Which way the straightedge lay.
    pub direction: Direction,
    /// The span, metres.
    pub span: f64,
    /// The deepest gap, metres.
    pub gap: f64,
    /// The standard's limit at the span, metres.
    pub limit: f64,
    /// Where the gap is deepest, design frame.
    pub at: Point3<f64>,
}

impl FlatnessGap {
    /// Whether the gap is within the limit.
    pub fn passes(&self) -> bool {
        self.gap <= self.limit
    }
}

/// One face's cells: sums and counts of the points' heights off the plane.
#[derive(Debug, Clone)]
struct Cells {
    cell: f64,
    nu: usize,
    nv: usize,
    sum: Vec<f64>,
    count: Vec<u32>,
}

/// Scan points gathered per planar face, judged by a standard on demand.
#[derive(Debug, Clone)]
pub struct FlatnessGrid {
    faces: PlanarFaces,
    cells: Vec<Cells>,
    /// The height the part stands on: where heights are measured from.
    bed: f64,
}

impl FlatnessGrid {
    /// Empty cells over every planar face of `design` of [`MIN_FACE_AREA`] or more.
    pub fn new(design: &crate::Design) -> Self {
        let faces = PlanarFaces::of(design, MIN_FACE_AREA);
        let cells = faces
            .faces
            .iter()
            .map(|f| {
                let [su, sv] = f.size();
                let cell = CELL.max((su * sv / MAX_CELLS as f64).sqrt());
                let nu = (su / cell).ceil().max(1.0) as usize;
                let nv = (sv / cell).ceil().max(1.0) as usize;
                Cells {
                    cell,
                    nu,
                    nv,
                    sum: vec![0.0; nu * nv],
                    count: vec![0; nu * nv],
                }
            })
            .collect();
        Self {
            faces,
            cells,
            bed: design.bounds().0.z,
        }
    }

    /// The faces.
    pub fn faces(&self) -> &[Face] {
        &self.faces.faces
    }

    /// Bytes the cells take.
    pub fn bytes(&self) -> usize {
        self.cells.iter().map(|c| c.sum.len() * 12).sum()
    }

    /// Forgets every point (a new scan layer).
    pub fn clear(&mut self) {
        for c in &mut self.cells {
            c.sum.fill(0.0);
            c.count.fill(0);
        }
    }

    /// Adds a chunk's deviations of a station scanned from `origin` (design frame; `None`
    /// when unknown): each matched point goes to its triangle's face, unless the face was seen
    /// at more than [`MAX_INCIDENCE_DEG`] from there.
    pub fn add(&mut self, devs: &[PointDeviation], origin: Option<Point3<f64>>) {
        let min_cos = MAX_INCIDENCE_DEG.to_radians().cos();
        for d in devs {
            if d.flags.contains(DeviationFlags::REJECTED) || !d.distance.is_finite() {
                continue;
            }
            let Some(Some(f)) = self.faces.of_triangle.get(d.triangle as usize) else {
                continue;
            };
            let p = Point3::from(d.position);
            if let Some(o) = origin {
                let ray = o - p;
                let n = ray.norm();
                if n > 0.0 && ray.dot(&self.faces.faces[*f as usize].normal) < min_cos * n {
                    continue;
                }
            }
            self.add_point(*f as usize, &p);
        }
    }

    /// Adds a point to face `f`.
    pub fn add_point(&mut self, f: usize, p: &Point3<f64>) {
        let face = &self.faces.faces[f];
        let c = &mut self.cells[f];
        let [u, v, w] = face.coordinates(p);
        let iu = ((u - face.extent[0][0]) / c.cell).floor();
        let iv = ((v - face.extent[1][0]) / c.cell).floor();
        if iu < 0.0 || iv < 0.0 || iu >= c.nu as f64 || iv >= c.nv as f64 {
            return;
        }
        let k = iv as usize * c.nu + iu as usize;
        c.sum[k] += w;
        c.count[k] += 1;
    }

    /// The deepest gap on every face, in both directions, at each of `standard`'s spans that
    /// fit the face, where the scans saw enough of it.
    pub fn judge(&self, standard: &FlatnessStandard) -> Vec<FlatnessGap> {
        let mut out = Vec::new();
        for (f, face) in self.faces.faces.iter().enumerate() {
            let size = face.size();
            for (axis, direction) in [(0, Direction::Along), (1, Direction::Across)] {
                for span in standard.spans() {
                    if span > size[axis] + 1e-9 {
                        continue;
                    }
                    if let Some((gap, u, v)) = self.worst(f, axis, span) {
                        out.push(FlatnessGap {
                            face: f as u32,
                            direction,
                            span,
                            gap,
                            limit: standard.limit(span),
                            at: face.point(u, v),
                        });
                    }
                }
            }
        }
        out
    }

    /// The deepest gap on face `f` with the straightedge along `axis` (0: u, 1: v) at `span`,
    /// and the face coordinates of its deepest point.
    fn worst(&self, f: usize, axis: usize, span: f64) -> Option<(f64, f64, f64)> {
        let c = &self.cells[f];
        let face = &self.faces.faces[f];
        // Cells merged into bins: `ka` along the straightedge, `kl` across it.
        let ka = (BIN / c.cell).round().max(1.0) as usize;
        let kl = (LANE / c.cell).round().max(1.0) as usize;
        let (ku, kv) = if axis == 0 { (ka, kl) } else { (kl, ka) };
        let bin = ka as f64 * c.cell;
        let steps = (span / bin).round() as usize;
        let (nu, nv) = (c.nu.div_ceil(ku), c.nv.div_ceil(kv));
        let mut sum = vec![0.0; nu * nv];
        let mut count = vec![0u32; nu * nv];
        for iv in 0..c.nv {
            for iu in 0..c.nu {
                let (src, dst) = (iv * c.nu + iu, (iv / kv) * nu + iu / ku);
                sum[dst] += c.sum[src];
                count[dst] += c.count[src];
            }
        }
        let height = |iu: usize, iv: usize| {
            let n = count[iv * nu + iu];
            (n > 0).then(|| sum[iv * nu + iu] / n as f64)
        };
        let (lanes, along) = if axis == 0 { (nv, nu) } else { (nu, nv) };
        let mut best: Option<(f64, f64, f64)> = None;
        let mut profile = Vec::with_capacity(along);
        for lane in 0..lanes {
            profile.clear();
            profile.extend((0..along).map(|i| {
                if axis == 0 {
                    height(i, lane)
                } else {
                    height(lane, i)
                }
            }));
            if let Some((gap, i)) = worst_gap(&profile, steps, MIN_FILLED)
                && best.is_none_or(|b| gap > b.0)
            {
                let (iu, iv) = if axis == 0 { (i, lane) } else { (lane, i) };
                best = Some((
                    gap,
                    face.extent[0][0] + (iu as f64 + 0.5) * ku as f64 * c.cell,
                    face.extent[1][0] + (iv as f64 + 0.5) * kv as f64 * c.cell,
                ));
            }
        }
        best
    }
}

#[cfg(test)]
mod tests;
