//! The design cut at one printed height, as the whole design's index needs it: the triangles
//! that cross the height, clipped as `crate::layers::cut_at` clips them, and the cap that closes
//! the cut, in a small index of their own. The triangles wholly below the cut are the design's
//! own and are searched in the design's index; nothing of the design is copied.
//!
//! The work is proportional to the section: the crossing triangles come from the design's BVH
//! (the nodes whose height range holds the cut), and so do the triangles around them, whose
//! normals the clipped pieces' edges and corners share.

use std::collections::HashMap;

use nalgebra::Point3;

use super::bvh::All;
use super::mesh::NormalSource;
use super::normals::PseudoNormals;
use super::{C2mIndex, C2mParams, CellCache, Closest, Cursor, GridUse};
use crate::layers::{ClipVertex, CutError, CutReport, CutVertex, cap, clip_below};

/// The mesh a section was made in: the triangles around the crossing ones (the first `ring`),
/// then the section's; each vertex's design vertex (`u32::MAX` for a point the cut adds).
pub(crate) struct LocalMesh<'a> {
    pub vertices: &'a [Point3<f64>],
    pub triangles: &'a [[u32; 3]],
    pub ring: usize,
    pub design_vertex: &'a [u32],
}

/// The design cut at one height: prepared by [`C2mIndex::section`], used by
/// [`C2mIndex::query_cut`].
pub struct Section {
    height: f64,
    /// The clipped pieces and the cap; `None` when nothing crosses the height.
    pub(super) index: Option<C2mIndex>,
    /// Section triangle → the id reported for it: the design triangle a piece came from, or the
    /// design's triangle count plus the cap triangle's number.
    reported: Vec<u32>,
    report: CutReport,
    /// The local mesh the section was made in: the triangles around the crossing ones (the
    /// first `ring` of `local`), then the section's, in the cut's order; and each local
    /// vertex's design vertex (`u32::MAX` for a point the cut adds). The cut mesh and its edges
    /// are put together from these and the design.
    local: Vec<[u32; 3]>,
    ring: usize,
    design_vertex: Vec<u32>,
}

impl Section {
    /// The printed height the design is cut at, metres.
    pub fn height(&self) -> f64 {
        self.height
    }

    /// Loops, cap triangles and open chains of the cut's outline.
    pub fn report(&self) -> CutReport {
        self.report
    }

    /// Triangles in the section's own index (pieces and cap).
    pub fn triangles(&self) -> usize {
        self.reported.len()
    }

    /// Memory of the section (its index and triangle map), bytes.
    pub fn bytes(&self) -> usize {
        self.index.as_ref().map_or(0, |i| i.stats().bytes)
            + self.reported.len() * 4
            + self.local.len() * 12
            + self.design_vertex.len() * 4
    }

    /// The section's triangles in the cut's order (the pieces of each crossing triangle in
    /// design order, then the cap), as points, with the id each reports.
    pub(crate) fn pieces(&self) -> impl Iterator<Item = ([Point3<f64>; 3], u32)> + '_ {
        let vertices = self.local_vertices();
        self.local[self.ring..]
            .iter()
            .zip(&self.reported)
            .map(move |(t, &r)| (t.map(|i| vertices[i as usize]), r))
    }

    /// The local mesh the section was made in.
    pub(crate) fn local_mesh(&self) -> LocalMesh<'_> {
        LocalMesh {
            vertices: self.local_vertices(),
            triangles: &self.local,
            ring: self.ring,
            design_vertex: &self.design_vertex,
        }
    }

    fn local_vertices(&self) -> &[Point3<f64>] {
        self.index.as_ref().map_or(&[], |i| &i.mesh.vertices)
    }

    /// The closest section triangle (internal to the section) and squared distance.
    pub(super) fn closest(
        &self,
        p: &Point3<f64>,
        cursor: &mut Cursor,
        limit2: f64,
    ) -> Option<(u32, f64)> {
        let index = self.index.as_ref()?;
        let cache: &mut CellCache = &mut cursor.section_cell;
        index
            .closest(p, cache, cursor.section_last, limit2)
            .filter(|&(_, d2)| d2 <= limit2)
    }

    pub(super) fn signed(&self, p: &Point3<f64>, t: u32) -> Closest {
        let index = self.index.as_ref().expect("a section hit has an index");
        let mut c = index.signed(p, t);
        c.triangle = self.reported[c.triangle as usize];
        c
    }

    pub(super) fn blocks_sight(
        &self,
        eye: &Point3<f64>,
        target: &Point3<f64>,
        margin: f64,
    ) -> bool {
        self.index
            .as_ref()
            .is_some_and(|i| i.blocks_sight_filtered(eye, target, margin, &All))
    }
}

impl C2mIndex {
    /// Prepares queries against the design cut at `height` and closed by a cap, in time and
    /// memory proportional to the section. A height at or above the design's top leaves the
    /// design whole (an empty section).
    pub fn section(&self, height: f64) -> Result<Section, CutError> {
        self.section_indexed(height, GridUse::Cells)
    }

    /// [`C2mIndex::section`] with its pieces indexed as `grid` says.
    pub(super) fn section_indexed(&self, height: f64, grid: GridUse) -> Result<Section, CutError> {
        if !height.is_finite() {
            return Err(CutError::Height { height });
        }
        if height <= self.lowest {
            return Err(CutError::BelowDesign {
                height,
                lowest: self.lowest,
            });
        }
        let (crossing, ring) = self.crossing_and_ring(height);
        let mut local = self.clip(&ring, &crossing, height);
        let mut vertices = std::mem::take(&mut local.vertices.vertices);
        let mut report = CutReport::default();
        let before = local.triangles.len();
        cap(
            &mut vertices,
            &local.segments,
            &mut local.triangles,
            &mut report,
        );
        let n = self.mesh.len() as u32;
        let capped = (local.triangles.len() - before) as u32;
        local
            .reported
            .extend((0..capped).map(|k| n.saturating_add(k)));
        Ok(self.index_section(height, local, vertices, report, grid))
    }

    /// The triangles crossing `height` (some vertex below it and some not, as `cut_at` tells
    /// them) and the whole triangles below it around them, which share the pieces' lower edges
    /// and corners; each in design order, as `cut_at` visits them.
    fn crossing_and_ring(&self, height: f64) -> (Vec<u32>, Vec<u32>) {
        let mesh = &self.mesh;
        let below = |i: u32| mesh.vertices[i as usize].z < height;
        let mut found = Vec::new();
        self.bvh.crossing(height, &mut found);
        let mut crossing: Vec<u32> = found
            .into_iter()
            .filter(|&t| {
                let n = mesh.faces[t as usize].iter().filter(|&&i| below(i)).count();
                n == 1 || n == 2
            })
            .collect();
        crossing.sort_unstable_by_key(|&t| mesh.ids[t as usize]);
        let mut ring: Vec<u32> = Vec::new();
        let mut corners: Vec<u32> = crossing
            .iter()
            .flat_map(|&t| mesh.faces[t as usize])
            .filter(|&i| below(i))
            .collect();
        corners.sort_unstable();
        corners.dedup();
        let mut near = Vec::new();
        for &v in &corners {
            near.clear();
            self.bvh.containing(&mesh.vertices[v as usize], &mut near);
            ring.extend(near.iter().copied().filter(|&t| {
                let f = mesh.faces[t as usize];
                f.contains(&v) && f.iter().all(|&i| below(i))
            }));
        }
        ring.sort_unstable_by_key(|&t| mesh.ids[t as usize]);
        ring.dedup();
        (crossing, ring)
    }

    /// A local mesh: the ring whole, then the crossing triangles clipped below `height`, each
    /// piece with the design triangle it reports, and the cut's segments for the cap.
    fn clip(&self, ring: &[u32], crossing: &[u32], height: f64) -> Clipped {
        let mesh = &self.mesh;
        let mut local = LocalVertices::default();
        let mut triangles: Vec<[u32; 3]> = Vec::new();
        for &t in ring {
            let f = mesh.faces[t as usize].map(|i| local.id(i, mesh.vertices[i as usize]));
            triangles.push(f);
        }
        let ring_len = triangles.len();
        let mut reported: Vec<u32> = Vec::new();
        let mut cut_ids: HashMap<CutVertex, u32> = HashMap::new();
        let mut segments: Vec<(u32, u32)> = Vec::new();
        for &t in crossing {
            let before = triangles.len();
            let mut id = |cv: ClipVertex| match cv {
                ClipVertex::Keep(i) => local.id(i, mesh.vertices[i as usize]),
                ClipVertex::Cut(cv) => *cut_ids.entry(cv).or_insert_with(|| match cv {
                    CutVertex::Vertex(i) => local.id(i, mesh.vertices[i as usize]),
                    CutVertex::Edge(a, b) => {
                        let (pa, pb) = (mesh.vertices[a as usize], mesh.vertices[b as usize]);
                        let s = (height - pa.z) / (pb.z - pa.z);
                        let mut p = pa + (pb - pa) * s;
                        p.z = height;
                        local.push(p)
                    }
                }),
            };
            let z = |i: u32| mesh.vertices[i as usize].z;
            if let Some(s) = clip_below(mesh.faces[t as usize], z, height, &mut id, &mut triangles)
            {
                segments.push(s);
            }
            reported.extend(std::iter::repeat_n(
                mesh.ids[t as usize],
                triangles.len() - before,
            ));
        }
        Clipped {
            vertices: local,
            triangles,
            ring_len,
            reported,
            segments,
        }
    }

    /// The section's own index over its pieces and cap (the ring only lends them normals);
    /// pieces without area are dropped, as `Design::from_indexed` drops them from the cut.
    fn index_section(
        &self,
        height: f64,
        local: Clipped,
        vertices: Vec<Point3<f64>>,
        report: CutReport,
        grid: GridUse,
    ) -> Section {
        let Clipped {
            vertices: ids,
            triangles,
            ring_len,
            reported,
            ..
        } = local;
        let keep: Vec<bool> = triangles.iter().map(|t| has_area(*t, &vertices)).collect();
        let kept: Vec<[u32; 3]> = (0..triangles.len())
            .filter(|&k| keep[k])
            .map(|k| triangles[k])
            .collect();
        let normals = PseudoNormals::new(&vertices, &kept);
        let mut design_vertex = vec![u32::MAX; vertices.len()];
        for (&g, &l) in &ids.ids {
            design_vertex[l as usize] = g;
        }
        let ring_kept = keep[..ring_len].iter().filter(|&&k| k).count();
        let mut section_tris = Vec::new();
        let mut section_reported = Vec::new();
        let mut edge = Vec::new();
        let mut k = ring_kept;
        for (j, t) in triangles.iter().enumerate().skip(ring_len) {
            if !keep[j] {
                continue;
            }
            section_tris.push(*t);
            section_reported.push(reported[j - ring_len]);
            edge.push(normals.edge[k]);
            k += 1;
        }
        let index = (!section_tris.is_empty()).then(|| {
            let given = PseudoNormals {
                edge,
                vertex: normals.vertex,
            };
            // A grid, as the design has: on the study's wall, whose twelve faces every cut
            // crosses, the section holds the whole printed surface, and its grid answers a cut
            // query 1.4 to 1.9 times as fast as its BVH alone (one thread, 2 M points, three
            // heights: `index_probe wall --cut`). On the bunny the two are even, and the grid
            // takes 15–24 ms to build where the BVH took 3–4 ms, once a printed height.
            let params = C2mParams::within(self.max_distance);
            C2mIndex::build_mesh(
                vertices,
                section_tris.into(),
                NormalSource::Given(given),
                params,
                grid,
            )
            .expect("the design's own parameters were valid")
        });
        let has_index = index.is_some();
        Section {
            height,
            index,
            reported: section_reported,
            report,
            // Without pieces there is no local mesh to keep (nor vertices for it).
            local: if has_index { kept } else { Vec::new() },
            ring: if has_index { ring_kept } else { 0 },
            design_vertex,
        }
    }
}

/// Whether triangle `t` of `vertices` has an area: three distinct corners, a finite non-zero
/// cross product.
fn has_area(t: [u32; 3], vertices: &[Point3<f64>]) -> bool {
    let [a, b, c] = t.map(|i| vertices[i as usize]);
    let area2 = (b - a).cross(&(c - a)).norm();
    !(t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || area2 <= 0.0 || !area2.is_finite())
}

/// The local mesh before its cap: the ring whole, then the crossing triangles' pieces.
struct Clipped {
    /// Design vertices renumbered, and the points the cut adds.
    vertices: LocalVertices,
    triangles: Vec<[u32; 3]>,
    /// Triangles of the ring, first in `triangles`.
    ring_len: usize,
    /// Each piece's (and then cap triangle's) reported id.
    reported: Vec<u32>,
    /// The cut's segments, in local vertices.
    segments: Vec<(u32, u32)>,
}

/// Design vertices renumbered for a local mesh, with the points the cut adds.
#[derive(Default)]
struct LocalVertices {
    ids: HashMap<u32, u32>,
    vertices: Vec<Point3<f64>>,
}

impl LocalVertices {
    fn id(&mut self, design_vertex: u32, p: Point3<f64>) -> u32 {
        *self.ids.entry(design_vertex).or_insert_with(|| {
            self.vertices.push(p);
            (self.vertices.len() - 1) as u32
        })
    }

    fn push(&mut self, p: Point3<f64>) -> u32 {
        self.vertices.push(p);
        (self.vertices.len() - 1) as u32
    }
}
