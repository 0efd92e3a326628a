use std::collections::HashMap;

/// Edge-based checks of a triangle mesh.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
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
        // Per undirected edge: how many triangles use it in each direction.
        let mut uses: HashMap<(u32, u32), (u32, u32)> = HashMap::with_capacity(triangles.len() * 2);
        for t in triangles {
            for i in 0..3 {
                let (a, b) = (t[i], t[(i + 1) % 3]);
                let e = uses.entry((a.min(b), a.max(b))).or_default();
                if a < b {
                    e.0 += 1;
                } else {
                    e.1 += 1;
                }
            }
        }
        let mut out = Topology {
            edges: uses.len(),
            ..Default::default()
        };
        for &(fwd, back) in uses.values() {
            match fwd + back {
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
