//! The design as printed so far. One index serves every printed height: a height needs only its
//! section (the triangles crossing it, clipped, and the cap), prepared in time proportional to
//! the section and shared by every station that scans at that height (and by the findings over
//! them). Preparing it can run on any thread ([`Preparer`]), so the agent's event loop never
//! does design work.

use std::sync::{Arc, OnceLock};

use nalgebra::Point3;

use crate::c2m::{C2mError, C2mIndex, C2mParams, Closest, Cursor, Section, Surface};
use crate::design::Design;
use crate::layers::CutError;

/// The design cut at one printed height (or whole), with the one index of the design.
pub struct PrintedDesign {
    /// The cut height, metres; NaN for the whole design.
    pub height: f64,
    /// The design's one index, which answers for this height too.
    pub index: Arc<C2mIndex>,
    section: Option<Section>,
    full: Arc<Design>,
    /// The cut as a mesh of its own, made only for those who sample it (findings).
    mesh: OnceLock<Design>,
    sharp: OnceLock<Vec<[Point3<f64>; 2]>>,
    /// The whole design's sharp edges, shared by every height (a cut's are those below it and
    /// those the section makes).
    full_sharp: Arc<OnceLock<Vec<[Point3<f64>; 2]>>>,
}

/// The surface turning by more than this is an edge (for M3C2's cylinders, which would average
/// two faces there).
pub const SHARP_EDGE_DEG: f64 = 30.0;

impl PrintedDesign {
    /// The section at the cut height; `None` for the whole design.
    pub fn section(&self) -> Option<&Section> {
        self.section.as_ref()
    }

    /// The design as printed, as a mesh: the whole design, or the cut made (once) on first use,
    /// equal to `crate::layers::cut_at`'s triangle for triangle: the design's triangles below
    /// the cut and the section's pieces, in the design's order, then the cap. Only sampling
    /// needs it; C2M and lines of sight use the index and the section.
    pub fn design(&self) -> &Design {
        match &self.section {
            None => &self.full,
            Some(s) => self
                .mesh
                .get_or_init(|| BelowCut::of(&self.full, s.height()).with_section(s)),
        }
    }
}

/// What a cut mesh takes from the design: its vertices and the triangles wholly below the
/// height, in design order, with the place of each crossing triangle (whose pieces the section
/// makes). Found without the section, so that it can be found beside it.
struct BelowCut {
    vertices: Vec<Point3<f64>>,
    triangles: Vec<[u32; 3]>,
    /// (position in `triangles`, design triangle) of each crossing triangle, in design order.
    crossing: Vec<(usize, u32)>,
}

impl BelowCut {
    fn of(full: &Design, h: f64) -> Self {
        use rayon::prelude::*;
        let below = |i: u32| full.vertices[i as usize].z < h;
        // The vertices' heights are read in parallel; the triangles are then kept in order.
        let below_count: Vec<u8> = full
            .triangles
            .par_iter()
            .map(|f| f.iter().filter(|&&i| below(i)).count() as u8)
            .collect();
        let mut triangles = Vec::with_capacity(full.triangles.len());
        let mut crossing = Vec::new();
        for (t, (f, &n)) in full.triangles.iter().zip(&below_count).enumerate() {
            match n {
                3 => triangles.push(*f),
                0 => {}
                _ => crossing.push((triangles.len(), t as u32)),
            }
        }
        Self {
            vertices: full.vertices.clone(),
            triangles,
            crossing,
        }
    }

    /// The design cut at the section's height, equal to `crate::layers::cut_at`'s triangle for
    /// triangle: the triangles below with each crossing triangle's pieces in its place, then
    /// the cap.
    fn with_section(self, section: &Section) -> Design {
        let local = section.local_mesh();
        let mut vertices = self.vertices;
        // Local vertex → vertex of the cut mesh: the design's own, or a cut point added.
        let ids: Vec<u32> = local
            .design_vertex
            .iter()
            .zip(local.vertices)
            .map(|(&g, p)| {
                if g != u32::MAX {
                    g
                } else {
                    vertices.push(*p);
                    (vertices.len() - 1) as u32
                }
            })
            .collect();
        let pieces = &local.triangles[local.ring..];
        let reported: Vec<u32> = section.pieces().map(|(_, r)| r).collect();
        let mut triangles = Vec::with_capacity(self.triangles.len() + pieces.len());
        let (mut k, mut from) = (0, 0);
        for &(at, t) in &self.crossing {
            triangles.extend_from_slice(&self.triangles[from..at]);
            from = at;
            while k < pieces.len() && reported[k] == t {
                triangles.push(pieces[k].map(|i| ids[i as usize]));
                k += 1;
            }
        }
        triangles.extend_from_slice(&self.triangles[from..]);
        // The cap.
        triangles.extend(pieces[k..].iter().map(|p| p.map(|i| ids[i as usize])));
        Design {
            vertices,
            triangles,
            report: Default::default(),
        }
    }
}

/// The sharp edges of the design cut at the section's height: the design's wholly below the
/// cut and off the crossing triangles, and those of the section's local mesh that touch a piece
/// or the cap.
fn cut_sharp_edges(
    full: &Design,
    full_sharp: &[[Point3<f64>; 2]],
    section: &Section,
) -> Vec<[Point3<f64>; 2]> {
    use std::collections::HashSet;
    let h = section.height();
    let key = |a: &Point3<f64>, b: &Point3<f64>| {
        let (a, b) = (a.coords.map(f64::to_bits), b.coords.map(f64::to_bits));
        let (a, b) = ([a.x, a.y, a.z], [b.x, b.y, b.z]);
        if a <= b { (a, b) } else { (b, a) }
    };
    let n = full.triangles.len() as u32;
    let mut replaced = HashSet::new();
    for (_, r) in section.pieces().filter(|&(_, r)| r < n) {
        let f = full.triangles[r as usize];
        for k in 0..3 {
            let (a, b) = (
                full.vertices[f[k] as usize],
                full.vertices[f[(k + 1) % 3] as usize],
            );
            if a.z < h && b.z < h {
                replaced.insert(key(&a, &b));
            }
        }
    }
    let mut out: Vec<[Point3<f64>; 2]> = full_sharp
        .iter()
        .filter(|[a, b]| a.z < h && b.z < h && !replaced.contains(&key(a, b)))
        .copied()
        .collect();
    let local = section.local_mesh();
    out.extend(crate::design::sharp_edges(
        local.vertices,
        local.triangles,
        SHARP_EDGE_DEG,
        |f| f >= local.ring,
    ));
    crate::design::sort_edges(&mut out);
    out
}

impl PrintedDesign {
    /// The sharp edges of the design as printed ([`SHARP_EDGE_DEG`]; boundary and non-manifold
    /// edges too), found once.
    pub fn sharp_edges(&self) -> &[[Point3<f64>; 2]] {
        let full = || self.full.sharp_edges(SHARP_EDGE_DEG);
        match &self.section {
            None => self.full_sharp.get_or_init(full),
            Some(s) => self
                .sharp
                .get_or_init(|| cut_sharp_edges(&self.full, self.full_sharp.get_or_init(full), s)),
        }
    }
}

impl Surface for PrintedDesign {
    #[inline]
    fn closest(&self, p: &Point3<f64>, cursor: &mut Cursor) -> Option<Closest> {
        match &self.section {
            None => self.index.query(p, cursor),
            Some(s) => self.index.query_cut(p, cursor, s),
        }
    }

    fn max_distance(&self) -> f64 {
        self.index.max_distance()
    }

    fn blocks_sight(&self, eye: &Point3<f64>, target: &Point3<f64>, margin: f64) -> bool {
        match &self.section {
            None => self.index.blocks_sight(eye, target, margin),
            Some(s) => self.index.blocks_sight_cut(eye, target, margin, s),
        }
    }
}

/// A printed height that cannot be prepared.
#[derive(Debug, thiserror::Error)]
pub enum PrintedError {
    /// The design cannot be cut there.
    #[error(transparent)]
    Cut(#[from] CutError),
    /// The design cannot be indexed.
    #[error(transparent)]
    Index(#[from] C2mError),
}

/// Prepares the design at a printed height; cheap to clone and send to a worker thread.
#[derive(Clone)]
pub struct Preparer {
    index: Arc<C2mIndex>,
    full: Arc<Design>,
    full_sharp: Arc<OnceLock<Vec<[Point3<f64>; 2]>>>,
    top: f64,
}

impl Preparer {
    /// The design below `height`, closed by a cap; the whole design for a height that is not
    /// finite or not below the top. With `mesh`, the cut mesh and its sharp edges are made too
    /// (for sampling).
    pub fn prepare(&self, height: f64, mesh: bool) -> Result<PrintedDesign, CutError> {
        let whole = height.is_finite() && height >= self.top;
        // The section is the index's, the rest of the cut mesh the design's: made side by side.
        let (section, below) = match (whole, mesh) {
            (true, _) => (None, None),
            (false, false) => (Some(self.index.section(height)?), None),
            (false, true) => {
                let (section, below) = rayon::join(
                    || self.index.section(height),
                    || BelowCut::of(&self.full, height),
                );
                (Some(section?), Some(below))
            }
        };
        let d = PrintedDesign {
            height: if section.is_some() { height } else { f64::NAN },
            index: self.index.clone(),
            section,
            full: self.full.clone(),
            mesh: OnceLock::new(),
            sharp: OnceLock::new(),
            full_sharp: self.full_sharp.clone(),
        };
        if mesh {
            rayon::join(
                || {
                    if let (Some(b), Some(s)) = (below, &d.section) {
                        let _ = d.mesh.set(b.with_section(s));
                    }
                },
                || {
                    d.sharp_edges();
                },
            );
        }
        Ok(d)
    }
}

/// The whole design and a few recently used heights: a job scans several stations per printed
/// height, one height after the other.
pub struct PrintedDesigns {
    full: Arc<PrintedDesign>,
    preparer: Preparer,
    recent: Vec<Arc<PrintedDesign>>,
}

const RECENT: usize = 3;

impl PrintedDesigns {
    /// Indexes the design once; every height is served from that index.
    pub fn new(design: Design, params: C2mParams) -> Result<Self, C2mError> {
        let index = C2mIndex::build(&design, params)?;
        Ok(Self::with_index(design, index))
    }

    /// [`PrintedDesigns::new`] over an index built for `design` before (one kept between runs).
    pub fn with_index(design: Design, index: C2mIndex) -> Self {
        let index = Arc::new(index);
        let top = design.bounds().1.z;
        let full = Arc::new(design);
        let full_sharp = Arc::new(OnceLock::new());
        Self {
            full: Arc::new(PrintedDesign {
                height: f64::NAN,
                index: index.clone(),
                section: None,
                full: full.clone(),
                mesh: OnceLock::new(),
                sharp: OnceLock::new(),
                full_sharp: full_sharp.clone(),
            }),
            preparer: Preparer {
                index,
                full,
                full_sharp,
                top,
            },
            recent: Vec::new(),
        }
    }

    /// The whole design, as a printed design with no cut.
    pub fn full(&self) -> &Arc<PrintedDesign> {
        &self.full
    }

    /// The whole design as read, shared (for those who show it).
    pub fn whole_design(&self) -> &Arc<Design> {
        &self.preparer.full
    }

    /// A preparer to make printed heights on a worker thread.
    pub fn preparer(&self) -> Preparer {
        self.preparer.clone()
    }

    /// The design at `height` if nothing needs preparing: the whole design (a height not
    /// finite or not below the top) or a recent height.
    pub fn cached(&self, height: f64) -> Option<Arc<PrintedDesign>> {
        if !height.is_finite() || height >= self.preparer.top {
            return Some(self.full.clone());
        }
        self.recent.iter().find(|d| d.height == height).cloned()
    }

    /// Keeps a prepared height for the stations that follow.
    pub fn insert(&mut self, d: Arc<PrintedDesign>) {
        if d.section.is_none() || self.recent.iter().any(|r| r.height == d.height) {
            return;
        }
        if self.recent.len() == RECENT {
            self.recent.remove(0);
        }
        self.recent.push(d);
    }

    /// The design at `height`, prepared here if it is not cached.
    pub fn at(&mut self, height: f64) -> Result<Arc<PrintedDesign>, PrintedError> {
        if let Some(d) = self.cached(height) {
            return Ok(d);
        }
        let d = Arc::new(self.preparer.prepare(height, false)?);
        self.insert(d.clone());
        Ok(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::shapes;
    use nalgebra::Point3;

    #[test]
    fn a_height_is_prepared_once_and_the_whole_design_serves_above_the_top() {
        let d = shapes::cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 1.0, 1.0));
        let mut p = PrintedDesigns::new(d, C2mParams::within(0.1)).unwrap();
        let a = p.at(0.5).unwrap();
        let b = p.at(0.5).unwrap();
        assert!(Arc::ptr_eq(&a, &b));
        assert!(
            Arc::ptr_eq(&a.index, &p.full().index),
            "one index for every height"
        );
        assert!((a.design().bounds().1.z - 0.5).abs() < 1e-12);
        // The top of the print is compared with the cap.
        let c = a
            .closest(&Point3::new(0.5, 0.5, 0.52), &mut Cursor::default())
            .unwrap();
        assert!((c.distance - 0.02).abs() < 1e-12, "{c:?}");
        assert!(Arc::ptr_eq(&p.at(f64::NAN).unwrap(), p.full()));
        assert!(Arc::ptr_eq(&p.at(2.0).unwrap(), p.full()));
        assert!(p.at(-1.0).is_err());
    }

    /// The cut mesh and its sharp edges, put together from the design and the section, equal
    /// what cutting the design gives.
    #[test]
    fn the_cut_mesh_and_its_edges_equal_cut_at() {
        let column = shapes::twisted_column(0.15, 0.1, 1.2, 90.0, 64, 30);
        let cube = shapes::cuboid(Point3::new(-0.3, 0.0, 0.1), Point3::new(0.7, 2.0, 0.5));
        for (design, heights) in [(column, vec![0.07, 0.6, 1.13]), (cube, vec![0.3])] {
            let mut p = PrintedDesigns::new(design.clone(), C2mParams::default()).unwrap();
            for h in heights {
                let d = p.at(h).unwrap();
                let (cut, _) = crate::layers::cut_at(&design, h).unwrap();
                let tris = |m: &Design| -> Vec<[[u64; 3]; 3]> {
                    m.triangles
                        .iter()
                        .map(|t| t.map(|i| m.vertices[i as usize].coords.map(f64::to_bits).into()))
                        .collect()
                };
                assert_eq!(tris(d.design()), tris(&cut), "height {h}");
                // Made ahead, beside the section, as the agent prepares a height.
                let ahead = p.preparer().prepare(h, true).unwrap();
                assert_eq!(tris(ahead.design()), tris(&cut), "height {h}, ahead");
                assert_eq!(ahead.sharp_edges(), d.sharp_edges(), "height {h}, ahead");
                let norm = |e: &[[Point3<f64>; 2]]| -> Vec<[[u64; 3]; 2]> {
                    let mut v: Vec<[[u64; 3]; 2]> = e
                        .iter()
                        .map(|[a, b]| {
                            let (a, b) = (
                                a.coords.map(f64::to_bits).into(),
                                b.coords.map(f64::to_bits).into(),
                            );
                            if a <= b { [a, b] } else { [b, a] }
                        })
                        .collect();
                    v.sort();
                    v
                };
                assert_eq!(
                    norm(d.sharp_edges()),
                    norm(&cut.sharp_edges(SHARP_EDGE_DEG)),
                    "height {h}"
                );
            }
        }
    }
}
