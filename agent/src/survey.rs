//! A surveyor's checks over each scan layer, live: the faces' flatness under a virtual
//! straightedge and the element's dimensions and plumb, judged by the standards in
//! `[tolerances]` (`flatness`, `dimensions`) after every station, logged and sent to the cell
//! as [`SurfaceFindings`]. The cells grow
//! with the design's faces, never with the scan; `asbuilt report` judges the recording the same
//! way into report.json.

use asbuilt_core::Design;
use asbuilt_core::flatness::{DimensionsStandard, FlatnessGrid, FlatnessStandard};
use asbuilt_protocol::{DimensionRow, FixedText, FlatnessRow, PointDeviation, SurfaceFindings};

use crate::{info, warn};

/// The faces' points of the scan layer being scanned, and the standards they are judged by.
pub struct Survey {
    grid: FlatnessGrid,
    flatness: Option<FlatnessStandard>,
    dimensions: Option<DimensionsStandard>,
    /// The scan layer gathered: job and printed height's bits.
    layer: Option<(u64, u64)>,
}

impl Survey {
    /// Cells over `design`'s planar faces; `None` when no standard is set.
    pub fn new(
        design: &Design,
        flatness: Option<FlatnessStandard>,
        dimensions: Option<DimensionsStandard>,
    ) -> Option<Self> {
        (flatness.is_some() || dimensions.is_some()).then(|| Self {
            grid: FlatnessGrid::new(design),
            flatness,
            dimensions,
            layer: None,
        })
    }

    /// A chunk's deviations of a station of `job` scanned at `printed_height` from `origin`
    /// (design frame): a new scan layer starts the faces over.
    pub fn ingest(
        &mut self,
        job: u64,
        printed_height: f64,
        origin: Option<nalgebra::Point3<f64>>,
        devs: &[PointDeviation],
    ) {
        let layer = (job, printed_height.to_bits());
        if self.layer != Some(layer) {
            self.grid.clear();
            self.layer = Some(layer);
        }
        self.grid.add(devs, origin);
    }

    /// Judges the scan layer so far after station `key` (job, station) of printed layer
    /// `layer` at `printed_height`, logs it and returns it for the cell.
    pub fn judge(&self, key: (u64, u32), layer: u32, printed_height: f64) -> SurfaceFindings {
        let (job, station) = key;
        let mut out = SurfaceFindings::new(job, station);
        out.layer = layer;
        out.printed_height = printed_height;
        if let Some(standard) = &self.flatness {
            self.judge_flatness(standard, &mut out);
        }
        if let Some(standard) = &self.dimensions {
            self.judge_dimensions(standard, &mut out);
        }
        out
    }

    /// The faces' flatness into `out`, logged.
    fn judge_flatness(&self, standard: &FlatnessStandard, out: &mut SurfaceFindings) {
        let (job, station) = (out.job, out.station);
        let gaps = self.grid.judge(standard);
        out.flatness_standard = FixedText::truncated(&standard.key());
        for g in &gaps {
            let row = FlatnessRow {
                face: g.face,
                direction: u8::from(g.direction == asbuilt_core::flatness::Direction::Across),
                pass: g.passes(),
                span: g.span,
                gap: g.gap,
                limit: g.limit,
                at: g.at.coords.into(),
            };
            if out.flatness.push(row).is_err() {
                out.truncated += 1;
            }
        }
        let failed: Vec<_> = gaps.iter().filter(|g| !g.passes()).collect();
        match failed
            .iter()
            .max_by(|a, b| (a.gap / a.limit).total_cmp(&(b.gap / b.limit)))
        {
            None => info!(
                "job {job} station {station}: flatness to {standard} over the scan layer so \
                 far: PASS, {} gap(s) on the faces seen",
                gaps.len()
            ),
            Some(w) => warn!(
                "job {job} station {station}: flatness to {standard} over the scan layer so \
                 far: FAIL, {} of {} gap(s); the worst {:.1} mm under a {} m straightedge {} \
                 (limit {:.1} mm) at ({:.2}, {:.2}, {:.2}) m",
                failed.len(),
                gaps.len(),
                w.gap * 1e3,
                w.span,
                w.direction.as_str().replace('_', " "),
                w.limit * 1e3,
                w.at.x,
                w.at.y,
                w.at.z
            ),
        }
    }

    /// The dimensions and plumb into `out`, logged.
    fn judge_dimensions(&self, standard: &DimensionsStandard, out: &mut SurfaceFindings) {
        let (job, station) = (out.job, out.station);
        out.dimensions_standard = FixedText::truncated("din18202");
        let mut off = Vec::new();
        let dims = self.grid.dimensions();
        let plumb = self.grid.plumb();
        let rows = dims
            .iter()
            .map(|d| DimensionRow {
                kind: d.kind as u8,
                pass: (d.measured - d.nominal).abs() <= d.limit,
                faces: d.faces,
                nominal: d.nominal,
                measured: d.measured,
                limit: d.limit,
            })
            .chain(plumb.iter().map(|p| DimensionRow {
                kind: 3,
                pass: p.gap.abs() <= p.limit,
                faces: [p.face; 2],
                nominal: p.height,
                measured: p.gap,
                limit: p.limit,
            }));
        for row in rows {
            if out.dimensions.push(row).is_err() {
                out.truncated += 1;
            }
        }
        for d in dims {
            if (d.measured - d.nominal).abs() > d.limit {
                off.push(format!(
                    "{} {:+.1} mm (limit ±{:.0})",
                    d.kind.as_str(),
                    (d.measured - d.nominal) * 1e3,
                    d.limit * 1e3
                ));
            }
        }
        for p in plumb {
            if p.gap.abs() > p.limit {
                off.push(format!(
                    "face {} out of plumb {:+.1} mm over {:.2} m (limit {:.0})",
                    p.face,
                    p.gap * 1e3,
                    p.height,
                    p.limit * 1e3
                ));
            }
        }
        if off.is_empty() {
            info!(
                "job {job} station {station}: dimensions and plumb to {standard} over the \
                 scan layer so far: PASS"
            );
        } else {
            warn!(
                "job {job} station {station}: dimensions and plumb to {standard} over the \
                 scan layer so far: FAIL: {}",
                off.join("; ")
            );
        }
    }
}
