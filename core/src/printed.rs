//! The design as printed so far, indexed once per printed height and shared by every station
//! that scans at that height (and by the findings over them).

use std::sync::Arc;

use crate::c2m::{C2mError, C2mIndex, C2mParams};
use crate::design::Design;
use crate::layers::{CutError, cut_at};

/// The design cut at one printed height (or whole), with its C2M index.
pub struct PrintedDesign {
    /// The cut height, metres; NaN for the whole design.
    pub height: f64,
    pub design: Design,
    pub index: Arc<C2mIndex>,
}

#[derive(Debug, thiserror::Error)]
pub enum PrintedError {
    #[error(transparent)]
    Cut(#[from] CutError),
    #[error(transparent)]
    Index(#[from] C2mError),
}

/// A few recently used cuts: a job scans several stations per printed height, one height after
/// the other, so memory stays at a few designs.
pub struct PrintedDesigns {
    full: Arc<PrintedDesign>,
    params: C2mParams,
    recent: Vec<Arc<PrintedDesign>>,
    top: f64,
}

const RECENT: usize = 3;

impl PrintedDesigns {
    pub fn new(design: Design, params: C2mParams) -> Result<Self, C2mError> {
        let index = Arc::new(C2mIndex::build(&design, params)?);
        let top = design.bounds().1.z;
        Ok(Self {
            full: Arc::new(PrintedDesign {
                height: f64::NAN,
                design,
                index,
            }),
            params,
            recent: Vec::new(),
            top,
        })
    }

    pub fn full(&self) -> &Arc<PrintedDesign> {
        &self.full
    }

    /// The design below `height`, closed by a cap; the whole design for a height that is not
    /// finite or not below the top.
    pub fn at(&mut self, height: f64) -> Result<Arc<PrintedDesign>, PrintedError> {
        if !height.is_finite() || height >= self.top {
            return Ok(self.full.clone());
        }
        if let Some(d) = self.recent.iter().find(|d| d.height == height) {
            return Ok(d.clone());
        }
        let (design, _) = cut_at(&self.full.design, height)?;
        let index = Arc::new(C2mIndex::build(&design, self.params)?);
        let d = Arc::new(PrintedDesign {
            height,
            design,
            index,
        });
        if self.recent.len() == RECENT {
            self.recent.remove(0);
        }
        self.recent.push(d.clone());
        Ok(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::shapes;
    use nalgebra::Point3;

    #[test]
    fn a_cut_is_built_once_and_the_whole_design_above_the_top() {
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
        assert!((a.design.bounds().1.z - 0.5).abs() < 1e-12);
        assert!(Arc::ptr_eq(&p.at(f64::NAN).unwrap(), p.full()));
        assert!(Arc::ptr_eq(&p.at(2.0).unwrap(), p.full()));
        assert!(p.at(-1.0).is_err());
    }
}
