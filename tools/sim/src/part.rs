//! What is printed: a design and the horizontal sections the printer lays down, layer by layer.

use std::collections::HashMap;

use nalgebra::Point3;

use asbuilt_core::Design;
use asbuilt_core::design::shapes;
use asbuilt_core::layers::{CutError, cut_at};

/// A closed outline in the plane, metres. Counter-clockwise around material, clockwise around
/// a hole, as seen from above.
pub type Ring = Vec<[f64; 2]>;

/// Outline vertices are at most this far apart, so local defects (a bulge) have vertices to move.
pub const OUTLINE_SPACING: f64 = 0.01;

#[derive(Debug, Clone)]
enum Shape {
    /// A box standing on z = 0, centred in x and y.
    Wall { length: f64, thickness: f64 },
    /// An elliptical column turning with height; see [`shapes::twisted_column`].
    Column { a: f64, b: f64, twist_deg: f64 },
    /// Any design: sections are sliced from the mesh at mid-layer.
    Mesh,
}

/// A part to print: the design the agent compares against, the layer height, and how to get
/// the printed outline at any height.
#[derive(Debug, Clone)]
pub struct Part {
    /// The part's name: `wall`, `column`, or the mesh file's stem.
    pub name: String,
    /// The design the agent compares against, metres.
    pub design: Design,
    /// Metres per printed layer.
    pub layer_height: f64,
    height: f64,
    shape: Shape,
}

/// A part that cannot be printed in layers.
#[derive(Debug, thiserror::Error)]
pub enum PartError {
    /// The layer height is not positive or not below the part's height.
    #[error("layer height {0} m must be positive and below the part's height {1} m")]
    LayerHeight(f64, f64),
    /// A layer's height cuts no section of the design.
    #[error("the design has no section at z = {z:.4} m (it may be open or not stand on z = 0)")]
    NoSection {
        /// The height, metres.
        z: f64,
    },
    /// The design could not be cut at a layer.
    #[error("slicing the design: {0}")]
    Cut(#[from] CutError),
}

impl Part {
    /// The source study's shotcrete wall (173.4 × 2000 × 980 mm) in 20 mm layers.
    pub fn wall() -> Self {
        let design = shapes::study_wall();
        Self {
            name: "wall".into(),
            design,
            layer_height: 0.02,
            height: 0.98,
            shape: Shape::Wall {
                length: 2.0,
                thickness: 0.1734,
            },
        }
    }

    /// A free-form part: a 300 × 200 mm elliptical column, 1.2 m tall, turning 90°, in 20 mm
    /// layers.
    pub fn column() -> Self {
        let (a, b, height, twist_deg) = (0.15, 0.10, 1.2, 90.0);
        Self {
            name: "column".into(),
            design: shapes::twisted_column(a, b, height, twist_deg, 128, 60),
            layer_height: 0.02,
            height,
            shape: Shape::Column { a, b, twist_deg },
        }
    }

    /// Any closed design standing on z = 0, printed in layers of `layer_height` metres. Its
    /// sections are sliced at mid-layer, so each layer is a vertical prism.
    pub fn from_design(name: &str, design: Design, layer_height: f64) -> Result<Self, PartError> {
        let (lo, hi) = design.bounds();
        let height = hi.z - lo.z.min(0.0);
        if !(layer_height > 0.0 && layer_height < height) {
            return Err(PartError::LayerHeight(layer_height, height));
        }
        let part = Self {
            name: name.into(),
            design,
            layer_height,
            height: hi.z,
            shape: Shape::Mesh,
        };
        part.section(0.5 * layer_height)?;
        Ok(part)
    }

    /// Height of the finished part, metres.
    pub fn height(&self) -> f64 {
        self.height
    }

    /// Number of layers of the finished part.
    pub fn layers(&self) -> u32 {
        (self.height / self.layer_height - 1e-9).ceil().max(1.0) as u32
    }

    /// Nominal bottom and top of layer `j`, metres.
    pub fn layer_span(&self, j: u32) -> (f64, f64) {
        let z0 = j as f64 * self.layer_height;
        (z0, (z0 + self.layer_height).min(self.height))
    }

    /// The width a layer comes out at nominal flow, for the printer's flow model: a wall's
    /// thickness; for another section sprayed or extruded whole, `2 · area / perimeter` of its
    /// first layer (what the width grows by when the flow's extra volume spreads evenly around
    /// its outline).
    pub fn bead_width(&self) -> Result<f64, PartError> {
        if let Shape::Wall { thickness, .. } = self.shape {
            return Ok(thickness);
        }
        let rings = self.section(0.5 * self.layer_height.min(self.height))?;
        let area: f64 = rings.iter().map(|r| 0.5 * signed_area2(r)).sum();
        let perimeter: f64 = rings
            .iter()
            .map(|r| {
                (0..r.len())
                    .map(|k| {
                        let (p, q) = (r[k], r[(k + 1) % r.len()]);
                        (q[0] - p[0]).hypot(q[1] - p[1])
                    })
                    .sum::<f64>()
            })
            .sum();
        Ok(2.0 * area.abs() / perimeter.max(f64::MIN_POSITIVE))
    }

    /// Whether a layer's bottom and top outlines correspond vertex for vertex (the analytic
    /// shapes), so a layer follows the design's slope; sliced meshes give vertical prisms.
    pub fn sections_correspond(&self) -> bool {
        !matches!(self.shape, Shape::Mesh)
    }

    /// The design's outline at height `z`. For the analytic shapes the vertex count and order do
    /// not depend on `z`.
    pub fn section(&self, z: f64) -> Result<Vec<Ring>, PartError> {
        match self.shape {
            Shape::Wall { length, thickness } => {
                let (x, y) = (0.5 * length, 0.5 * thickness);
                Ok(vec![resample(
                    &[[-x, -y], [x, -y], [x, y], [-x, y]],
                    OUTLINE_SPACING,
                )])
            }
            Shape::Column { a, b, twist_deg } => {
                let h = 3.0 * (a - b).powi(2) / (a + b).powi(2);
                let perimeter =
                    std::f64::consts::PI * (a + b) * (1.0 + h / (10.0 + (4.0 - h).sqrt()));
                let n = (perimeter / OUTLINE_SPACING).ceil().max(16.0) as usize;
                let (s, c) = (twist_deg.to_radians() * z / self.height).sin_cos();
                Ok(vec![
                    (0..n)
                        .map(|i| {
                            let phi = std::f64::consts::TAU * i as f64 / n as f64;
                            let (x, y) = (a * phi.cos(), b * phi.sin());
                            [x * c - y * s, x * s + y * c]
                        })
                        .collect(),
                ])
            }
            Shape::Mesh => {
                let rings = slice(&self.design, z)?;
                if rings.is_empty() {
                    return Err(PartError::NoSection { z });
                }
                Ok(rings.iter().map(|r| resample(r, OUTLINE_SPACING)).collect())
            }
        }
    }
}

/// The outlines of `design` at height `z`: the boundary of the cap that closes the part cut
/// there.
fn slice(design: &Design, z: f64) -> Result<Vec<Ring>, PartError> {
    let (cut, _) = cut_at(design, z)?;
    let v = &cut.vertices;
    let at = |i: u32| v[i as usize].z == z;
    let mut edges: HashMap<u32, u32> = HashMap::new();
    let mut directed: Vec<(u32, u32)> = Vec::new();
    for t in cut.triangles.iter().filter(|t| t.iter().all(|&i| at(i))) {
        for k in 0..3 {
            directed.push((t[k], t[(k + 1) % 3]));
        }
    }
    let set: std::collections::HashSet<(u32, u32)> = directed.iter().copied().collect();
    for &(a, b) in &directed {
        if !set.contains(&(b, a)) {
            edges.insert(a, b);
        }
    }
    let mut rings = Vec::new();
    while let Some((&start, _)) = edges.iter().next() {
        let mut ring = vec![];
        let mut cur = start;
        while let Some(next) = edges.remove(&cur) {
            let p: Point3<f64> = v[cur as usize];
            ring.push([p.x, p.y]);
            cur = next;
            if cur == start {
                break;
            }
        }
        if ring.len() >= 3 {
            rings.push(ring);
        }
    }
    Ok(rings)
}

/// Adds vertices so that no edge of the closed ring is longer than `spacing`.
pub fn resample(ring: &[[f64; 2]], spacing: f64) -> Ring {
    let mut out = Vec::with_capacity(ring.len());
    for k in 0..ring.len() {
        let (p, q) = (ring[k], ring[(k + 1) % ring.len()]);
        let len = ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)).sqrt();
        let n = (len / spacing).ceil().max(1.0) as usize;
        for i in 0..n {
            let t = i as f64 / n as f64;
            out.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
        }
    }
    out
}

/// Twice the signed area: positive counter-clockwise.
pub fn signed_area2(ring: &[[f64; 2]]) -> f64 {
    (0..ring.len())
        .map(|k| {
            let (p, q) = (ring[k], ring[(k + 1) % ring.len()]);
            p[0] * q[1] - q[0] * p[1]
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(rings: &[Ring]) -> f64 {
        rings.iter().map(|r| 0.5 * signed_area2(r)).sum()
    }

    #[test]
    fn the_wall_section_is_its_footprint_and_counter_clockwise() {
        let w = Part::wall();
        let s = w.section(0.5).unwrap();
        assert_eq!(s.len(), 1);
        assert!((area(&s) - 2.0 * 0.1734).abs() < 1e-12);
        assert_eq!(w.layers(), 49);
        let max_edge = (0..s[0].len())
            .map(|k| {
                let (p, q) = (s[0][k], s[0][(k + 1) % s[0].len()]);
                ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)).sqrt()
            })
            .fold(0.0, f64::max);
        assert!(max_edge <= OUTLINE_SPACING + 1e-12);
    }

    #[test]
    fn a_sliced_mesh_gives_the_same_section_as_the_analytic_shape() {
        let c = Part::column();
        let sliced = Part::from_design("c", c.design.clone(), 0.02).unwrap();
        for z in [0.01, 0.61, 1.19] {
            let (a, b) = (
                area(&c.section(z).unwrap()),
                area(&sliced.section(z).unwrap()),
            );
            // 128 facets against the smooth ellipse: within 0.1 %.
            assert!((a - b).abs() < 1e-3 * a, "z {z}: {a} vs {b}");
            assert!(b > 0.0);
        }
    }

    #[test]
    fn a_hollow_design_slices_into_an_outer_ring_and_a_hole() {
        let outer = shapes::cuboid(Point3::new(-1.0, -1.0, 0.0), Point3::new(1.0, 1.0, 1.0));
        let mut inner = shapes::cuboid(Point3::new(-0.5, -0.5, 0.0), Point3::new(0.5, 0.5, 1.0));
        inner.triangles.iter_mut().for_each(|t| t.swap(1, 2));
        let tube = shapes::merge(&[outer, inner]);
        let rings = slice(&tube, 0.5).unwrap();
        let mut areas: Vec<f64> = rings.iter().map(|r| 0.5 * signed_area2(r)).collect();
        areas.sort_by(f64::total_cmp);
        assert_eq!(areas.len(), 2);
        assert!((areas[0] + 1.0).abs() < 1e-9 && (areas[1] - 4.0).abs() < 1e-9);
    }
}
