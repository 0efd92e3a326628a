//! Dimensions and plumb from the same faces: the distance between opposite faces as built
//! (each face's median offset off its plane added to the design's distance), the height to a
//! top face that was seen, and each upright face's tilt over its height, judged by DIN 18202
//! Tables 1 and 2.

use nalgebra::{Matrix3, Vector3};

use super::FlatnessGrid;

/// Which dimension of the element.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DimensionKind {
    /// Between the two farthest-apart upright faces that face each other.
    Length = 0,
    /// Between the other upright faces that face each other.
    Thickness = 1,
    /// From the bed to a top face that was seen.
    Height = 2,
}

impl DimensionKind {
    /// As report.json spells it.
    pub fn as_str(self) -> &'static str {
        match self {
            DimensionKind::Length => "length",
            DimensionKind::Thickness => "thickness",
            DimensionKind::Height => "height",
        }
    }
}

/// A dimension as built against the design.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dimension {
    /// Which.
    pub kind: DimensionKind,
    /// The faces it is measured between (the top face twice for a height).
    pub faces: [u32; 2],
    /// The design's, metres.
    pub nominal: f64,
    /// As built, metres.
    pub measured: f64,
    /// DIN 18202 Table 1's limit for the nominal size, metres.
    pub limit: f64,
}

/// An upright face's tilt from the vertical, as the gap it makes over its height.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plumb {
    /// The face.
    pub face: u32,
    /// The height of the face the scans saw, metres.
    pub height: f64,
    /// The face's top less its foot, outward, over that height, metres (signed).
    pub gap: f64,
    /// DIN 18202 Table 2's limit over that height, metres.
    pub limit: f64,
}

/// DIN 18202 Table 1: lengths and widths up to 1, 3, 6 and 15 m, millimetres.
const TABLE_1_PLAN: [(f64, f64); 4] = [(1.0, 10.0), (3.0, 12.0), (6.0, 16.0), (15.0, 20.0)];
/// DIN 18202 Table 1: heights up to 1, 3, 6 and 15 m, millimetres.
const TABLE_1_HEIGHT: [(f64, f64); 4] = [(1.0, 10.0), (3.0, 16.0), (6.0, 16.0), (15.0, 20.0)];
/// DIN 18202 Table 2: angles as a gap over up to 1, 3 and 6 m, millimetres.
const TABLE_2: [(f64, f64); 3] = [(1.0, 6.0), (3.0, 8.0), (6.0, 12.0)];

/// The limit of the first row whose size is at least `size` (the last row beyond), metres.
fn stepped(table: &[(f64, f64)], size: f64) -> f64 {
    table
        .iter()
        .find(|r| size <= r.0)
        .unwrap_or(&table[table.len() - 1])
        .1
        * 1e-3
}

/// A face's median offset off its plane (what a local bulge or dent does not move) and its
/// tilt: the plane `w = a + b·u + c·v` fitted to its cells, with the `v` range they cover.
#[derive(Debug, Clone, Copy)]
pub(crate) struct FaceFit {
    pub median: f64,
    pub slope_v: f64,
    pub v_range: [f64; 2],
}

impl FlatnessGrid {
    /// The dimensions between opposite faces that were both seen, and the height to a seen top.
    pub fn dimensions(&self) -> Vec<Dimension> {
        let faces = self.faces();
        let fits: Vec<Option<FaceFit>> = (0..faces.len()).map(|f| self.fit(f)).collect();
        let mut pairs = Vec::new();
        for a in 0..faces.len() {
            for b in a + 1..faces.len() {
                let (fa, fb) = (&faces[a], &faces[b]);
                let upright = fa.normal.z.abs() < 0.1;
                if !upright || fa.normal.dot(&fb.normal) > -0.999 {
                    continue;
                }
                let (Some(ma), Some(mb)) = (fits[a], fits[b]) else {
                    continue;
                };
                let nominal = (fb.origin - fa.origin).dot(&fa.normal).abs();
                pairs.push((a as u32, b as u32, nominal, nominal + ma.median + mb.median));
            }
        }
        let longest = pairs.iter().map(|p| p.2).fold(0.0, f64::max);
        let mut out: Vec<Dimension> = pairs
            .into_iter()
            .map(|(a, b, nominal, measured)| Dimension {
                kind: if nominal == longest {
                    DimensionKind::Length
                } else {
                    DimensionKind::Thickness
                },
                faces: [a, b],
                nominal,
                measured,
                limit: stepped(&TABLE_1_PLAN, nominal),
            })
            .collect();
        let bed = self.bed;
        for (f, face) in faces.iter().enumerate() {
            if face.normal.z > 0.999
                && let Some(fit) = fits[f]
            {
                let nominal = face.origin.z - bed;
                out.push(Dimension {
                    kind: DimensionKind::Height,
                    faces: [f as u32; 2],
                    nominal,
                    measured: nominal + fit.median,
                    limit: stepped(&TABLE_1_HEIGHT, nominal),
                });
            }
        }
        out
    }

    /// Each upright face's tilt over the height the scans saw of it.
    pub fn plumb(&self) -> Vec<Plumb> {
        self.faces()
            .iter()
            .enumerate()
            .filter(|(_, face)| face.normal.z.abs() < 0.1)
            .filter_map(|(f, face)| {
                let fit = self.fit(f)?;
                // v runs up the face: its height is v's range times how upright v is.
                let height = (fit.v_range[1] - fit.v_range[0]) * face.v.z.abs();
                (height > 0.0).then(|| Plumb {
                    face: f as u32,
                    height,
                    gap: fit.slope_v * (fit.v_range[1] - fit.v_range[0]) * face.v.z.signum(),
                    limit: stepped(&TABLE_2, height),
                })
            })
            .collect()
    }

    /// The plane through face `f`'s measured cells, each weighted by its points and refitted
    /// once without the cells beyond 3 robust σ of the first fit (a bulge or a dent tilts a
    /// plane fitted to part of a face); `None` with fewer than 10 cells or a single row.
    pub(crate) fn fit(&self, f: usize) -> Option<FaceFit> {
        let c = &self.cells[f];
        let face = &self.faces.faces[f];
        // Each measured cell: (u, v, mean height, points).
        let mut cells = Vec::new();
        for iv in 0..c.nv {
            for iu in 0..c.nu {
                let k = iv * c.nu + iu;
                if c.count[k] > 0 {
                    cells.push((
                        face.extent[0][0] + (iu as f64 + 0.5) * c.cell,
                        face.extent[1][0] + (iv as f64 + 0.5) * c.cell,
                        c.sum[k] / c.count[k] as f64,
                        c.count[k] as f64,
                    ));
                }
            }
        }
        let v_range = cells
            .iter()
            .fold([f64::INFINITY, f64::NEG_INFINITY], |r, x| {
                [r[0].min(x.1), r[1].max(x.1)]
            });
        if cells.len() < 10 || v_range[1] - v_range[0] < c.cell {
            return None;
        }
        let first = plane(cells.iter())?;
        let residual = |x: &(f64, f64, f64, f64)| x.2 - (first.x + first.y * x.0 + first.z * x.1);
        let sigma = 1.4826 * crate::stats::median(cells.iter().map(|x| residual(x).abs()))?;
        let cut = (3.0 * sigma).max(0.001);
        let s = plane(cells.iter().filter(|x| residual(x).abs() <= cut)).unwrap_or(first);
        Some(FaceFit {
            median: crate::stats::median(cells.iter().map(|x| x.2))?,
            slope_v: s.z,
            v_range,
        })
    }
}

/// `w = a + b·u + c·v` by least squares over cells `(u, v, w, weight)`.
fn plane<'a>(cells: impl Iterator<Item = &'a (f64, f64, f64, f64)>) -> Option<Vector3<f64>> {
    let (mut a, mut b) = (Matrix3::<f64>::zeros(), Vector3::<f64>::zeros());
    for &(u, v, w, n) in cells {
        let x = Vector3::new(1.0, u, v);
        a += x * x.transpose() * n;
        b += x * (w * n);
    }
    a.lu().solve(&b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn the_tables_rows() {
        assert!((stepped(&TABLE_1_PLAN, 0.17) - 0.010).abs() < 1e-12);
        assert!((stepped(&TABLE_1_PLAN, 2.0) - 0.012).abs() < 1e-12);
        assert!((stepped(&TABLE_1_HEIGHT, 2.0) - 0.016).abs() < 1e-12);
        assert!((stepped(&TABLE_1_PLAN, 40.0) - 0.020).abs() < 1e-12);
        assert!((stepped(&TABLE_2, 0.98) - 0.006).abs() < 1e-12);
        assert!((stepped(&TABLE_2, 2.0) - 0.008).abs() < 1e-12);
    }

    /// The study wall with every upright face and the top scanned every 5 mm, each face moved
    /// out by `out(face normal, z)`, with 0.3 mm of scanner noise.
    fn wall(out: impl Fn(&Vector3<f64>, f64) -> f64) -> FlatnessGrid {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, 0.0003).unwrap();
        let design = crate::design::shapes::study_wall();
        let mut grid = FlatnessGrid::new(&design);
        for f in 0..grid.faces().len() {
            let face = grid.faces()[f].clone();
            let [[u0, u1], [v0, v1]] = face.extent;
            let step = 0.005;
            let mut u = u0 + 0.5 * step;
            while u < u1 {
                let mut v = v0 + 0.5 * step;
                while v < v1 {
                    let p = face.point(u, v);
                    let w = out(&face.normal, p.z) + noise.sample(&mut rng);
                    grid.add_point(f, &Point3::from(p.coords + face.normal.into_inner() * w));
                    v += step;
                }
                u += step;
            }
        }
        grid
    }

    #[test]
    fn dimensions_and_plumb_of_a_wall_as_built() {
        // 4 mm thicker (2 mm each side), 12 mm longer (6 mm each end), the top 3 mm low, and
        // the +y face leaning out 7 mm over its 0.98 m.
        let grid = wall(|n, z| {
            if n.z > 0.9 {
                -0.003
            } else if n.x.abs() > 0.9 {
                0.006
            } else if n.y > 0.9 {
                0.002 + 0.007 * z / 0.98
            } else {
                0.002
            }
        });
        let dims = grid.dimensions();
        let find = |k: DimensionKind| *dims.iter().find(|d| d.kind == k).unwrap();
        let thick = find(DimensionKind::Thickness);
        assert!((thick.nominal - 0.1734).abs() < 1e-6, "{thick:?}");
        // The leaning face's median offset is its middle: 2 + 3.5 mm.
        assert!(
            (thick.measured - thick.nominal - 0.0075).abs() < 2e-4,
            "{thick:?}"
        );
        let length = find(DimensionKind::Length);
        assert!(
            (length.measured - length.nominal - 0.012).abs() < 1e-4,
            "{length:?}"
        );
        assert!((length.limit - 0.012).abs() < 1e-12);
        let height = find(DimensionKind::Height);
        assert!((height.measured - 0.98 + 0.003).abs() < 1e-4, "{height:?}");
        let plumb = grid.plumb();
        assert_eq!(plumb.len(), 4, "{plumb:?}");
        let leaning = plumb
            .iter()
            .find(|p| grid.faces()[p.face as usize].normal.y > 0.9)
            .unwrap();
        assert!((leaning.gap - 0.007).abs() < 2e-4, "{leaning:?}");
        assert!(leaning.gap.abs() > leaning.limit, "{leaning:?}");
        for p in plumb.iter().filter(|p| p.face != leaning.face) {
            assert!(p.gap.abs() < 1e-4 && p.gap.abs() < p.limit, "{p:?}");
        }
    }
}
