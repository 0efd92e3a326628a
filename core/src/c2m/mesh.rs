//! The design's triangles as the index keeps them: compact (vertices shared, no per-triangle
//! copies of points or normals), in the order of the BVH's leaves so that neighbours in space are
//! neighbours in memory, with each triangle's id in the design kept for ties and results.
//!
//! Pseudo-normals are not stored per feature: a face normal is recomputed from the vertices, an
//! edge normal is the sum of the two faces' normals (the neighbour is stored), and only vertex
//! normals and the edges of non-manifold or externally supplied meshes live in tables. Every
//! value is computed by the same operations in the same order as [`PseudoNormals`], so the bits
//! are the same.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use super::normals::{PseudoNormals, vertex_normals};
use super::triangle::{Lanes, Region, Triangle};

/// An edge's neighbour code: a triangle (internal index) below this, a boundary edge, or an
/// entry of the side table of edge normals (the high bit set).
const BOUNDARY: u32 = u32::MAX;
const EXTRA: u32 = 1 << 31;

#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Mesh {
    pub vertices: Vec<Point3<f64>>,
    /// Vertex ids, in internal order.
    pub faces: Vec<[u32; 3]>,
    /// The design's id of each internal triangle.
    pub ids: Vec<u32>,
    /// Design triangle → internal position (the inverse of `ids`).
    pub internal: Vec<u32>,
    /// Per internal triangle and edge `i` (vertex `i` to `i + 1`): the neighbour code.
    edges: Vec<[u32; 3]>,
    /// Edge normals that are not the sum of two faces: non-manifold edges, supplied normals.
    edge_extra: Vec<Vector3<f64>>,
    vertex_normals: Vec<Vector3<f64>>,
}

/// Where pseudo-normals come from: the mesh itself, or normals computed on a larger mesh (a
/// section of the design needs those of the triangles around it).
pub enum NormalSource {
    Own,
    Given(PseudoNormals),
}

impl Mesh {
    /// `order[k]` is the design triangle stored at internal position `k`.
    pub fn new(
        vertices: Vec<Point3<f64>>,
        triangles: &[[u32; 3]],
        order: &[u32],
        normals: NormalSource,
    ) -> Self {
        let faces: Vec<[u32; 3]> = order.iter().map(|&t| triangles[t as usize]).collect();
        let mut internal = vec![0u32; order.len()];
        for (k, &t) in order.iter().enumerate() {
            internal[t as usize] = k as u32;
        }
        let (edges, edge_extra, vertex_normals) = match normals {
            NormalSource::Own => {
                let vn = vertex_normals(&vertices, triangles);
                let (edges, extra) = edge_codes(&vertices, triangles, order, &internal);
                (edges, extra, vn)
            }
            NormalSource::Given(n) => {
                // Every edge from the table: the supplier's mesh is larger than this one.
                let mut extra = Vec::with_capacity(3 * order.len());
                let edges = order
                    .iter()
                    .map(|&t| {
                        std::array::from_fn(|i| {
                            extra.push(n.edge[t as usize][i]);
                            EXTRA | (extra.len() - 1) as u32
                        })
                    })
                    .collect();
                (edges, extra, n.vertex)
            }
        };
        Self {
            vertices,
            faces,
            ids: order.to_vec(),
            internal,
            edges,
            edge_extra,
            vertex_normals,
        }
    }

    pub fn len(&self) -> usize {
        self.faces.len()
    }

    #[inline]
    pub fn triangle(&self, t: usize) -> Triangle {
        let [a, b, c] = self.faces[t].map(|i| self.vertices[i as usize]);
        Triangle::new(a, b, c)
    }

    /// Internal triangles `ts` (one to four) into `lanes`; spare lanes repeat the first.
    #[inline(always)]
    pub fn load(&self, lanes: &mut Lanes<4>, ts: &[u32]) {
        let f = |l: usize| &self.faces[ts[if l < ts.len() { l } else { 0 }] as usize];
        lanes.set_faces(&self.vertices, [f(0), f(1), f(2), f(3)]);
    }

    /// Largest z of a triangle's vertices.
    #[inline]
    pub fn top(&self, t: usize) -> f64 {
        let [a, b, c] = self.faces[t].map(|i| self.vertices[i as usize].z);
        a.max(b).max(c)
    }

    /// Unit normal, zero for a triangle without area: as [`PseudoNormals`] computes it.
    #[inline]
    pub fn face_normal(&self, t: usize) -> Vector3<f64> {
        let p = self.faces[t].map(|i| self.vertices[i as usize]);
        face_normal(&p)
    }

    /// The pseudo-normal of the feature `region` of internal triangle `t`.
    #[inline(always)]
    pub fn pseudo_normal(&self, t: usize, region: Region) -> Vector3<f64> {
        match region {
            Region::Face => self.face_normal(t),
            Region::Edge(i) => match self.edges[t][i as usize] {
                BOUNDARY => self.face_normal(t),
                code if code & EXTRA != 0 => self.edge_extra[(code & !EXTRA) as usize],
                // The edge sum starts at zero and adds each face in design order; for two
                // faces that is one exact, commutative addition.
                nb => self.face_normal(t) + self.face_normal(nb as usize),
            },
            Region::Vertex(i) => self.vertex_normals[self.faces[t][i as usize] as usize],
        }
    }

    pub fn bytes(&self) -> usize {
        self.vertices.len() * size_of::<Point3<f64>>()
            + self.faces.len() * (size_of::<[u32; 3]>() * 2 + size_of::<u32>() * 2)
            + self.edge_extra.len() * size_of::<Vector3<f64>>()
            + self.vertex_normals.len() * size_of::<Vector3<f64>>()
    }
}

pub(crate) fn face_normal(p: &[Point3<f64>; 3]) -> Vector3<f64> {
    let n = (p[1] - p[0]).cross(&(p[2] - p[0]));
    n.try_normalize(0.0).unwrap_or_else(Vector3::zeros)
}

/// Neighbour codes from the edges sorted by their vertex pair: no hash map of 1.5 edges per
/// triangle, and parallel.
fn edge_codes(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    order: &[u32],
    internal: &[u32],
) -> (Vec<[u32; 3]>, Vec<Vector3<f64>>) {
    // (edge key, design triangle, edge index), sorted by key then triangle: faces in design
    // order within an edge, as the sum is taken. Collected three to a triangle into one vector
    // of the exact size: gathered piecemeal, the pieces and their concatenation were held at
    // once (115 MB at the peak of a million-triangle design's index build).
    let mut half: Vec<(u64, u32, u8)> = triangles
        .par_iter()
        .enumerate()
        .map(|(t, f)| {
            std::array::from_fn::<_, 3, _>(|i| {
                let (a, b) = (f[i], f[(i + 1) % 3]);
                let key = (a.min(b) as u64) << 32 | a.max(b) as u64;
                (key, t as u32, i as u8)
            })
        })
        .collect::<Vec<[_; 3]>>()
        .into_flattened();
    half.par_sort_unstable();
    let mut edges = vec![[BOUNDARY; 3]; order.len()];
    let mut extra = Vec::new();
    let mut s = 0;
    while s < half.len() {
        let mut e = s + 1;
        while e < half.len() && half[e].0 == half[s].0 {
            e += 1;
        }
        let group = &half[s..e];
        match group {
            [_] => {}
            [(_, t0, i0), (_, t1, i1)] => {
                edges[internal[*t0 as usize] as usize][*i0 as usize] = internal[*t1 as usize];
                edges[internal[*t1 as usize] as usize][*i1 as usize] = internal[*t0 as usize];
            }
            _ => {
                let mut sum = Vector3::zeros();
                for (_, t, _) in group {
                    sum += face_normal(&triangles[*t as usize].map(|i| vertices[i as usize]));
                }
                extra.push(sum);
                let code = EXTRA | (extra.len() - 1) as u32;
                for (_, t, i) in group {
                    edges[internal[*t as usize] as usize][*i as usize] = code;
                }
            }
        }
        s = e;
    }
    (edges, extra)
}
