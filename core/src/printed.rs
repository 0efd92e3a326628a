//! The design as printed so far. One index serves every printed height: a height needs only its
//! section (the triangles crossing it, clipped, and the cap), prepared in time proportional to
//! the section and shared by every station that scans at that height (and by the findings over
//! them). Preparing it can run on any thread ([`Preparer`]), so the agent's event loop never
//! does design work.

use std::sync::{Arc, OnceLock};

use nalgebra::Point3;

use crate::c2m::{C2mError, C2mIndex, C2mParams, Closest, Cursor, Section, Surface};
use crate::design::Design;
use crate::layers::{CutError, cut_at};

/// The design cut at one printed height (or whole), with the one index of the design.
pub struct PrintedDesign {
    /// The cut height, metres; NaN for the whole design.
    pub height: f64,
    pub index: Arc<C2mIndex>,
    section: Option<Section>,
    full: Arc<Design>,
    /// The cut as a mesh of its own, made only for those who sample it (findings).
    mesh: OnceLock<Design>,
    sharp: OnceLock<Vec<[Point3<f64>; 2]>>,
}

/// The surface turning by more than this is an edge (for M3C2's cylinders, which would average
/// two faces there).
pub const SHARP_EDGE_DEG: f64 = 30.0;

impl PrintedDesign {
    pub fn section(&self) -> Option<&Section> {
        self.section.as_ref()
    }

    /// The design as printed, as a mesh: the whole design, or the cut made (once) on first use.
    /// Only sampling needs it; C2M and lines of sight use the index and the section.
    pub fn design(&self) -> &Design {
        match &self.section {
            None => &self.full,
            Some(s) => self.mesh.get_or_init(|| {
                cut_at(&self.full, s.height())
                    .map(|(d, _)| d)
                    .unwrap_or_else(|_| (*self.full).clone())
            }),
        }
    }
}

impl PrintedDesign {
    /// The sharp edges of the design as printed ([`SHARP_EDGE_DEG`]; boundary and non-manifold
    /// edges too), found once.
    pub fn sharp_edges(&self) -> &[[Point3<f64>; 2]] {
        self.sharp
            .get_or_init(|| self.design().sharp_edges(SHARP_EDGE_DEG))
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

#[derive(Debug, thiserror::Error)]
pub enum PrintedError {
    #[error(transparent)]
    Cut(#[from] CutError),
    #[error(transparent)]
    Index(#[from] C2mError),
}

/// Prepares the design at a printed height; cheap to clone and send to a worker thread.
#[derive(Clone)]
pub struct Preparer {
    index: Arc<C2mIndex>,
    full: Arc<Design>,
    top: f64,
}

impl Preparer {
    /// The design below `height`, closed by a cap; the whole design for a height that is not
    /// finite or not below the top. With `mesh`, the cut mesh and its sharp edges are made too
    /// (for sampling).
    pub fn prepare(&self, height: f64, mesh: bool) -> Result<PrintedDesign, CutError> {
        let section = if height.is_finite() && height >= self.top {
            None
        } else {
            Some(self.index.section(height)?)
        };
        let d = PrintedDesign {
            height: if section.is_some() { height } else { f64::NAN },
            index: self.index.clone(),
            section,
            full: self.full.clone(),
            mesh: OnceLock::new(),
            sharp: OnceLock::new(),
        };
        if mesh {
            d.sharp_edges();
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
        let index = Arc::new(C2mIndex::build(&design, params)?);
        let top = design.bounds().1.z;
        let full = Arc::new(design);
        Ok(Self {
            full: Arc::new(PrintedDesign {
                height: f64::NAN,
                index: index.clone(),
                section: None,
                full: full.clone(),
                mesh: OnceLock::new(),
                sharp: OnceLock::new(),
            }),
            preparer: Preparer { index, full, top },
            recent: Vec::new(),
        })
    }

    pub fn full(&self) -> &Arc<PrintedDesign> {
        &self.full
    }

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
        let mut p = PrintedDesigns::new(
            d,
            C2mParams {
                max_distance: 0.1,
                cell_size: None,
            },
        )
        .unwrap();
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
}
