//! Layer-aware comparison: the design as printed so far, and statistics per layer band.
//!
//! While printing, the part is only as tall as the layers laid so far. Comparing it with the
//! whole design would call every unprinted layer missing and every top layer wrong, so the
//! design is cut at the printed height and closed by a cap in the cut plane: the top of the
//! printed part is compared with the cap, the rest with the design below the cut.

use std::collections::HashMap;

use earcut::Earcut;
use nalgebra::Point3;

use crate::design::{Design, DesignError};
use crate::m3c2::Running;

/// What the cut produced besides the clipped design.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CutReport {
    /// Closed outlines in the cut plane, outer and holes.
    pub loops: usize,
    /// Triangles of the cap that closes the cut.
    pub cap_triangles: usize,
    /// Outline pieces that did not close (an open design): left without a cap.
    pub open_chains: usize,
}

/// A height the design cannot be cut at.
#[derive(Debug, thiserror::Error)]
pub enum CutError {
    /// The height is NaN or infinite.
    #[error("printed height {height} m is not a finite number")]
    Height {
        /// The height given.
        height: f64,
    },
    #[error(
        "printed height {height} m is at or below the design's lowest point ({lowest} m): \
         nothing is printed yet"
    )]
    /// Nothing of the design lies below the height.
    BelowDesign {
        /// The height given, metres.
        height: f64,
        /// The design's lowest point, metres.
        lowest: f64,
    },
    /// The cut mesh is empty.
    #[error("cut design: {0}")]
    Design(#[from] DesignError),
}

/// A point of the cut's outline: a design vertex exactly at the height, or where an edge
/// crosses it.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum CutVertex {
    Edge(u32, u32),
    Vertex(u32),
}

/// The part of `design` below `height` (z, metres), closed by a cap at the cut.
pub fn cut_at(design: &Design, height: f64) -> Result<(Design, CutReport), CutError> {
    if !height.is_finite() {
        return Err(CutError::Height { height });
    }
    let (lo, hi) = design.bounds();
    if height <= lo.z {
        return Err(CutError::BelowDesign {
            height,
            lowest: lo.z,
        });
    }
    if height > hi.z {
        return Ok((design.clone(), CutReport::default()));
    }
    let v = &design.vertices;
    let below = |i: u32| v[i as usize].z < height;
    let mut vertices = v.clone();
    let mut ids: HashMap<CutVertex, u32> = HashMap::new();
    let mut cut_point = |cv: CutVertex, vertices: &mut Vec<Point3<f64>>| -> u32 {
        *ids.entry(cv).or_insert_with(|| match cv {
            CutVertex::Vertex(i) => i,
            CutVertex::Edge(a, b) => {
                let (pa, pb) = (v[a as usize], v[b as usize]);
                let t = (height - pa.z) / (pb.z - pa.z);
                let mut p = pa + (pb - pa) * t;
                p.z = height;
                vertices.push(p);
                (vertices.len() - 1) as u32
            }
        })
    };
    let mut triangles = Vec::with_capacity(design.triangles.len());
    // Directed cut segments, in the cap's orientation (opposite to the side walls' edges).
    let mut segments: Vec<(u32, u32)> = Vec::new();
    for t in &design.triangles {
        let n_below = t.iter().filter(|&&i| below(i)).count();
        if n_below == 3 {
            triangles.push(*t);
            continue;
        }
        if n_below == 0 {
            continue;
        }
        let mut id = |cv: ClipVertex| match cv {
            ClipVertex::Keep(i) => i,
            ClipVertex::Cut(cv) => cut_point(cv, &mut vertices),
        };
        if let Some(s) = clip_below(*t, |i| v[i as usize].z, height, &mut id, &mut triangles) {
            segments.push(s);
        }
    }
    let mut report = CutReport::default();
    cap(&mut vertices, &segments, &mut triangles, &mut report);
    let cut = Design::from_indexed(vertices, triangles, 1.0)?;
    Ok((cut, report))
}

/// A vertex of a clipped triangle: one of its own below the cut, or where the cut meets it.
pub(crate) enum ClipVertex {
    Keep(u32),
    Cut(CutVertex),
}

/// Clips a triangle with some but not all vertices below `height` to the part below, fanned
/// into `triangles`; `id` names the clipped polygon's vertices. Returns the directed segment the
/// cut leaves in the cap's plane, in the cap's orientation.
pub(crate) fn clip_below(
    t: [u32; 3],
    z: impl Fn(u32) -> f64,
    height: f64,
    id: &mut impl FnMut(ClipVertex) -> u32,
    triangles: &mut Vec<[u32; 3]>,
) -> Option<(u32, u32)> {
    let below = |i: u32| z(i) < height;
    let mut poly: Vec<u32> = Vec::with_capacity(4);
    let (mut exit, mut entry) = (None, None);
    for k in 0..3 {
        let (a, b) = (t[k], t[(k + 1) % 3]);
        if below(a) {
            poly.push(id(ClipVertex::Keep(a)));
        }
        if below(a) != below(b) {
            let (lo_i, hi_i) = if below(a) { (a, b) } else { (b, a) };
            let cv = if z(hi_i) == height {
                CutVertex::Vertex(hi_i)
            } else {
                CutVertex::Edge(lo_i.min(hi_i), lo_i.max(hi_i))
            };
            let c = id(ClipVertex::Cut(cv));
            poly.push(c);
            if below(a) {
                exit = Some(c);
            } else {
                entry = Some(c);
            }
        }
    }
    for k in 1..poly.len() - 1 {
        triangles.push([poly[0], poly[k], poly[k + 1]]);
    }
    match (exit, entry) {
        (Some(x), Some(e)) if x != e => Some((e, x)),
        _ => None,
    }
}

/// Closes the outlines formed by `segments` with triangles facing +z.
pub(crate) fn cap(
    vertices: &mut Vec<Point3<f64>>,
    segments: &[(u32, u32)],
    triangles: &mut Vec<[u32; 3]>,
    report: &mut CutReport,
) {
    let loops = outline_loops(segments, report);
    report.loops = loops.len();
    let (outers, holes_of) = holes_by_outer(vertices, &loops);
    let mut earcut = Earcut::new();
    for &o in &outers {
        // The outer ring, then its holes, each a range of `ring`.
        let mut ring: Vec<u32> = loops[o].clone();
        let mut rings: Vec<std::ops::Range<usize>> = Vec::with_capacity(1 + holes_of.len());
        rings.push(0..ring.len());
        for &h in holes_of.get(&o).map(Vec::as_slice).unwrap_or(&[]) {
            let start = ring.len();
            ring.extend(&loops[h]);
            rings.push(start..ring.len());
        }
        cap_ring(vertices, (&ring, &rings), &mut earcut, triangles, report);
    }
}

/// The closed loops `segments` form, each at least a triangle; a chain that does not close is
/// counted in `report`.
fn outline_loops(segments: &[(u32, u32)], report: &mut CutReport) -> Vec<Vec<u32>> {
    let mut next: HashMap<u32, u32> = segments.iter().copied().collect();
    let mut loops: Vec<Vec<u32>> = Vec::new();
    let starts: Vec<u32> = segments.iter().map(|s| s.0).collect();
    for s in starts {
        let Some(mut cur) = next.remove(&s) else {
            continue;
        };
        let mut ring = vec![s];
        let closed = loop {
            if cur == s {
                break true;
            }
            ring.push(cur);
            match next.remove(&cur) {
                Some(n) => cur = n,
                None => break false,
            }
        };
        if closed && ring.len() >= 3 {
            loops.push(ring);
        } else {
            report.open_chains += 1;
        }
    }
    loops
}

/// The signed area of `ring` in the plan (shoelace): positive counter-clockwise.
fn plan_area(vertices: &[Point3<f64>], ring: &[u32]) -> f64 {
    let mut a = 0.0;
    for k in 0..ring.len() {
        let (p, q) = (
            vertices[ring[k] as usize],
            vertices[ring[(k + 1) % ring.len()] as usize],
        );
        a += p.x * q.y - q.x * p.y;
    }
    0.5 * a
}

/// Whether `pt` lies inside `ring` in the plan (even-odd crossings).
fn inside_in_plan(vertices: &[Point3<f64>], pt: &Point3<f64>, ring: &[u32]) -> bool {
    let mut c = false;
    for k in 0..ring.len() {
        let (p, q) = (
            vertices[ring[k] as usize],
            vertices[ring[(k + 1) % ring.len()] as usize],
        );
        if (p.y > pt.y) != (q.y > pt.y) && pt.x < p.x + (pt.y - p.y) / (q.y - p.y) * (q.x - p.x) {
            c = !c;
        }
    }
    c
}

/// Counter-clockwise loops bound material; clockwise loops are holes in the smallest
/// counter-clockwise loop that holds them. Returns the outer loops and each one's holes.
fn holes_by_outer(
    vertices: &[Point3<f64>],
    loops: &[Vec<u32>],
) -> (Vec<usize>, HashMap<usize, Vec<usize>>) {
    let areas: Vec<f64> = loops.iter().map(|r| plan_area(vertices, r)).collect();
    let outers: Vec<usize> = (0..loops.len()).filter(|&i| areas[i] > 0.0).collect();
    let mut holes_of: HashMap<usize, Vec<usize>> = HashMap::new();
    for h in (0..loops.len()).filter(|&i| areas[i] < 0.0) {
        let probe = vertices[loops[h][0] as usize];
        if let Some(&o) = outers
            .iter()
            .filter(|&&o| inside_in_plan(vertices, &probe, &loops[o]))
            .min_by(|&&a, &&b| areas[a].total_cmp(&areas[b]))
        {
            holes_of.entry(o).or_default().push(h);
        }
    }
    (outers, holes_of)
}

/// One outer loop with its holes (`ring`, split in `rings`), ear-cut into triangles facing +z.
fn cap_ring(
    vertices: &mut Vec<Point3<f64>>,
    (ring, rings): (&[u32], &[std::ops::Range<usize>]),
    earcut: &mut Earcut<f64>,
    triangles: &mut Vec<[u32; 3]>,
    report: &mut CutReport,
) {
    let mut out: Vec<u32> = Vec::new();
    let hole_starts: Vec<u32> = rings[1..].iter().map(|r| r.start as u32).collect();
    earcut.earcut(
        ring.iter()
            .map(|&i| [vertices[i as usize].x, vertices[i as usize].y]),
        &hole_starts,
        &mut out,
    );
    let on_edge = dropped_points(&out, ring, rings);
    for t in out.chunks_exact(3) {
        let [a, b, c] = [
            ring[t[0] as usize],
            ring[t[1] as usize],
            ring[t[2] as usize],
        ];
        let (pa, pb, pc) = (
            vertices[a as usize],
            vertices[b as usize],
            vertices[c as usize],
        );
        let tri = if (pb - pa).cross(&(pc - pa)).z >= 0.0 {
            [a, b, c]
        } else {
            [a, c, b]
        };
        let mut outline = Vec::with_capacity(3);
        for k in 0..3 {
            let (x, y) = (tri[k], tri[(k + 1) % 3]);
            outline.push(x);
            if let Some(mid) = on_edge.get(&(x, y)) {
                outline.extend(mid);
            } else if let Some(mid) = on_edge.get(&(y, x)) {
                outline.extend(mid.iter().rev());
            }
        }
        if outline.len() == 3 {
            triangles.push(tri);
            report.cap_triangles += 1;
            continue;
        }
        // A fan from the triangle's centre keeps the outline points on its edges.
        let centre = Point3::from((pa.coords + pb.coords + pc.coords) / 3.0);
        vertices.push(centre);
        let m = (vertices.len() - 1) as u32;
        for k in 0..outline.len() {
            triangles.push([m, outline[k], outline[(k + 1) % outline.len()]]);
            report.cap_triangles += 1;
        }
    }
}

/// Earcut drops collinear outline points, but the walls below end on them: the points it left
/// out of its triangles `out`, by the edge (from, to) of kept points they lie on, so the cap
/// can put them back and the cap and walls do not meet in T-junctions.
fn dropped_points(
    out: &[u32],
    ring: &[u32],
    rings: &[std::ops::Range<usize>],
) -> HashMap<(u32, u32), Vec<u32>> {
    let mut used = vec![false; ring.len()];
    out.iter().for_each(|&k| used[k as usize] = true);
    let mut on_edge: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for r in rings {
        let len = r.len();
        let Some(first) = (0..len).find(|&k| used[r.start + k]) else {
            continue;
        };
        let mut run = Vec::new();
        let mut from = ring[r.start + first];
        for step in 1..=len {
            let k = r.start + (first + step) % len;
            if used[k] {
                if !run.is_empty() {
                    on_edge.insert((from, ring[k]), std::mem::take(&mut run));
                }
                from = ring[k];
            } else {
                run.push(ring[k]);
            }
        }
    }
    on_edge
}

/// Statistics of one quantity per layer band, with an estimate of each band's top from the
/// heights of the points that fell in it.
#[derive(Debug, Clone)]
pub struct LayerBands {
    base: f64,
    layer_height: f64,
    bands: Vec<Band>,
    /// Values whose height is outside every band.
    pub outside: u64,
}

/// Height bins per band for the top estimate: fine enough for a tenth of a layer.
const HEIGHT_BINS: usize = 32;

#[derive(Debug, Clone, Copy, Default)]
struct Band {
    values: Running,
    heights: [u32; HEIGHT_BINS],
}

/// One band's row of a per-layer table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandRow {
    /// The band's layer, from 0.
    pub layer: u32,
    /// The band's bottom, metres.
    pub z_min: f64,
    /// The band's top, metres.
    pub z_max: f64,
    /// Values in the band.
    pub count: u32,
    /// Their mean.
    pub mean: f64,
    /// Their standard deviation; `None` for fewer than two.
    pub std: Option<f64>,
    /// 98th percentile of the heights of the values in the band, metres: where a printed top
    /// layer stands.
    pub top: f64,
}

impl LayerBands {
    /// Bands of `layer_height` from `base` up to `top` (the design's or the printed height).
    pub fn new(base: f64, top: f64, layer_height: f64) -> Option<Self> {
        if !(layer_height > 0.0 && base.is_finite() && top.is_finite() && top > base) {
            return None;
        }
        // A design top a float's width above a whole number of layers (f32 STL) adds no band.
        let layers = (top - base) / layer_height;
        let n = if (layers - layers.round()).abs() < 1e-6 {
            layers.round()
        } else {
            layers.ceil()
        }
        .clamp(1.0, 1e6) as usize;
        Some(Self {
            base,
            layer_height,
            bands: vec![Band::default(); n],
            outside: 0,
        })
    }

    /// The same bands with nothing in them.
    pub fn clone_empty(&self) -> Self {
        Self {
            base: self.base,
            layer_height: self.layer_height,
            bands: vec![Band::default(); self.bands.len()],
            outside: 0,
        }
    }

    /// The lowest band's bottom and the layer height, metres.
    pub fn geometry(&self) -> (f64, f64) {
        (self.base, self.layer_height)
    }

    /// Adds `value` measured at height `z` to its band; values outside every band are counted.
    #[inline]
    pub fn push(&mut self, z: f64, value: f64) {
        let n = self.bands.len() as f64;
        let mut x = (z - self.base) / self.layer_height;
        // The top of the last band belongs to it (the design's top face lies there).
        if x >= n && x < n + 1e-6 {
            x = n - 1e-9;
        }
        if !(x >= 0.0 && x < n) {
            self.outside += 1;
            return;
        }
        let k = x as usize;
        let bin = (((x - k as f64) * HEIGHT_BINS as f64) as usize).min(HEIGHT_BINS - 1);
        let b = &mut self.bands[k];
        b.values.push(value);
        b.heights[bin] += 1;
    }

    /// Adds another table of the same bands.
    pub fn merge(&mut self, other: &Self) {
        for (a, b) in self.bands.iter_mut().zip(&other.bands) {
            a.values.merge(&b.values);
            for (x, y) in a.heights.iter_mut().zip(&b.heights) {
                *x += y;
            }
        }
        self.outside += other.outside;
    }

    /// Rows of bands that received values, lowest first.
    pub fn rows(&self) -> Vec<BandRow> {
        self.bands
            .iter()
            .enumerate()
            .filter(|(_, b)| b.values.n > 0)
            .map(|(k, b)| {
                let z_min = self.base + k as f64 * self.layer_height;
                let target = (0.98 * b.values.n as f64).ceil() as u32;
                let mut seen = 0;
                let mut bin = HEIGHT_BINS - 1;
                for (i, &c) in b.heights.iter().enumerate() {
                    seen += c;
                    if seen >= target {
                        bin = i;
                        break;
                    }
                }
                BandRow {
                    layer: k as u32,
                    z_min,
                    z_max: z_min + self.layer_height,
                    count: b.values.n,
                    mean: b.values.mean,
                    std: b.values.std(),
                    top: z_min + (bin + 1) as f64 / HEIGHT_BINS as f64 * self.layer_height,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::c2m::{C2mIndex, C2mParams};
    use crate::design::shapes;
    use crate::design::topology::Topology;

    fn ring_with_hole() -> Design {
        // A square tube: outer 1 × 1, inner 0.6 × 0.6, 1 m tall, as a closed mesh of two boxes'
        // walls: outer walls facing out, inner walls facing in, top and bottom rings.
        let outer = shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 1.0, 1.0));
        let inner = shapes::cuboid(Point3::new(0.2, 0.2, 0.0), Point3::new(0.8, 0.8, 1.0));
        // Keep the side walls of both; flip the inner one's; rings for top and bottom.
        let side = |d: &Design, flip: bool, off: u32| -> Vec<[u32; 3]> {
            d.triangles
                .iter()
                .filter(|t| {
                    let zs = t.map(|i| d.vertices[i as usize].z);
                    !(zs.iter().all(|&z| z == 0.0) || zs.iter().all(|&z| z == 1.0))
                })
                .map(|t| {
                    let t = if flip { [t[0], t[2], t[1]] } else { *t };
                    t.map(|i| i + off)
                })
                .collect()
        };
        let mut v = outer.vertices.clone();
        v.extend(&inner.vertices);
        let mut t = side(&outer, false, 0);
        t.extend(side(&inner, true, 8));
        // Ring faces: each of the two rings is 8 triangles between outer and inner squares.
        let find =
            |pts: &[Point3<f64>], p: Point3<f64>| pts.iter().position(|q| *q == p).unwrap() as u32;
        for (z, up) in [(0.0, false), (1.0, true)] {
            let o = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
                .map(|(x, y)| find(&v, Point3::new(x, y, z)));
            let i = [(0.2, 0.2), (0.8, 0.2), (0.8, 0.8), (0.2, 0.8)]
                .map(|(x, y)| find(&v, Point3::new(x, y, z)));
            for k in 0..4 {
                let (a, b, c, d) = (o[k], o[(k + 1) % 4], i[(k + 1) % 4], i[k]);
                if up {
                    t.push([a, b, c]);
                    t.push([a, c, d]);
                } else {
                    t.push([a, c, b]);
                    t.push([a, d, c]);
                }
            }
        }
        Design::from_indexed(v, t, 1.0).unwrap()
    }

    #[test]
    fn a_box_cut_halfway_is_a_closed_box_of_half_the_height() {
        let d = shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(2.0, 1.0, 1.0));
        let (cut, report) = cut_at(&d, 0.4).unwrap();
        assert_eq!(report.loops, 1);
        assert_eq!(report.open_chains, 0);
        assert!(Topology::of(&cut.triangles).is_closed_and_oriented());
        let (lo, hi) = cut.bounds();
        assert_eq!((lo.z, hi.z), (0.0, 0.4));
        let area = 2.0 * (2.0 * 1.0 + 2.0 * 0.4 + 1.0 * 0.4);
        assert!((cut.surface_area() - area).abs() < 1e-9);
        // A point just above the cut is outside by its height over the cap.
        let ix = C2mIndex::build(&cut, C2mParams::default()).unwrap();
        let c = ix.brute_force(&Point3::new(1.0, 0.5, 0.43)).unwrap();
        assert!((c.distance - 0.03).abs() < 1e-12);
        let c = ix.brute_force(&Point3::new(1.0, 0.5, 0.38)).unwrap();
        assert!((c.distance + 0.02).abs() < 1e-12);
    }

    #[test]
    fn a_tube_is_capped_with_its_hole_and_cuts_through_vertices_work() {
        let d = ring_with_hole();
        assert!(Topology::of(&d.triangles).is_closed_and_oriented());
        for h in [0.5, 1.0 - 1e-9] {
            let (cut, report) = cut_at(&d, h).unwrap();
            assert_eq!(report.loops, 2, "at {h}");
            assert!(
                Topology::of(&cut.triangles).is_closed_and_oriented(),
                "at {h}"
            );
            let ring = 1.0 - 0.36;
            let walls = 4.0 * h + 4.0 * 0.6 * h;
            assert!(
                (cut.surface_area() - (2.0 * ring + walls)).abs() < 1e-6,
                "at {h}"
            );
        }
        // Cut exactly through the top vertices: the whole design.
        let (cut, _) = cut_at(&d, 1.5).unwrap();
        assert_eq!(cut.triangles.len(), d.triangles.len());
        assert!(cut_at(&d, 0.0).is_err());
        assert!(cut_at(&d, f64::NAN).is_err());
    }

    #[test]
    fn a_sphere_cut_below_its_equator_is_closed() {
        let d = shapes::icosphere(Point3::origin(), 1.0, 3);
        let (cut, report) = cut_at(&d, -0.3).unwrap();
        assert_eq!(report.loops, 1);
        assert!(Topology::of(&cut.triangles).is_closed_and_oriented());
        assert!(cut.bounds().1.z <= -0.3 + 1e-12);
    }

    #[test]
    fn bands_give_per_layer_statistics_and_the_top() {
        let mut b = LayerBands::new(0.0, 0.1, 0.01).unwrap();
        // Layers 0..5 printed, each with deviation = layer index mm; the top layer ends at
        // 0.055 (half of layer 5).
        for k in 0..6 {
            for i in 0..1000 {
                let top = if k == 5 { 0.005 } else { 0.01 };
                let z = k as f64 * 0.01 + top * i as f64 / 1000.0;
                b.push(z, k as f64 * 1e-3);
            }
        }
        b.push(0.5, 0.0);
        let rows = b.rows();
        assert_eq!(rows.len(), 6);
        for (k, r) in rows.iter().enumerate() {
            assert_eq!(r.count, 1000);
            assert!((r.mean - k as f64 * 1e-3).abs() < 1e-12);
        }
        assert!(
            (rows[5].top - 0.055).abs() <= 0.01 / 32.0 + 1e-12,
            "{}",
            rows[5].top
        );
        assert!((rows[4].top - 0.05).abs() <= 0.01 / 32.0 + 1e-12);
        assert_eq!(b.outside, 1);
    }
}
