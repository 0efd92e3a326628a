//! The part as printed after some layers: a stack of layer prisms, each the design's outline at
//! that layer moved by the defects. Prisms stand on each other without a boolean union; the
//! faces between two layers are left out where nothing of them shows, and kept as ledges where
//! one layer sticks out over the other, so the outer surface is what a scanner would see.

use nalgebra::{Point3, Vector2};

use super::Part;
use super::defects::{Defect, LayerSettings, LayerState, bulge_at, gaps_of, layer_states};
use super::part::{PartError, Ring, signed_area2};

/// Cap triangles longer than this are split, so a scanner's raster tests few pixels per triangle.
const MAX_CAP_EDGE: f64 = 0.15;

/// The as-built part after `printed` layers with `defects`: triangles, outward, metres.
#[derive(Debug, Clone)]
pub struct AsBuilt {
    /// Vertices, design frame.
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Height of the printed top, metres (it differs from the nominal one under drift and sag).
    pub top: f64,
    /// Layers printed.
    pub printed: u32,
}

/// One layer's outlines at its bottom and its top, vertex for vertex.
struct LayerRings {
    state: LayerState,
    bottom: Vec<Ring>,
    top: Vec<Ring>,
    gapped: bool,
}

/// The as-built part after `printed` layers (at most the part's) with `defects` applied,
/// printed as designed.
pub fn as_built(part: &Part, defects: &[Defect], printed: u32) -> Result<AsBuilt, PartError> {
    as_built_with(part, defects, printed, &[])
}

/// The as-built part after `printed` layers with `defects`, each layer printed with its
/// `settings` (nominal past their end): corrections act on the process disturbances, not on
/// local defects.
pub fn as_built_with(
    part: &Part,
    defects: &[Defect],
    printed: u32,
    settings: &[LayerSettings],
) -> Result<AsBuilt, PartError> {
    let printed = printed.min(part.layers());
    let states = layer_states(part, defects, printed, settings, part.bead_width()?);
    let mut layers = Vec::with_capacity(states.len());
    for (j, s) in states.iter().enumerate() {
        let gaps = gaps_of(defects, j as u32);
        let (bottom, top) = if part.sections_correspond() && gaps.is_empty() {
            (part.section(s.nominal.0)?, part.section(s.nominal.1)?)
        } else {
            let mid = part.section(0.5 * (s.nominal.0 + s.nominal.1))?;
            (mid.clone(), mid)
        };
        let mv = |rings: Vec<Ring>| -> Vec<Ring> {
            rings
                .iter()
                .map(|r| move_ring(r, s, 0.5 * (s.z0 + s.z1), defects))
                .collect()
        };
        let (mut bottom, mut top) = (mv(bottom), mv(top));
        for &(c, u, len) in &gaps {
            bottom = cut_gap(&bottom, c, u, len);
            top = cut_gap(&top, c, u, len);
        }
        layers.push(LayerRings {
            state: *s,
            bottom,
            top,
            gapped: !gaps.is_empty(),
        });
    }
    let mut mesh = Mesh::default();
    for (j, l) in layers.iter().enumerate() {
        for (b, t) in l.bottom.iter().zip(&l.top) {
            mesh.side(b, t, l.state.z0, l.state.z1);
        }
        let Some(next) = layers.get(j + 1) else {
            mesh.cap(&l.top, l.state.z1, true);
            continue;
        };
        if l.gapped || next.gapped {
            // Where the next layer has a gap, this one's top shows; where this one has a gap,
            // the next one's underside shows.
            for &(c, u, len) in &gaps_of(defects, j as u32 + 1) {
                mesh.cap(&keep_gap(&l.top, c, u, len), l.state.z1, true);
            }
            for &(c, u, len) in &gaps_of(defects, j as u32) {
                mesh.cap(&keep_gap(&next.bottom, c, u, len), l.state.z1, false);
            }
        } else {
            for (a, b) in l.top.iter().zip(&next.bottom) {
                mesh.ledge(a, b, l.state.z1);
            }
        }
    }
    Ok(AsBuilt {
        vertices: mesh.vertices,
        triangles: mesh.triangles,
        top: states.last().map(|s| s.z1).unwrap_or(0.0),
        printed,
    })
}

/// Moves an outline by the layer's offset (outward, mitred at corners), its bulges and shift.
fn move_ring(ring: &Ring, s: &LayerState, z_mid: f64, defects: &[Defect]) -> Ring {
    let n = ring.len();
    let sense = signed_area2(ring).signum();
    let normal = |a: [f64; 2], b: [f64; 2]| -> Vector2<f64> {
        let e = Vector2::new(b[0] - a[0], b[1] - a[1]);
        sense * Vector2::new(e.y, -e.x) / e.norm().max(f64::MIN_POSITIVE)
    };
    (0..n)
        .map(|k| {
            let (prev, p, next) = (ring[(k + n - 1) % n], ring[k], ring[(k + 1) % n]);
            let (n1, n2) = (normal(prev, p), normal(p, next));
            // The mitre m with m·n1 = m·n2 = 1 moves both edges by exactly one unit.
            let miter = (n1 + n2) / (1.0 + n1.dot(&n2)).max(0.25);
            let along = s.offset + bulge_at(defects, Point3::new(p[0], p[1], z_mid));
            [
                p[0] + miter.x * along + s.shift[0],
                p[1] + miter.y * along + s.shift[1],
            ]
        })
        .collect()
}

/// The outline with the slab |(p − c)·u| < len/2 removed: each ring becomes its parts on
/// either side.
fn cut_gap(rings: &[Ring], c: [f64; 2], u: [f64; 2], len: f64) -> Vec<Ring> {
    let d = |p: &[f64; 2]| (p[0] - c[0]) * u[0] + (p[1] - c[1]) * u[1];
    let mut out = Vec::new();
    for r in rings {
        for side in [-1.0, 1.0] {
            let piece = clip(r, |p| side * d(p) - 0.5 * len);
            if piece.len() >= 3 {
                out.push(piece);
            }
        }
    }
    out
}

/// The outline inside the slab |(p − c)·u| < len/2.
fn keep_gap(rings: &[Ring], c: [f64; 2], u: [f64; 2], len: f64) -> Vec<Ring> {
    let d = |p: &[f64; 2]| (p[0] - c[0]) * u[0] + (p[1] - c[1]) * u[1];
    rings
        .iter()
        .map(|r| {
            let a = clip(r, |p| d(p) + 0.5 * len);
            clip(&a, |p| 0.5 * len - d(p))
        })
        .filter(|r| r.len() >= 3)
        .collect()
}

/// Sutherland–Hodgman: the part of `ring` where `inside(p) >= 0`. Exact for convex outlines.
fn clip(ring: &[[f64; 2]], inside: impl Fn(&[f64; 2]) -> f64) -> Ring {
    let mut out = Vec::with_capacity(ring.len() + 2);
    for k in 0..ring.len() {
        let (p, q) = (ring[k], ring[(k + 1) % ring.len()]);
        let (fp, fq) = (inside(&p), inside(&q));
        if fp >= 0.0 {
            out.push(p);
        }
        if (fp >= 0.0) != (fq >= 0.0) {
            let t = fp / (fp - fq);
            out.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
        }
    }
    out
}

#[derive(Default)]
struct Mesh {
    vertices: Vec<Point3<f64>>,
    triangles: Vec<[u32; 3]>,
}

impl Mesh {
    fn push(&mut self, p: [f64; 2], z: f64) -> u32 {
        self.vertices.push(Point3::new(p[0], p[1], z));
        (self.vertices.len() - 1) as u32
    }

    /// The wall of one ring between its bottom and top outlines.
    fn side(&mut self, bottom: &Ring, top: &Ring, z0: f64, z1: f64) {
        let n = bottom.len();
        if n < 3 || top.len() != n {
            return;
        }
        let b0 = self.vertices.len() as u32;
        bottom.iter().for_each(|&p| {
            self.push(p, z0);
        });
        let t0 = self.vertices.len() as u32;
        top.iter().for_each(|&p| {
            self.push(p, z1);
        });
        for i in 0..n as u32 {
            let k = (i + 1) % n as u32;
            // For a counter-clockwise ring the edge b_i → b_k, then up, faces outward; a hole
            // runs clockwise and the same order faces into the hole, away from the material.
            self.triangles.push([b0 + i, b0 + k, t0 + k]);
            self.triangles.push([b0 + i, t0 + k, t0 + i]);
        }
    }

    /// The band between one layer's top outline `a` and the next one's bottom outline `b` at
    /// height `z`: facing up where `b` lies inside `a`, down where it sticks out.
    fn ledge(&mut self, a: &Ring, b: &Ring, z: f64) {
        let n = a.len();
        if b.len() != n {
            return;
        }
        let same = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).abs() + (p[1] - q[1]).abs() < 1e-9;
        for i in 0..n {
            let k = (i + 1) % n;
            if same(a[i], b[i]) && same(a[k], b[k]) {
                continue;
            }
            let ids = [a[i], a[k], b[k], b[i]].map(|p| self.push(p, z));
            self.triangles.push([ids[0], ids[1], ids[2]]);
            self.triangles.push([ids[0], ids[2], ids[3]]);
        }
    }

    /// A flat cap over `rings` at height `z`, facing up or down, split into small triangles.
    fn cap(&mut self, rings: &[Ring], z: f64, up: bool) {
        let (outers, holes): (Vec<&Ring>, Vec<&Ring>) =
            rings.iter().partition(|r| signed_area2(r) > 0.0);
        let mut earcut = earcut::Earcut::new();
        let mut tris: Vec<u32> = Vec::new();
        for o in outers {
            let mut pts: Vec<[f64; 2]> = o.clone();
            let mut starts = Vec::new();
            for h in holes.iter().filter(|h| inside(&h[0], o)) {
                starts.push(pts.len() as u32);
                pts.extend(h.iter());
            }
            earcut.earcut(pts.iter().copied(), &starts, &mut tris);
            for t in tris.chunks_exact(3) {
                let [p, q, r] = [t[0], t[1], t[2]].map(|i| pts[i as usize]);
                let ccw = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]) > 0.0;
                let (q, r) = if ccw == up { (q, r) } else { (r, q) };
                self.split(p, q, r, z);
            }
        }
    }

    /// Longest-edge bisection down to [`MAX_CAP_EDGE`].
    fn split(&mut self, p: [f64; 2], q: [f64; 2], r: [f64; 2], z: f64) {
        let l2 = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2);
        let (pq, qr, rp) = (l2(p, q), l2(q, r), l2(r, p));
        let longest = pq.max(qr).max(rp);
        if longest <= MAX_CAP_EDGE * MAX_CAP_EDGE {
            let ids = [p, q, r].map(|v| self.push(v, z));
            self.triangles.push(ids);
            return;
        }
        let mid = |a: [f64; 2], b: [f64; 2]| [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])];
        if longest == pq {
            let m = mid(p, q);
            self.split(p, m, r, z);
            self.split(m, q, r, z);
        } else if longest == qr {
            let m = mid(q, r);
            self.split(p, q, m, z);
            self.split(p, m, r, z);
        } else {
            let m = mid(r, p);
            self.split(p, q, m, z);
            self.split(m, q, r, z);
        }
    }
}

fn inside(pt: &[f64; 2], ring: &[[f64; 2]]) -> bool {
    let mut c = false;
    for k in 0..ring.len() {
        let (p, q) = (ring[k], ring[(k + 1) % ring.len()]);
        if (p[1] > pt[1]) != (q[1] > pt[1])
            && pt[0] < p[0] + (pt[1] - p[1]) / (q[1] - p[1]) * (q[0] - p[0])
        {
            c = !c;
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Signed volume by the divergence theorem: equals the enclosed volume for a closed,
    /// outward mesh, and the prisms' internal faces are left out only where they cancel.
    fn volume(m: &AsBuilt) -> f64 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.vertices[i as usize].coords);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum()
    }

    fn area_up(m: &AsBuilt) -> f64 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.vertices[i as usize]);
                0.5 * (b - a).cross(&(c - a)).z
            })
            .sum()
    }

    /// The study wall after 10 layers with one defect.
    fn ten_layers_of_the_wall_with(defect: Defect) -> AsBuilt {
        as_built(&Part::wall(), &[defect], 10).unwrap()
    }

    #[test]
    fn a_defect_free_wall_is_the_design_cut_at_the_printed_height() {
        let m = as_built(&Part::wall(), &[], 10).unwrap();
        assert!((m.top - 0.2).abs() < 1e-12);
        // Without a bottom face the divergence volume is that of the closed box minus the
        // bottom's contribution, which is zero at z = 0.
        assert!(
            (volume(&m) - 2.0 * 0.1734 * 0.2).abs() < 1e-9,
            "{}",
            volume(&m)
        );
        assert!((area_up(&m) - 2.0 * 0.1734).abs() < 1e-9);
    }

    #[test]
    fn over_extrusion_widens_the_layers_and_leaves_ledges_that_face_the_right_way() {
        let w = 0.01;
        let m = ten_layers_of_the_wall_with(Defect::Extrusion {
            first: 3,
            last: 5,
            width: w,
        });
        let extra = (2.0 + w) * (0.1734 + w) - 2.0 * 0.1734;
        let v = 2.0 * 0.1734 * 0.2 + extra * 0.06;
        assert!((volume(&m) - v).abs() < 1e-9, "{} vs {v}", volume(&m));
        // The net upward area is still the top; the ledges cancel.
        assert!((area_up(&m) - 2.0 * 0.1734).abs() < 1e-9);
    }

    #[test]
    fn a_missing_segment_removes_its_volume() {
        let m = ten_layers_of_the_wall_with(Defect::MissingSegment {
            layer: 4,
            centre: [0.3, 0.0],
            direction: [1.0, 0.0],
            length: 0.2,
        });
        let v = 2.0 * 0.1734 * 0.2 - 0.2 * 0.1734 * 0.02;
        assert!((volume(&m) - v).abs() < 1e-9, "{} vs {v}", volume(&m));
    }

    #[test]
    fn a_shift_moves_the_upper_layers() {
        let m = ten_layers_of_the_wall_with(Defect::LateralShift {
            from: 5,
            offset: [0.0, 0.01],
        });
        assert!((volume(&m) - 2.0 * 0.1734 * 0.2).abs() < 1e-9);
        let max_y = m
            .vertices
            .iter()
            .map(|v| v.y)
            .fold(f64::NEG_INFINITY, f64::max);
        assert!((max_y - (0.0867 + 0.01)).abs() < 1e-9);
    }

    #[test]
    fn the_column_follows_its_twist() {
        let p = Part::column();
        let m = as_built(&p, &[], p.layers()).unwrap();
        // Faceted design and the 10 mm outline differ by well under 1 % in volume.
        let design_volume: f64 = p
            .design
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| p.design.vertices[i as usize].coords);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum();
        assert!((volume(&m) - design_volume).abs() < 0.01 * design_volume);
    }
}
