//! report.json's flatness: the deepest gap under a virtual straightedge on every planar face
//! the scans saw, along and across the layers, at a standard's spans, judged by its table
//! (`core::flatness`). With a recording, the latest scan layer is judged: it sees the part as
//! it stands.

use asbuilt_core::Design;
use asbuilt_core::flatness::{DimensionsStandard, FlatnessGrid, FlatnessStandard};
use asbuilt_core::verdict::Verdict;
use asbuilt_protocol::PointDeviation;
use serde::Serialize;

/// Gathers the points of the latest scan layer per planar face, for the flatness and, when
/// asked, the dimensions and plumb.
pub struct FlatnessCollector {
    grid: FlatnessGrid,
    standard: Option<FlatnessStandard>,
    dimensions: Option<DimensionsStandard>,
    /// The scan layer gathered: job and printed height (NaN: not printing).
    layer: Option<(u64, f64)>,
}

/// A face the straightedge was laid on.
#[derive(Debug, Clone, Serialize)]
pub struct FaceSection {
    /// Its index, as the gaps name it.
    pub face: u32,
    /// Outward normal, design frame.
    pub normal: [f64; 3],
    /// Area, m².
    pub area_m2: f64,
    /// Size along and across the layers, metres.
    pub size_m: [f64; 2],
}

/// The deepest gap at one span, on one face, one way.
#[derive(Debug, Clone, Serialize)]
pub struct GapSection {
    /// The face.
    pub face: u32,
    /// `along_layers` or `across_layers`.
    pub direction: &'static str,
    /// The straightedge's span, metres.
    pub span_m: f64,
    /// The deepest gap under it, metres.
    pub gap_m: f64,
    /// The standard's limit at the span, metres.
    pub limit_m: f64,
    /// `pass` or `fail`.
    pub verdict: Verdict,
    /// Where the gap is deepest, design frame.
    pub at_m: [f64; 3],
}

/// report.json's `flatness`.
#[derive(Debug, Clone, Serialize)]
pub struct FlatnessSection {
    /// The standard, for people: "DIN 18202 Table 3 row 6".
    pub standard: String,
    /// As `--flatness` takes it: "din18202:6".
    pub key: String,
    /// The printed height of the scan layer judged; `None` for a scan not taken while printing.
    pub printed_height_m: Option<f64>,
    /// `fail` when any gap is beyond its limit.
    pub verdict: Verdict,
    /// The faces judged.
    pub faces: Vec<FaceSection>,
    /// The deepest gap per face, direction and span.
    pub gaps: Vec<GapSection>,
}

impl FlatnessCollector {
    /// Cells over `design`'s planar faces, their flatness judged by `standard` and their
    /// dimensions and plumb by `dimensions`; `None` when neither is asked for.
    pub fn new(
        design: &Design,
        standard: Option<FlatnessStandard>,
        dimensions: Option<DimensionsStandard>,
    ) -> Option<Self> {
        (standard.is_some() || dimensions.is_some()).then(|| Self {
            grid: FlatnessGrid::new(design),
            standard,
            dimensions,
            layer: None,
        })
    }

    /// Points of a station of `job` scanned at `printed_height` from `origin` (design frame,
    /// when known): a later scan layer starts the faces over, an earlier one's late station is
    /// left out.
    pub fn points(
        &mut self,
        job: u64,
        printed_height: f64,
        origin: Option<nalgebra::Point3<f64>>,
        devs: &[PointDeviation],
    ) {
        let height = if printed_height.is_finite() {
            printed_height
        } else {
            f64::INFINITY
        };
        match self.layer {
            Some((j, h)) if j == job && h == height => {}
            Some((j, h)) if j == job && h > height => return,
            _ => {
                self.grid.clear();
                self.layer = Some((job, height));
            }
        }
        self.grid.add(devs, origin);
    }

    /// The faces gathered, judged: their flatness and their dimensions and plumb, as asked.
    pub fn finish(self) -> (Option<FlatnessSection>, Option<DimensionsSection>) {
        let printed_height_m = self.layer.map(|l| l.1).filter(|h| h.is_finite());
        let dimensions = self
            .dimensions
            .map(|s| DimensionsSection::of(&self.grid, s, printed_height_m));
        let flatness = self
            .standard
            .map(|s| FlatnessSection::of(&self.grid, s, printed_height_m));
        (flatness, dimensions)
    }
}

impl FlatnessSection {
    fn of(grid: &FlatnessGrid, standard: FlatnessStandard, printed_height_m: Option<f64>) -> Self {
        let gaps: Vec<GapSection> = grid
            .judge(&standard)
            .into_iter()
            .map(|g| GapSection {
                face: g.face,
                direction: g.direction.as_str(),
                span_m: g.span,
                gap_m: g.gap,
                limit_m: g.limit,
                verdict: if g.passes() {
                    Verdict::Pass
                } else {
                    Verdict::Fail
                },
                at_m: g.at.coords.into(),
            })
            .collect();
        let judged: std::collections::BTreeSet<u32> = gaps.iter().map(|g| g.face).collect();
        let faces = grid
            .faces()
            .iter()
            .enumerate()
            .filter(|(k, _)| judged.contains(&(*k as u32)))
            .map(|(k, f)| FaceSection {
                face: k as u32,
                normal: f.normal.into_inner().into(),
                area_m2: f.area,
                size_m: f.size(),
            })
            .collect();
        FlatnessSection {
            standard: standard.to_string(),
            key: standard.key(),
            printed_height_m,
            verdict: gaps
                .iter()
                .map(|g| g.verdict)
                .max()
                .unwrap_or(Verdict::Pass),
            faces,
            gaps,
        }
    }
}

impl FlatnessSection {
    /// One line for the summary: the standard and what failed.
    pub fn summary_line(&self) -> String {
        let failed: Vec<&GapSection> = self
            .gaps
            .iter()
            .filter(|g| g.verdict == Verdict::Fail)
            .collect();
        if self.gaps.is_empty() {
            return format!(
                "Flatness to {}: no planar face was seen well enough to lay a straightedge on.",
                self.standard
            );
        }
        if failed.is_empty() {
            return format!(
                "Flatness to {}: PASS, {} gap(s) on {} face(s) within their limits.",
                self.standard,
                self.gaps.len(),
                self.faces.len()
            );
        }
        let worst = failed
            .iter()
            .max_by(|a, b| (a.gap_m / a.limit_m).total_cmp(&(b.gap_m / b.limit_m)))
            .expect("failed is not empty");
        let [x, y, z] = worst.at_m;
        format!(
            "Flatness to {}: FAIL, {} of {} gap(s) beyond the limit; the worst {:.1} mm under a \
             {} m straightedge {} on face {} (limit {:.1} mm) at ({x:.2}, {y:.2}, {z:.2}) m.",
            self.standard,
            failed.len(),
            self.gaps.len(),
            worst.gap_m * 1e3,
            worst.span_m,
            worst.direction.replace('_', " "),
            worst.face,
            worst.limit_m * 1e3
        )
    }
}

impl FlatnessSection {
    /// Each face's worst failing gap as a call-out for the maps of the scan layer judged,
    /// labelled `F<face>`.
    pub fn map_items(&self) -> Vec<crate::Item> {
        let mut worst: std::collections::BTreeMap<u32, &GapSection> = Default::default();
        for g in self.gaps.iter().filter(|g| g.verdict == Verdict::Fail) {
            let e = worst.entry(g.face).or_insert(g);
            if g.gap_m / g.limit_m > e.gap_m / e.limit_m {
                *e = g;
            }
        }
        worst
            .values()
            .map(|g| {
                let r = (0.5 * g.span_m).min(0.1);
                let [x, y, z] = g.at_m;
                crate::Item {
                    label: format!("F{}", g.face),
                    kind: crate::ItemKind::Flatness,
                    verdict: Verdict::Fail,
                    value: g.gap_m,
                    limit: g.limit_m,
                    layers: None,
                    z: [z, z],
                    at: Some(g.at_m),
                    extent: Some([[x - r, y - r, z - r], [x + r, y + r, z + r]]),
                    since: 0,
                    change: crate::Change::New,
                    previous: None,
                    text: format!(
                        "face {}: gap {:.1} mm under a {} m straightedge {} (limit {:.1} mm, {})",
                        g.face,
                        g.gap_m * 1e3,
                        g.span_m,
                        g.direction.replace('_', " "),
                        g.limit_m * 1e3,
                        self.standard
                    ),
                }
            })
            .collect()
    }

    /// The table of report.html: per face, direction and span, the gap against the limit.
    pub fn html(&self) -> String {
        use std::fmt::Write;
        let mut rows = String::new();
        for g in &self.gaps {
            let [x, y, z] = g.at_m;
            let _ = write!(
                rows,
                "<tr class=\"gap\" data-face=\"{}\"><td>{}</td><td>{}</td><td>{}</td>\
                 <td>{:.1}</td><td>{:.1}</td><td class=\"{v}\">{V}</td>\
                 <td>({x:.2}, {y:.2}, {z:.2})</td></tr>",
                g.face,
                g.face,
                g.direction.replace('_', " "),
                g.span_m,
                g.gap_m * 1e3,
                g.limit_m * 1e3,
                v = g.verdict,
                V = g.verdict.as_str().to_uppercase()
            );
        }
        let faces: Vec<String> = self
            .faces
            .iter()
            .map(|f| {
                let [nx, ny, nz] = f.normal;
                format!(
                    "face {}: facing ({nx:+.2}, {ny:+.2}, {nz:+.2}), {:.2} × {:.2} m",
                    f.face, f.size_m[0], f.size_m[1]
                )
            })
            .collect();
        format!(
            "<section class=\"flatness\"><h2>Flatness to {} <span class=\"verdict {v}\">{V}\
             </span></h2><p>A virtual straightedge on every planar face the scans saw, along the \
             layers and across them, at the standard's spans up to the face's size: the deepest \
             gap between it and the surface where it rests on two high points, over every \
             position (bins 10 mm long and 30 mm wide; the latest scan layer{}). {}.</p>\
             <table class=\"flatness\"><tr><th>face</th><th>straightedge</th><th>span m</th>\
             <th>gap mm</th><th>limit mm</th><th>verdict</th><th>deepest at (m)</th></tr>{rows}\
             </table></section>",
            crate::html::esc(&self.standard),
            self.printed_height_m
                .map_or(String::new(), |h| format!(", printed to {h:.3} m")),
            crate::html::esc(&faces.join("; ")),
            v = self.verdict,
            V = self.verdict.as_str().to_uppercase()
        )
    }
}

/// A dimension as built, judged.
#[derive(Debug, Clone, Serialize)]
pub struct DimensionSection {
    /// `length`, `thickness` or `height`.
    pub kind: &'static str,
    /// The faces it is measured between.
    pub faces: [u32; 2],
    /// The design's, metres.
    pub nominal_m: f64,
    /// As built, metres.
    pub measured_m: f64,
    /// The limit, metres.
    pub limit_m: f64,
    /// `pass` or `fail`.
    pub verdict: Verdict,
}

/// An upright face's tilt, judged.
#[derive(Debug, Clone, Serialize)]
pub struct PlumbSection {
    /// The face.
    pub face: u32,
    /// The height seen, metres.
    pub height_m: f64,
    /// Its top less its foot, outward, metres.
    pub gap_m: f64,
    /// The limit over that height, metres.
    pub limit_m: f64,
    /// `pass` or `fail`.
    pub verdict: Verdict,
}

/// report.json's `dimensions`: the element's dimensions and each upright face's plumb.
#[derive(Debug, Clone, Serialize)]
pub struct DimensionsSection {
    /// "DIN 18202 Tables 1 and 2".
    pub standard: String,
    /// The printed height of the scan layer judged.
    pub printed_height_m: Option<f64>,
    /// `fail` when any is beyond its limit.
    pub verdict: Verdict,
    /// Between opposite faces, and to a top that was seen.
    pub dimensions: Vec<DimensionSection>,
    /// Per upright face.
    pub plumb: Vec<PlumbSection>,
}

fn verdict(value: f64, limit: f64) -> Verdict {
    if value.abs() <= limit {
        Verdict::Pass
    } else {
        Verdict::Fail
    }
}

impl DimensionsSection {
    fn of(
        grid: &FlatnessGrid,
        standard: DimensionsStandard,
        printed_height_m: Option<f64>,
    ) -> Self {
        let dimensions: Vec<DimensionSection> = grid
            .dimensions()
            .into_iter()
            .map(|d| DimensionSection {
                kind: d.kind.as_str(),
                faces: d.faces,
                nominal_m: d.nominal,
                measured_m: d.measured,
                limit_m: d.limit,
                verdict: verdict(d.measured - d.nominal, d.limit),
            })
            .collect();
        let plumb: Vec<PlumbSection> = grid
            .plumb()
            .into_iter()
            .map(|p| PlumbSection {
                face: p.face,
                height_m: p.height,
                gap_m: p.gap,
                limit_m: p.limit,
                verdict: verdict(p.gap, p.limit),
            })
            .collect();
        let verdict = dimensions
            .iter()
            .map(|d| d.verdict)
            .chain(plumb.iter().map(|p| p.verdict))
            .max()
            .unwrap_or(Verdict::Pass);
        Self {
            standard: standard.to_string(),
            printed_height_m,
            verdict,
            dimensions,
            plumb,
        }
    }

    /// One line for the summary: the standard and what failed.
    pub fn summary_line(&self) -> String {
        let failed: Vec<String> = self
            .dimensions
            .iter()
            .filter(|d| d.verdict == Verdict::Fail)
            .map(|d| {
                format!(
                    "{} {:.1} mm off (limit ±{:.0} mm)",
                    d.kind,
                    (d.measured_m - d.nominal_m) * 1e3,
                    d.limit_m * 1e3
                )
            })
            .chain(
                self.plumb
                    .iter()
                    .filter(|p| p.verdict == Verdict::Fail)
                    .map(|p| {
                        format!(
                            "face {} out of plumb by {:+.1} mm over {:.2} m (limit {:.0} mm)",
                            p.face,
                            p.gap_m * 1e3,
                            p.height_m,
                            p.limit_m * 1e3
                        )
                    }),
            )
            .collect();
        if failed.is_empty() {
            format!(
                "Dimensions and plumb to {}: PASS, {} dimension(s) and {} face(s).",
                self.standard,
                self.dimensions.len(),
                self.plumb.len()
            )
        } else {
            format!(
                "Dimensions and plumb to {}: FAIL: {}.",
                self.standard,
                failed.join("; ")
            )
        }
    }

    /// The tables of report.html.
    pub fn html(&self) -> String {
        let dims: String = self
            .dimensions
            .iter()
            .map(|d| {
                format!(
                    "<tr class=\"dimension\"><td>{}</td><td>{} / {}</td><td>{:.1}</td><td>{:.1}\
                     </td><td>{:+.1}</td><td>±{:.0}</td><td class=\"{v}\">{V}</td></tr>",
                    d.kind,
                    d.faces[0],
                    d.faces[1],
                    d.nominal_m * 1e3,
                    d.measured_m * 1e3,
                    (d.measured_m - d.nominal_m) * 1e3,
                    d.limit_m * 1e3,
                    v = d.verdict,
                    V = d.verdict.as_str().to_uppercase()
                )
            })
            .collect();
        let plumb: String = self
            .plumb
            .iter()
            .map(|p| {
                format!(
                    "<tr class=\"plumb\"><td>{}</td><td>{:.2}</td><td>{:+.1}</td><td>{:.0}</td>\
                     <td class=\"{v}\">{V}</td></tr>",
                    p.face,
                    p.height_m,
                    p.gap_m * 1e3,
                    p.limit_m * 1e3,
                    v = p.verdict,
                    V = p.verdict.as_str().to_uppercase()
                )
            })
            .collect();
        format!(
            "<section class=\"dimensions\"><h2>Dimensions and plumb to {} <span class=\"verdict \
             {v}\">{V}</span></h2><p>Between opposite faces the design's distance plus each \
             face's median offset (a local bulge does not move it); a height to a top face that \
             was seen; each upright face's tilt, fitted to its cells, as the gap it makes over \
             the height seen.</p><table class=\"dimensions\"><tr><th>dimension</th>\
             <th>faces</th><th>design mm</th><th>as built mm</th><th>off mm</th><th>limit mm</th>\
             <th>verdict</th></tr>{dims}</table><table class=\"plumb\"><tr><th>face</th>\
             <th>height m</th><th>top less foot mm</th><th>limit mm</th><th>verdict</th></tr>\
             {plumb}</table></section>",
            crate::html::esc(&self.standard),
            v = self.verdict,
            V = self.verdict.as_str().to_uppercase()
        )
    }
}
