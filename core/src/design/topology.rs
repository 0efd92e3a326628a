use rayon::slice::ParallelSliceMut;

/// Edge-based checks of a triangle mesh.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Topology {
    /// Distinct undirected edges.
    pub edges: usize,
    /// Edges used by one triangle only: the mesh has holes or is a sheet.
    pub boundary_edges: usize,
    /// Edges used by three or more triangles.
    pub non_manifold_edges: usize,
    /// Manifold edges whose two triangles traverse them in the same direction.
    pub inconsistent_edges: usize,
}

impl Topology {
    /// The edge checks of `triangles`.
    pub fn of(triangles: &[[u32; 3]]) -> Self {
        let uses = EdgeUse::sorted(triangles);
        let mut out = Topology::default();
        for edge in uses.chunk_by(|a, b| a.key == b.key) {
            out.edges += 1;
            let fwd = edge.iter().filter(|e| e.forward).count();
            match edge.len() {
                1 => out.boundary_edges += 1,
                2 if fwd != 1 => out.inconsistent_edges += 1,
                2 => {}
                _ => out.non_manifold_edges += 1,
            }
        }
        out
    }

    /// Whether every edge has two triangles that traverse it in opposite directions.
    pub fn is_closed_and_oriented(&self) -> bool {
        self.boundary_edges == 0 && self.non_manifold_edges == 0 && self.inconsistent_edges == 0
    }
}

/// One triangle's use of an undirected edge.
#[derive(Debug, Clone, Copy)]
pub(crate) struct EdgeUse {
    /// The edge's vertices, lower index in the high half.
    pub key: u64,
    pub triangle: u32,
    /// Whether the triangle traverses the edge from its lower vertex to its higher.
    pub forward: bool,
}

impl EdgeUse {
    /// Every edge of every triangle, sorted by edge and then triangle, so the triangles that
    /// share an edge sit together (`chunk_by` on the key). A sort, not a hash map of edges: on a
    /// million-triangle design it takes a tenth of the time the map took to fill.
    pub fn sorted(triangles: &[[u32; 3]]) -> Vec<EdgeUse> {
        let mut uses: Vec<EdgeUse> = triangles
            .iter()
            .zip(0u32..)
            .flat_map(|(t, triangle)| {
                (0..3).map(move |i| {
                    let (a, b) = (t[i], t[(i + 1) % 3]);
                    EdgeUse {
                        key: (u64::from(a.min(b)) << 32) | u64::from(a.max(b)),
                        triangle,
                        forward: a < b,
                    }
                })
            })
            .collect();
        uses.par_sort_unstable_by_key(|e| (e.key, e.triangle));
        uses
    }

    /// The edge's two vertices, lower index first.
    pub fn vertices(&self) -> [u32; 2] {
        [(self.key >> 32) as u32, self.key as u32]
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use nalgebra::Point3;

    use super::*;
    use crate::design::shapes::{cuboid, sheet, study_wall, twisted_column};
    use crate::design::{Design, sharp_edges, sort_edges};

    /// Meshes with every kind of edge: closed, open, a flipped face, a fin on an edge.
    fn meshes() -> Vec<Design> {
        let cube = cuboid(Point3::origin(), Point3::new(1.0, 2.0, 3.0));
        let mut flipped = cube.clone();
        flipped.triangles[3].swap(0, 1);
        let mut fin = cube.clone();
        let [a, b, _] = fin.triangles[0];
        fin.vertices.push(Point3::new(-1.0, -1.0, -1.0));
        fin.triangles.push([a, b, (fin.vertices.len() - 1) as u32]);
        let column = twisted_column(0.15, 0.1, 0.4, 45.0, 60, 40);
        vec![cube, flipped, fin, sheet(1.0, 0.0, 7), study_wall(), column]
    }

    #[test]
    fn topology_counts_as_a_map_of_edges_does() {
        for d in meshes() {
            let mut uses: BTreeMap<(u32, u32), (u32, u32)> = BTreeMap::new();
            for t in &d.triangles {
                for i in 0..3 {
                    let (a, b) = (t[i], t[(i + 1) % 3]);
                    let e = uses.entry((a.min(b), a.max(b))).or_default();
                    if a < b { e.0 += 1 } else { e.1 += 1 }
                }
            }
            let mut want = Topology {
                edges: uses.len(),
                ..Default::default()
            };
            for &(f, b) in uses.values() {
                match f + b {
                    1 => want.boundary_edges += 1,
                    2 if f != 1 => want.inconsistent_edges += 1,
                    2 => {}
                    _ => want.non_manifold_edges += 1,
                }
            }
            assert_eq!(Topology::of(&d.triangles), want);
        }
    }

    #[test]
    fn sharp_edges_are_those_a_pairwise_search_finds() {
        for d in meshes() {
            let normal = |t: &[u32; 3]| {
                let [a, b, c] = t.map(|i| d.vertices[i as usize]);
                let n = (b - a).cross(&(c - a));
                n / n.norm().max(f64::MIN_POSITIVE)
            };
            let include = |f: usize| f % 3 != 1;
            let cos_max = 30f64.to_radians().cos();
            let mut want = Vec::new();
            let mut edges: Vec<(u32, u32)> = d
                .triangles
                .iter()
                .flat_map(|t| {
                    (0..3).map(move |i| (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3])))
                })
                .collect();
            edges.sort_unstable();
            edges.dedup();
            for (u, v) in edges {
                let faces: Vec<usize> = (0..d.triangles.len())
                    .filter(|&f| {
                        let t = d.triangles[f];
                        (0..3)
                            .any(|i| (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3])) == (u, v))
                    })
                    .collect();
                let sharp = faces.len() != 2
                    || normal(&d.triangles[faces[0]]).dot(&normal(&d.triangles[faces[1]]))
                        < cos_max;
                if sharp && faces.iter().any(|&f| include(f)) {
                    want.push([d.vertices[u as usize], d.vertices[v as usize]]);
                }
            }
            sort_edges(&mut want);
            assert_eq!(sharp_edges(&d.vertices, &d.triangles, 30.0, include), want);
        }
    }
}
