//! Dimensions and plumb from the same faces: the distance between opposite faces as built
//! (each face's median offset off its plane added to the design's distance), the height to a
//! top face that was seen, and each upright face's tilt over its height, judged by DIN 18202
//! Tables 1 and 2.

use nalgebra::{Matrix3, Vector3};

use super::FlatnessGrid;

/// Which dimension of the element.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize),
    serde(rename_all = "snake_case")
)]
pub enum DimensionKind {
    /// Between the two farthest-apart upright faces that face each other.
    Length = 0,
    /// Between the other upright faces that face each other.
    Thickness = 1,
    /// From the bed to a top face that was seen.
    Height = 2,
}

impl std::fmt::Display for DimensionKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
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
    /// The expanded uncertainty (k = 2) of `measured`, metres.
    pub uncertainty: f64,
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
    /// The expanded uncertainty (k = 2) of `gap`, metres.
    pub uncertainty: f64,
}

/// DIN 18202:2019-07 Table 1's nominal sizes: up to 1, 3, 6, 15, 30 m, and over 30 m.
pub const TABLE_1_SIZES: [f64; 6] = [1.0, 3.0, 6.0, 15.0, 30.0, f64::INFINITY];
/// DIN 18202:2019-07 Table 1, rows 1 to 6: the limit deviations (±, millimetres) at those
/// sizes; `None` where the table has no value.
pub const TABLE_1: [[Option<f64>; 6]; 6] = [
    // 1: dimensions in plan (lengths, widths, axis and grid dimensions).
    [
        Some(10.0),
        Some(12.0),
        Some(16.0),
        Some(20.0),
        Some(24.0),
        Some(30.0),
    ],
    // 2: dimensions in elevation (storey heights, landing heights, heights to bearings).
    [
        Some(10.0),
        Some(16.0),
        Some(16.0),
        Some(20.0),
        Some(30.0),
        Some(30.0),
    ],
    // 3: clear dimensions in plan (between columns, piers).
    [
        Some(12.0),
        Some(16.0),
        Some(20.0),
        Some(24.0),
        Some(30.0),
        None,
    ],
    // 4: clear dimensions in elevation (under slabs and beams).
    [Some(16.0), Some(20.0), Some(20.0), Some(30.0), None, None],
    // 5: openings (windows, doors, built-in elements).
    [Some(10.0), Some(12.0), Some(16.0), None, None, None],
    // 6: openings as row 5 with finished reveals.
    [Some(8.0), Some(10.0), Some(12.0), None, None, None],
];
/// DIN 18202:2019-07 Table 2's nominal sizes: up to 0.5, 1, 3, 6, 15, 30 m, and over 30 m.
pub const TABLE_2_SIZES: [f64; 7] = [0.5, 1.0, 3.0, 6.0, 15.0, 30.0, f64::INFINITY];
/// DIN 18202:2019-07 Table 2: angular deviations of vertical, horizontal and inclined surfaces
/// as a gap (Stichmaß) over those sizes, millimetres.
pub const TABLE_2: [f64; 7] = [3.0, 6.0, 8.0, 12.0, 16.0, 20.0, 30.0];

/// Table 1's limit of `row` (1 to 6) for a nominal `size`, metres; `None` where the table has
/// none (a clear dimension or an opening beyond its largest size).
pub fn table_1(row: usize, size: f64) -> Option<f64> {
    let col = TABLE_1_SIZES.iter().position(|s| size <= *s)?;
    TABLE_1.get(row.checked_sub(1)?)?[col].map(|mm| mm * 1e-3)
}

/// Table 2's limit over a nominal `size`, metres.
pub fn table_2(size: f64) -> f64 {
    let col = TABLE_2_SIZES
        .iter()
        .position(|s| size <= *s)
        .unwrap_or(TABLE_2.len() - 1);
    TABLE_2[col] * 1e-3
}

/// A face's median offset off its plane (what a local bulge or dent does not move) and its
/// tilt: the plane `w = a + b·u + c·v` fitted to its cells, with the `v` range they cover; and
/// what their uncertainty is made of.
#[derive(Debug, Clone)]
pub(crate) struct FaceFit {
    pub median: f64,
    pub slope_v: f64,
    pub v_range: [f64; 2],
    /// The median's variance from range noise, m².
    pub median_noise_var: f64,
    /// The median's share of each station's pose error: (tag, weight).
    pub median_pose: Vec<(u8, f64)>,
    /// The slope's variance from range noise.
    pub slope_noise_var: f64,
    /// The slope's sensitivity to each station's pose error along the normal: (tag, coefficient).
    pub slope_pose: Vec<(u8, f64)>,
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
                let (Some(ma), Some(mb)) = (&fits[a], &fits[b]) else {
                    continue;
                };
                let nominal = (fb.origin - fa.origin).dot(&fa.normal).abs();
                let u = self.offsets_uncertainty(&[(a, ma), (b, mb)]);
                pairs.push((
                    a as u32,
                    b as u32,
                    nominal,
                    nominal + ma.median + mb.median,
                    u,
                ));
            }
        }
        let longest = pairs.iter().map(|p| p.2).fold(0.0, f64::max);
        let mut out: Vec<Dimension> = pairs
            .into_iter()
            .map(|(a, b, nominal, measured, uncertainty)| Dimension {
                kind: if nominal == longest {
                    DimensionKind::Length
                } else {
                    DimensionKind::Thickness
                },
                faces: [a, b],
                nominal,
                measured,
                limit: table_1(1, nominal).unwrap_or(f64::NAN),
                uncertainty,
            })
            .collect();
        let bed = self.bed;
        for (f, face) in faces.iter().enumerate() {
            if face.normal.z > 0.999
                && let Some(fit) = &fits[f]
            {
                let nominal = face.origin.z - bed;
                out.push(Dimension {
                    kind: DimensionKind::Height,
                    faces: [f as u32; 2],
                    nominal,
                    measured: nominal + fit.median,
                    limit: table_1(2, nominal).unwrap_or(f64::NAN),
                    uncertainty: self.offsets_uncertainty(&[(f, fit)]),
                });
            }
        }
        out
    }

    /// U of a sum of faces' median offsets (each along its own normal).
    fn offsets_uncertainty(&self, faces: &[(usize, &FaceFit)]) -> f64 {
        let mut var = 0.0;
        let mut pose = Vec::new();
        for (f, fit) in faces {
            var += fit.median_noise_var;
            let n = self.faces()[*f].normal.into_inner();
            pose.extend(fit.median_pose.iter().map(|&(tag, w)| (tag, w, n)));
        }
        var += self.pose_variance(&pose);
        super::uncertainty::COVERAGE_FACTOR * var.sqrt()
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
                let seen = fit.v_range[1] - fit.v_range[0];
                let height = seen * face.v.z.abs();
                let n = face.normal.into_inner();
                let pose: Vec<_> = fit.slope_pose.iter().map(|&(t, a)| (t, a, n)).collect();
                let var = fit.slope_noise_var + self.pose_variance(&pose);
                (height > 0.0).then(|| Plumb {
                    face: f as u32,
                    height,
                    gap: fit.slope_v * seen * face.v.z.signum(),
                    limit: table_2(height),
                    uncertainty: super::uncertainty::COVERAGE_FACTOR * var.sqrt() * seen,
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
        // Each measured cell: (u, v, mean height, points), and its station.
        let mut cells = Vec::new();
        let mut tags = Vec::new();
        for iv in 0..c.nv {
            for iu in 0..c.nu {
                let k = iv * c.nu + iu;
                let x = &c.cell[k];
                if x.count > 0 {
                    cells.push((
                        face.extent[0][0] + (iu as f64 + 0.5) * c.size[0],
                        face.extent[1][0] + (iv as f64 + 0.5) * c.size[1],
                        x.sum / x.count as f64,
                        x.count as f64,
                    ));
                    tags.push(x.station());
                }
            }
        }
        let v_range = cells
            .iter()
            .fold([f64::INFINITY, f64::NEG_INFINITY], |r, x| {
                [r[0].min(x.1), r[1].max(x.1)]
            });
        if cells.len() < 10 || v_range[1] - v_range[0] < c.size[1] {
            return None;
        }
        let first = plane(cells.iter())?;
        let residual = |x: &(f64, f64, f64, f64)| x.2 - (first.x + first.y * x.0 + first.z * x.1);
        let sigma = 1.4826 * crate::stats::median(cells.iter().map(|x| residual(x).abs()))?;
        let cut = (3.0 * sigma).max(0.001);
        let s = plane(cells.iter().filter(|x| residual(x).abs() <= cut)).unwrap_or(first);
        let noise = self.noise_sigma(f);
        let points: f64 = cells.iter().map(|x| x.3).sum();
        // The slope's sensitivity to each cell, as a fit in v alone: a_c = n_c (v_c - v̄) / S.
        let v_mean = cells.iter().map(|x| x.1 * x.3).sum::<f64>() / points;
        let spread: f64 = cells.iter().map(|x| x.3 * (x.1 - v_mean).powi(2)).sum();
        Some(FaceFit {
            median: crate::stats::median(cells.iter().map(|x| x.2))?,
            slope_v: s.z,
            v_range,
            median_noise_var: std::f64::consts::FRAC_PI_2 * noise * noise / points,
            median_pose: shares(&tags, cells.iter().map(|x| x.3 / points)),
            slope_noise_var: noise * noise / spread,
            slope_pose: shares(&tags, cells.iter().map(|x| x.3 * (x.1 - v_mean) / spread)),
        })
    }
}

/// Per station tag (mixed cells together), the sum of its cells' coefficients.
fn shares(tags: &[u8], coefficients: impl Iterator<Item = f64>) -> Vec<(u8, f64)> {
    let mut by_tag: std::collections::BTreeMap<u8, f64> = Default::default();
    for (&t, a) in tags.iter().zip(coefficients) {
        *by_tag.entry(t).or_default() += a;
    }
    by_tag.into_iter().collect()
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

    /// DIN 18202:2019-07 Tables 1 and 2 as printed, every row at every size column, and at the
    /// columns' edges (a size "up to 1 m" includes 1 m).
    #[test]
    fn tables_1_and_2_row_by_row() {
        let printed: [[i32; 6]; 6] = [
            [10, 12, 16, 20, 24, 30],
            [10, 16, 16, 20, 30, 30],
            [12, 16, 20, 24, 30, 0],
            [16, 20, 20, 30, 0, 0],
            [10, 12, 16, 0, 0, 0],
            [8, 10, 12, 0, 0, 0],
        ];
        let sizes = [0.17, 2.0, 4.5, 10.0, 20.0, 45.0];
        for (r, row) in printed.iter().enumerate() {
            for (size, mm) in sizes.iter().zip(row) {
                let got = table_1(r + 1, *size);
                if *mm == 0 {
                    assert_eq!(got, None, "row {} at {size} m", r + 1);
                } else {
                    let got = got.unwrap_or_else(|| panic!("row {} at {size} m", r + 1));
                    assert!(
                        (got - *mm as f64 * 1e-3).abs() < 1e-12,
                        "row {} at {size}",
                        r + 1
                    );
                }
            }
        }
        assert_eq!(table_1(1, 1.0), Some(0.010));
        assert_eq!(table_1(1, 1.0 + 1e-9), Some(0.012));
        assert_eq!(table_1(7, 1.0), None);
        let t2 = [
            (0.3, 3.0),
            (0.5, 3.0),
            (0.98, 6.0),
            (2.0, 8.0),
            (5.0, 12.0),
            (12.0, 16.0),
        ];
        for (size, mm) in t2.into_iter().chain([(25.0, 20.0), (31.0, 30.0)]) {
            assert!((table_2(size) - mm * 1e-3).abs() < 1e-12, "{size} m");
        }
    }

    /// The study wall with every upright face and the top scanned every 5 mm, each face moved
    /// out by `out(face normal, z)`, with 0.3 mm of scanner noise; all seen by one station.
    fn wall(out: impl Fn(&Vector3<f64>, f64) -> f64) -> FlatnessGrid {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        seen(&out, &[Vector3::zeros()], &|_| 0, 0.005, &mut rng)
    }

    /// The study wall scanned every `step` by stations whose translations are off by
    /// `errors`, each face by the station `by(normal)` picks.
    fn seen(
        out: &dyn Fn(&Vector3<f64>, f64) -> f64,
        errors: &[Vector3<f64>],
        by: &dyn Fn(&Vector3<f64>) -> usize,
        step: f64,
        rng: &mut rand_chacha::ChaCha8Rng,
    ) -> FlatnessGrid {
        use rand_distr::{Distribution, Normal};
        let noise = Normal::new(0.0, 0.0003).unwrap();
        let design = crate::design::shapes::study_wall();
        let mut grid = FlatnessGrid::new(&design);
        let tags: Vec<u8> = (0..errors.len())
            .map(|k| {
                grid.station(&super::super::StationView {
                    key: (0, k as u32),
                    origin: None,
                    position_sigma: 0.001,
                })
            })
            .collect();
        for f in 0..grid.faces().len() {
            let face = grid.faces()[f].clone();
            let s = by(&face.normal);
            let [[u0, u1], [v0, v1]] = face.extent;
            let mut u = u0 + 0.5 * step;
            while u < u1 {
                let mut v = v0 + 0.5 * step;
                while v < v1 {
                    let p = face.point(u, v);
                    let w = out(&face.normal, p.z) + noise.sample(rng);
                    let q = p.coords + face.normal.into_inner() * w + errors[s];
                    grid.add_point(f, &Point3::from(q), tags[s]);
                    v += step;
                }
                u += step;
            }
        }
        grid
    }

    /// The thickness seen by two stations, one on each side, and the height and the +y face's
    /// plumb: U against twice their spread over repeated scans with fresh pose errors (1 mm σ
    /// per axis) and noise. One station seeing both sides would cancel its own error.
    #[test]
    fn dimension_and_plumb_uncertainty_match_a_monte_carlo() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
        let pose = Normal::new(0.0, 0.001).unwrap();
        let flat = |_: &Vector3<f64>, _: f64| 0.0;
        let mut runs: Vec<[f64; 6]> = Vec::new();
        for _ in 0..120 {
            let mut e = || Vector3::from_fn(|_, _| pose.sample(&mut rng));
            let errors = [e(), e()];
            let grid = seen(
                &flat,
                &errors,
                &|n| usize::from(n.y < -0.9),
                0.004,
                &mut rng,
            );
            let dims = grid.dimensions();
            let thick = dims
                .iter()
                .find(|d| d.kind == DimensionKind::Thickness)
                .unwrap();
            let height = dims
                .iter()
                .find(|d| d.kind == DimensionKind::Height)
                .unwrap();
            let plumb = grid.plumb();
            let py = plumb
                .iter()
                .find(|p| grid.faces()[p.face as usize].normal.y > 0.9)
                .unwrap();
            runs.push([
                thick.measured,
                thick.uncertainty,
                height.measured,
                height.uncertainty,
                py.gap,
                py.uncertainty,
            ]);
        }
        let spread = |k: usize| {
            let v: Vec<f64> = runs.iter().map(|r| r[k]).collect();
            super::super::tests::spread(&v)
        };
        let mean = |k: usize| runs.iter().map(|r| r[k]).sum::<f64>() / runs.len() as f64;
        for (what, k) in [("thickness", 0), ("height", 2), ("plumb", 4)] {
            let (u, mc) = (mean(k + 1), 2.0 * spread(k));
            assert!(
                (u - mc).abs() < 0.2 * mc,
                "{what}: U {:.4} mm against the Monte Carlo's {:.4} mm",
                u * 1e3,
                mc * 1e3
            );
        }
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
        eprintln!(
            "face leaning 7 mm over 0.98 m: {:.2} ± {:.2} mm, limit {:.0} mm: {}",
            leaning.gap * 1e3,
            leaning.uncertainty * 1e3,
            leaning.limit * 1e3,
            crate::verdict::DecisionRule::Iso14253_1.decide(
                leaning.gap,
                leaning.uncertainty,
                leaning.limit
            )
        );
        assert!((leaning.gap - 0.007).abs() < 2e-4, "{leaning:?}");
        assert!(leaning.gap.abs() > leaning.limit, "{leaning:?}");
        for p in plumb.iter().filter(|p| p.face != leaning.face) {
            assert!(p.gap.abs() < 1e-4 && p.gap.abs() < p.limit, "{p:?}");
        }
    }
}
