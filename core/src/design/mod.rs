//! The as-designed model: an indexed triangle mesh in metres, checked for the defects that make
//! signed distances unreliable.

pub mod shapes;
pub(crate) mod topology;

use nalgebra::Point3;

pub use topology::Topology;

/// Why triangles do not make a design. Reading design files is `asbuilt-io`'s, which names the
/// file in its own error.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DesignError {
    #[error(
        "the mesh has no usable triangles (empty, or every triangle degenerate): export the \
         surface as a triangle mesh"
    )]
    /// No triangle with an area is left.
    Empty,
}

/// The unit a design file was written in. Declared by the user, never guessed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Units {
    /// The file's numbers are metres.
    Metres,
    /// The file's numbers are millimetres.
    Millimetres,
}

impl Units {
    /// Metres per file unit.
    pub fn scale(self) -> f64 {
        match self {
            Units::Metres => 1.0,
            Units::Millimetres => 1e-3,
        }
    }
}

/// As the command line and agent.toml write it: `m` or `mm`.
impl std::fmt::Display for Units {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Units::Metres => "m",
            Units::Millimetres => "mm",
        })
    }
}

impl std::str::FromStr for Units {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "m" | "metres" | "meters" => Ok(Units::Metres),
            "mm" | "millimetres" | "millimeters" => Ok(Units::Millimetres),
            other => Err(format!("unknown unit {other:?}: use m or mm")),
        }
    }
}

/// What loading and cleaning found. Everything here is a warning unless the mesh ends up empty.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct MeshReport {
    /// Vertices the file holds.
    pub input_vertices: usize,
    /// Triangles the file holds (after polygons are fanned).
    pub input_triangles: usize,
    /// Vertices dropped because another one had the same position.
    pub merged_vertices: usize,
    /// Triangles dropped because they have no area (repeated or collinear vertices).
    pub degenerate_triangles: usize,
    /// Triangles that point to a vertex the file does not have.
    pub invalid_indices: usize,
    /// Edge checks of the cleaned mesh.
    pub topology: Topology,
}

impl MeshReport {
    /// One line per problem, saying what it means for the deviations.
    pub fn warnings(&self) -> Vec<String> {
        let mut w = Vec::new();
        if self.invalid_indices > 0 {
            w.push(format!(
                "{} triangles refer to vertices the file does not have; they were dropped",
                self.invalid_indices
            ));
        }
        if self.degenerate_triangles > 0 {
            w.push(format!(
                "{} degenerate triangles (no area) were dropped",
                self.degenerate_triangles
            ));
        }
        let t = &self.topology;
        if t.boundary_edges > 0 {
            w.push(format!(
                "{} open boundary edges: the design is not closed, so the sign of a distance \
                 near a hole may be wrong",
                t.boundary_edges
            ));
        }
        if t.non_manifold_edges > 0 {
            w.push(format!(
                "{} non-manifold edges (shared by more than two triangles): signs near them may \
                 be wrong",
                t.non_manifold_edges
            ));
        }
        if t.inconsistent_edges > 0 {
            w.push(format!(
                "{} edges between triangles of opposite orientation: fix the normals in the \
                 design tool, or signs will flip across those edges",
                t.inconsistent_edges
            ));
        }
        w
    }
}

/// An indexed triangle mesh in metres, with no degenerate triangles.
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[derive(Debug, Clone)]
pub struct Design {
    /// Vertices, metres.
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// What loading and cleaning found.
    pub report: MeshReport,
}

impl Design {
    /// Builds a design from vertices and triangles in file units, scaled to metres by `scale`.
    /// Vertices at the same position are merged and degenerate triangles dropped.
    pub fn from_indexed(
        vertices: Vec<Point3<f64>>,
        triangles: Vec<[u32; 3]>,
        scale: f64,
    ) -> Result<Self, DesignError> {
        let mut report = MeshReport {
            input_vertices: vertices.len(),
            input_triangles: triangles.len(),
            ..Default::default()
        };
        // Merge by exact position: STL repeats each vertex per triangle, bit for bit.
        let mut remap = Vec::with_capacity(vertices.len());
        let mut unique: Vec<Point3<f64>> = Vec::with_capacity(vertices.len());
        // Fx, not SipHash: the keys are the file's own coordinates, and hashing them is most
        // of the time a large design takes to load.
        let mut seen: rustc_hash::FxHashMap<[u64; 3], u32> = rustc_hash::FxHashMap::default();
        seen.reserve(vertices.len());
        for v in &vertices {
            let v = v * scale;
            // +0.0 and -0.0 are one position.
            let key = [v.x, v.y, v.z].map(|c| (c + 0.0).to_bits());
            let id = *seen.entry(key).or_insert_with(|| {
                unique.push(v);
                (unique.len() - 1) as u32
            });
            remap.push(id);
        }
        report.merged_vertices = vertices.len() - unique.len();

        let mut kept = Vec::with_capacity(triangles.len());
        for t in triangles {
            if t.iter().any(|&i| i as usize >= remap.len()) {
                report.invalid_indices += 1;
                continue;
            }
            let t = t.map(|i| remap[i as usize]);
            let [a, b, c] = t.map(|i| unique[i as usize]);
            let area2 = (b - a).cross(&(c - a)).norm();
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || area2 <= 0.0 || !area2.is_finite() {
                report.degenerate_triangles += 1;
                continue;
            }
            kept.push(t);
        }
        if kept.is_empty() {
            return Err(DesignError::Empty);
        }
        report.topology = Topology::of(&kept);
        Ok(Self {
            vertices: unique,
            triangles: kept,
            report,
        })
    }

    /// Axis-aligned bounds, metres.
    pub fn bounds(&self) -> (Point3<f64>, Point3<f64>) {
        let mut lo = self.vertices[self.triangles[0][0] as usize];
        let mut hi = lo;
        for t in &self.triangles {
            for &i in t {
                lo = lo.inf(&self.vertices[i as usize]);
                hi = hi.sup(&self.vertices[i as usize]);
            }
        }
        (lo, hi)
    }

    /// The surface's area, m².
    pub fn surface_area(&self) -> f64 {
        self.triangles.iter().map(|t| self.triangle_area(t)).sum()
    }

    /// Area of triangle `t` (vertex ids of this design), m².
    #[inline]
    pub fn triangle_area(&self, t: &[u32; 3]) -> f64 {
        let [a, b, c] = t.map(|i| self.vertices[i as usize]);
        0.5 * (b - a).cross(&(c - a)).norm()
    }

    /// Edges where the surface turns by more than `min_angle_deg` (the faces' normals), and
    /// boundary or non-manifold edges: where a neighbourhood on the surface stops being one face.
    pub fn sharp_edges(&self, min_angle_deg: f64) -> Vec<[Point3<f64>; 2]> {
        sharp_edges(&self.vertices, &self.triangles, min_angle_deg, |_| true)
    }

    /// Median triangle edge length, metres.
    pub fn median_edge(&self) -> f64 {
        let mut e: Vec<f64> = self
            .triangles
            .iter()
            .flat_map(|t| {
                let p = t.map(|i| self.vertices[i as usize]);
                [
                    (p[1] - p[0]).norm(),
                    (p[2] - p[1]).norm(),
                    (p[0] - p[2]).norm(),
                ]
            })
            .collect();
        let mid = e.len() / 2;
        *e.select_nth_unstable_by(mid, f64::total_cmp).1
    }
}

/// [`Design::sharp_edges`] of a mesh, for the edges with at least one face that `include` takes
/// (by the face's index), sorted.
pub(crate) fn sharp_edges(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    min_angle_deg: f64,
    include: impl Fn(usize) -> bool,
) -> Vec<[Point3<f64>; 2]> {
    let normals: Vec<nalgebra::Vector3<f64>> = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            let n = (b - a).cross(&(c - a));
            n / n.norm().max(f64::MIN_POSITIVE)
        })
        .collect();
    let cos_max = min_angle_deg.to_radians().cos();
    let uses = topology::EdgeUse::sorted(triangles);
    let mut out: Vec<[Point3<f64>; 2]> = uses
        .chunk_by(|a, b| a.key == b.key)
        .filter(|faces| faces.iter().any(|e| include(e.triangle as usize)))
        .filter(|faces| {
            let n = |k: usize| &normals[faces[k].triangle as usize];
            faces.len() != 2 || n(0).dot(n(1)) < cos_max
        })
        .map(|faces| faces[0].vertices().map(|v| vertices[v as usize]))
        .collect();
    sort_edges(&mut out);
    out
}

/// The order [`Design::sharp_edges`] gives its edges in.
pub(crate) fn sort_edges(edges: &mut [[Point3<f64>; 2]]) {
    edges.sort_by(|a, b| {
        (a[0].coords.as_slice(), a[1].coords.as_slice())
            .partial_cmp(&(b[0].coords.as_slice(), b[1].coords.as_slice()))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
}
