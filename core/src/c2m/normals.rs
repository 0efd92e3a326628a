//! Angle-weighted pseudo-normals (Bærentzen & Aanæs, *Signed distance computation using the
//! angle weighted pseudonormal*, 2005). With the pseudo-normal of the feature that holds the
//! closest point, `sign((p - q) · n)` is the inside/outside test, exact at edges and corners of a
//! closed, consistently oriented mesh.

use std::collections::HashMap;

use nalgebra::{Point3, Vector3};

use super::mesh::face_normal;

pub struct PseudoNormals {
    /// Per triangle, per edge `i` (vertex `i` to `i + 1`): the sum of the unit normals of the
    /// faces that share the edge (each face's angle at an edge is π, so the weights are equal).
    pub edge: Vec<[Vector3<f64>; 3]>,
    pub vertex: Vec<Vector3<f64>>,
}

impl PseudoNormals {
    pub fn new(vertices: &[Point3<f64>], triangles: &[[u32; 3]]) -> Self {
        let mut edge_sum: HashMap<(u32, u32), Vector3<f64>> =
            HashMap::with_capacity(triangles.len() * 3 / 2);
        for t in triangles {
            let n = face_normal(&t.map(|i| vertices[i as usize]));
            for i in 0..3 {
                *edge_sum.entry(edge_key(t[i], t[(i + 1) % 3])).or_default() += n;
            }
        }
        let edge = triangles
            .iter()
            .map(|t| std::array::from_fn(|i| edge_sum[&edge_key(t[i], t[(i + 1) % 3])]))
            .collect();
        Self {
            edge,
            vertex: vertex_normals(vertices, triangles),
        }
    }
}

/// Angle-weighted vertex normals, summed in the triangles' order (the order fixes the bits).
pub fn vertex_normals(vertices: &[Point3<f64>], triangles: &[[u32; 3]]) -> Vec<Vector3<f64>> {
    let mut vertex = vec![Vector3::zeros(); vertices.len()];
    for t in triangles {
        let p = t.map(|i| vertices[i as usize]);
        let n = face_normal(&p);
        for i in 0..3 {
            let e1 = p[(i + 1) % 3] - p[i];
            let e2 = p[(i + 2) % 3] - p[i];
            let angle = e1.angle(&e2);
            if angle.is_finite() {
                vertex[t[i] as usize] += n * angle;
            }
        }
    }
    vertex
}

pub(crate) fn edge_key(a: u32, b: u32) -> (u32, u32) {
    if a < b { (a, b) } else { (b, a) }
}
