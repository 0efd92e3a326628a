//! report.json's flatness: the deepest gap under a virtual straightedge on every planar face
//! the scans saw, along and across the layers, at a standard's spans, judged by its table
//! (`core::flatness`). With a recording, the latest scan layer is judged: it sees the part as
//! it stands.

use asbuilt_core::Design;
use asbuilt_core::flatness::{
    DIN_18202_EDITION, DimensionKind, DimensionsStandard, Direction, FlatnessGap, FlatnessGrid,
    FlatnessStandard, NotJudgedReason, StationView,
};
use asbuilt_core::verdict::{DecisionRule, Verdict};
use asbuilt_protocol::PointDeviation;
use serde::Serialize;

/// Gathers the points of the latest scan layer per planar face, for the flatness and, when
/// asked, the dimensions and plumb.
pub struct FlatnessCollector {
    grid: FlatnessGrid,
    standard: Option<FlatnessStandard>,
    dimensions: Option<DimensionsStandard>,
    rule: DecisionRule,
    /// The scan layer gathered: job and printed height (NaN: not printing).
    layer: Option<(u64, f64)>,
    /// The only scan layer to gather, when known ahead ([`FlatnessCollector::only`]).
    only: Option<(u64, f64)>,
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

/// A gap under the straightedge on one face, one way: the one that governs the face's verdict,
/// or the deepest with its supports within one of the table's distances (`span_m`).
#[derive(Debug, Clone, Serialize)]
pub struct GapSection {
    /// The face.
    pub face: u32,
    /// `along_layers` or `across_layers`.
    pub direction: Direction,
    /// The table's distance the supports lie within; absent for a governing gap.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub span_m: Option<f64>,
    /// The gap under the straightedge, metres.
    pub gap_m: f64,
    /// The distance between the two high points the straightedge rests on, metres.
    pub support_distance_m: f64,
    /// The standard's limit at that distance, metres.
    pub limit_m: f64,
    /// The gap's expanded uncertainty (k = 2), metres.
    pub uncertainty_m: f64,
    /// By the report's decision rule.
    pub verdict: Verdict,
    /// Where the gap is deepest, design frame.
    pub at_m: [f64; 3],
    /// Where the straightedge rests, design frame.
    pub supports_m: [[f64; 3]; 2],
}

/// The largest abrupt offset on one face, one way (ACI 117: within an inch).
#[derive(Debug, Clone, Serialize)]
pub struct AbruptSection {
    /// The face.
    pub face: u32,
    /// `along_layers` or `across_layers`.
    pub direction: Direction,
    /// The offset, metres.
    pub step_m: f64,
    /// How far apart the two points it is measured between lie, metres.
    pub distance_m: f64,
    /// The class's abrupt limit, metres.
    pub limit_m: f64,
    /// The offset's expanded uncertainty (k = 2), metres.
    pub uncertainty_m: f64,
    /// By the report's decision rule.
    pub verdict: Verdict,
    /// The two points, design frame.
    pub between_m: [[f64; 3]; 2],
}

impl AbruptSection {
    fn of(a: &asbuilt_core::flatness::AbruptStep, rule: DecisionRule) -> Self {
        AbruptSection {
            face: a.face,
            direction: a.direction,
            step_m: a.step,
            distance_m: a.distance,
            limit_m: a.limit,
            uncertainty_m: a.uncertainty,
            verdict: a.verdict(rule),
            between_m: a.between.map(|p| p.coords.into()),
        }
    }
}

/// A face, one way, not judged.
#[derive(Debug, Clone, Serialize)]
pub struct NotJudgedSection {
    /// The face.
    pub face: u32,
    /// `along_layers` or `across_layers`.
    pub direction: Direction,
    /// `not_seen` or `too_sparse`.
    pub reason: NotJudgedReason,
}

impl GapSection {
    fn of(g: &FlatnessGap, rule: DecisionRule) -> Self {
        GapSection {
            face: g.face,
            direction: g.direction,
            span_m: g.span,
            gap_m: g.gap,
            support_distance_m: g.support_distance,
            limit_m: g.limit,
            uncertainty_m: g.uncertainty,
            verdict: g.verdict(rule),
            at_m: g.at.coords.into(),
            supports_m: g.supports.map(|p| p.coords.into()),
        }
    }
}

/// report.json's `flatness`.
#[derive(Debug, Clone, Serialize)]
pub struct FlatnessSection {
    /// The standard, for people: "DIN 18202 Table 3 row 6".
    pub standard: String,
    /// As `--flatness` takes it: "din18202:6".
    pub key: String,
    /// The decision rule the verdicts follow: `iso14253-1` or `simple`.
    pub decision_rule: DecisionRule,
    /// The printed height of the scan layer judged; `None` for a scan not taken while printing.
    pub printed_height_m: Option<f64>,
    /// The worst governing verdict; `not_judged` when no face was judged.
    pub verdict: Verdict,
    /// Why nothing was judged, when nothing was.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub not_judged_reason: Option<String>,
    /// The faces judged.
    pub faces: Vec<FaceSection>,
    /// Per face and direction judged, the gap that governs its verdict, judged at the distance
    /// between its supports.
    pub gaps: Vec<GapSection>,
    /// Per face and direction, the deepest gap with its supports within each of the table's
    /// distances up to the face's size.
    pub by_span: Vec<GapSection>,
    /// The faces and directions not judged, and why.
    pub not_judged: Vec<NotJudgedSection>,
    /// Per face and direction judged, the largest abrupt offset, where the standard limits
    /// them (ACI 117; empty for DIN 18202).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub abrupt: Vec<AbruptSection>,
}

impl FlatnessCollector {
    /// Cells over `design`'s planar faces, their flatness judged by `standard` and their
    /// dimensions and plumb by `dimensions`; `None` when neither is asked for.
    pub fn new(
        design: &Design,
        standard: Option<FlatnessStandard>,
        dimensions: Option<DimensionsStandard>,
        rule: DecisionRule,
    ) -> Option<Self> {
        (standard.is_some() || dimensions.is_some()).then(|| Self {
            grid: FlatnessGrid::new(design),
            standard,
            dimensions,
            rule,
            layer: None,
            only: None,
        })
    }

    /// Gathers only the points of `job`'s scan layer at `printed_height` (the one the faces
    /// would be judged on anyway, when the reader knows it ahead): every other scan layer's
    /// points are left out before they are placed.
    pub fn only(mut self, job: u64, printed_height: f64) -> Self {
        self.only = Some((job, Self::height_of(printed_height)));
        self
    }

    /// A scan layer's height as the collector keys it: a station scanned while not printing
    /// (no printed height) comes after every printed one.
    pub fn height_of(printed_height: f64) -> f64 {
        if printed_height.is_finite() {
            printed_height
        } else {
            f64::INFINITY
        }
    }

    /// Points of `station` of `job` scanned at `printed_height`: a later scan layer starts
    /// the faces over, an earlier one's late station is left out.
    pub fn points(
        &mut self,
        job: u64,
        printed_height: f64,
        station: &StationView,
        devs: &[PointDeviation],
    ) {
        let height = Self::height_of(printed_height);
        if self.only.is_some_and(|o| o != (job, height)) {
            return;
        }
        match self.layer {
            Some((j, h)) if j == job && h == height => {}
            Some((j, h)) if j == job && h > height => return,
            _ => {
                self.grid.clear();
                self.layer = Some((job, height));
            }
        }
        self.grid.add(devs, station);
    }

    /// The faces gathered, judged: their flatness and their dimensions and plumb, as asked.
    pub fn finish(self) -> (Option<FlatnessSection>, Option<DimensionsSection>) {
        let printed_height_m = self.layer.map(|l| l.1).filter(|h| h.is_finite());
        let rule = self.rule;
        let dimensions = self
            .dimensions
            .map(|s| DimensionsSection::of(&self.grid, s, printed_height_m, rule));
        let flatness = self
            .standard
            .map(|s| FlatnessSection::of(&self.grid, s, printed_height_m, rule));
        (flatness, dimensions)
    }
}

impl FlatnessSection {
    fn of(
        grid: &FlatnessGrid,
        standard: FlatnessStandard,
        printed_height_m: Option<f64>,
        rule: DecisionRule,
    ) -> Self {
        let judged = grid.judge(&standard);
        let gaps: Vec<GapSection> = judged
            .gaps
            .iter()
            .filter(|g| g.span.is_none())
            .map(|g| GapSection::of(g, rule))
            .collect();
        let by_span = judged
            .gaps
            .iter()
            .filter(|g| g.span.is_some())
            .map(|g| GapSection::of(g, rule))
            .collect();
        let not_judged: Vec<NotJudgedSection> = judged
            .not_judged
            .iter()
            .map(|n| NotJudgedSection {
                face: n.face,
                direction: n.direction,
                reason: n.reason,
            })
            .collect();
        let faces_judged: std::collections::BTreeSet<u32> = gaps.iter().map(|g| g.face).collect();
        let faces = grid
            .faces()
            .iter()
            .enumerate()
            .filter(|(k, _)| faces_judged.contains(&(*k as u32)))
            .map(|(k, f)| FaceSection {
                face: k as u32,
                normal: f.normal.into_inner().into(),
                area_m2: f.area,
                size_m: f.size(),
            })
            .collect();
        let abrupt: Vec<AbruptSection> = judged
            .abrupt
            .iter()
            .map(|a| AbruptSection::of(a, rule))
            .collect();
        let verdict = gaps
            .iter()
            .map(|g| g.verdict)
            .chain(abrupt.iter().map(|a| a.verdict))
            .max()
            .unwrap_or(Verdict::NotJudged);
        let not_judged_reason = gaps.is_empty().then(|| {
            if grid.faces().is_empty() {
                "the design has no planar face of 0.01 m² or more".to_string()
            } else if judged
                .not_judged
                .iter()
                .all(|n| n.reason == NotJudgedReason::NotSeen)
            {
                format!(
                    "none of the design's {} planar face(s) was seen (out of view, or only \
                     beyond 75° incidence)",
                    grid.faces().len()
                )
            } else {
                format!(
                    "none of the design's {} planar face(s) was measured densely enough to lay \
                     a straightedge on (70 % of its length)",
                    grid.faces().len()
                )
            }
        });
        FlatnessSection {
            standard: standard.to_string(),
            key: standard.key(),
            decision_rule: rule,
            printed_height_m,
            verdict,
            not_judged_reason,
            faces,
            gaps,
            by_span,
            not_judged,
            abrupt,
        }
    }
}

/// One row of the standard's table: `(class, face, direction, what)`, then the value ± U, the
/// distance it was measured over and the limit (metres, shown in mm and m), its verdict and
/// where.
fn table_row(
    rows: &mut String,
    (class, face, direction, what): (&str, u32, Direction, &str),
    (value, u, distance, limit): (f64, f64, f64, f64),
    verdict: Verdict,
    [x, y, z]: [f64; 3],
) {
    use std::fmt::Write;
    let _ = write!(
        rows,
        "<tr class=\"{class}\" data-face=\"{face}\"><td>{face}</td><td>{}</td><td>{what}</td>\
         <td>{:.1} ± {:.1}</td><td>{distance:.2}</td><td>{:.1}</td><td class=\"{verdict}\">{}</td>\
         <td>({x:.2}, {y:.2}, {z:.2})</td></tr>",
        direction,
        value * 1e3,
        u * 1e3,
        limit * 1e3,
        verdict.shout()
    );
}

impl FlatnessSection {
    /// One line for the summary, in the words a site manager signs: the standard and its
    /// edition, the rule, what passed, failed, was inconclusive and was not judged.
    pub fn summary_line(&self) -> String {
        let count = |v: Verdict| self.gaps.iter().filter(|g| g.verdict == v).count();
        if self.gaps.is_empty() {
            return format!(
                "Flatness to {}: NOT JUDGED: {}.",
                self.standard,
                self.not_judged_reason
                    .as_deref()
                    .unwrap_or("nothing was judged")
            );
        }
        let mut line = format!(
            "Flatness to {} by the {} rule: {}; {} face-direction(s) judged: {} pass, {} \
             inconclusive, {} fail",
            self.standard,
            self.decision_rule,
            self.verdict.shout(),
            self.gaps.len(),
            count(Verdict::Pass) + count(Verdict::Warn),
            count(Verdict::Inconclusive),
            count(Verdict::Fail)
        );
        if let Some(a) = self
            .abrupt
            .iter()
            .max_by(|a, b| (a.step_m / a.limit_m).total_cmp(&(b.step_m / b.limit_m)))
        {
            line += &format!(
                "; the largest abrupt offset {:.1} ± {:.1} mm {} on face {} (limit {:.1} mm): {}",
                a.step_m * 1e3,
                a.uncertainty_m * 1e3,
                a.direction,
                a.face,
                a.limit_m * 1e3,
                a.verdict.shout()
            );
        }
        if !self.not_judged.is_empty() {
            line += &format!(
                "; {} not judged ({} not seen, {} too sparse)",
                self.not_judged.len(),
                self.not_judged
                    .iter()
                    .filter(|n| n.reason == NotJudgedReason::NotSeen)
                    .count(),
                self.not_judged
                    .iter()
                    .filter(|n| n.reason == NotJudgedReason::TooSparse)
                    .count()
            );
        }
        if let Some(w) = self
            .gaps
            .iter()
            .filter(|g| g.verdict >= Verdict::Inconclusive)
            .max_by(|a, b| (a.gap_m / a.limit_m).total_cmp(&(b.gap_m / b.limit_m)))
        {
            let [x, y, z] = w.at_m;
            line += &format!(
                ". The worst: {:.1} ± {:.1} mm {} on face {} under a straightedge on two high \
                 points {:.2} m apart (limit {:.1} mm there) at ({x:.2}, {y:.2}, {z:.2}) m",
                w.gap_m * 1e3,
                w.uncertainty_m * 1e3,
                w.direction,
                w.face,
                w.support_distance_m,
                w.limit_m * 1e3
            );
        }
        line + "."
    }
}

impl FlatnessSection {
    /// Each face's worst failing gap as a call-out for the maps of the scan layer judged,
    /// labelled `F<face>`.
    pub fn map_items(&self) -> Vec<crate::Item> {
        let mut worst: std::collections::BTreeMap<u32, &GapSection> = Default::default();
        for g in self
            .gaps
            .iter()
            .filter(|g| g.verdict >= Verdict::Inconclusive)
        {
            let e = worst.entry(g.face).or_insert(g);
            if g.gap_m / g.limit_m > e.gap_m / e.limit_m {
                *e = g;
            }
        }
        worst
            .values()
            .map(|g| {
                let r = (0.5 * g.support_distance_m).clamp(0.02, 0.1);
                let [x, y, z] = g.at_m;
                crate::Item {
                    label: format!("F{}", g.face),
                    kind: crate::ItemKind::Flatness,
                    verdict: g.verdict,
                    value: g.gap_m,
                    uncertainty: Some(g.uncertainty_m),
                    limit: g.limit_m,
                    layers: None,
                    z: [z, z],
                    at: Some(g.at_m),
                    extent: Some([[x - r, y - r, z - r], [x + r, y + r, z + r]]),
                    since: 0,
                    change: crate::Change::New,
                    previous: None,
                    text: format!(
                        "face {}: gap {:.1} ± {:.1} mm {}, supports {:.2} m apart (limit {:.1} \
                         mm, {}): {}",
                        g.face,
                        g.gap_m * 1e3,
                        g.uncertainty_m * 1e3,
                        g.direction,
                        g.support_distance_m,
                        g.limit_m * 1e3,
                        self.standard,
                        g.verdict.shout()
                    ),
                }
            })
            .collect()
    }

    /// The table of report.html: per face and direction, the governing gap ± U against the
    /// limit at its supports' distance, and the deepest within each table distance.
    pub fn html(&self) -> String {
        use std::fmt::Write;
        let mut rows = String::new();
        for g in self.gaps.iter().chain(&self.by_span) {
            let span = g
                .span_m
                .map_or("governing".to_string(), |s| format!("within {s} m"));
            table_row(
                &mut rows,
                (
                    if g.span_m.is_some() {
                        "gap span"
                    } else {
                        "gap governing"
                    },
                    g.face,
                    g.direction,
                    &span,
                ),
                (g.gap_m, g.uncertainty_m, g.support_distance_m, g.limit_m),
                g.verdict,
                g.at_m,
            );
        }
        for a in &self.abrupt {
            table_row(
                &mut rows,
                ("abrupt", a.face, a.direction, "abrupt, within 1 in"),
                (a.step_m, a.uncertainty_m, a.distance_m, a.limit_m),
                a.verdict,
                a.between_m[0],
            );
        }
        for n in &self.not_judged {
            let _ = write!(
                rows,
                "<tr class=\"not_judged\"><td>{}</td><td>{}</td><td colspan=\"6\" \
                 class=\"not_judged\">NOT JUDGED: {}</td></tr>",
                n.face,
                n.direction,
                n.reason.as_str().replace('_', " ")
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
        let settle = if self.gaps.iter().any(|g| g.verdict == Verdict::Inconclusive) {
            " An inconclusive gap lies within its uncertainty of the limit: another station \
             facing that face, or a denser scan of it, narrows U and settles it."
        } else {
            ""
        };
        format!(
            "<section class=\"flatness\"><h2>Flatness to {} <span class=\"verdict {v}\">{V}\
             </span></h2><p>A virtual straightedge on every planar face the scans saw, along the \
             layers and across them, resting on two high points of the surface; each gap is \
             judged against the limit at the distance between those points ({edition} Table 3 \
             interpolated), the value ± its expanded uncertainty U (k = 2) by the {rule} rule \
             (the latest scan layer{}).{settle} {}{}.</p>\
             <table class=\"flatness\"><tr><th>face</th><th>straightedge</th><th>gap</th>\
             <th>gap ± U mm</th><th>supports m apart</th><th>limit mm</th><th>verdict</th>\
             <th>deepest at (m)</th></tr>{rows}</table></section>",
            crate::markup::esc(&self.standard),
            self.printed_height_m
                .map_or(String::new(), |h| format!(", printed to {h:.3} m")),
            crate::markup::esc(&faces.join("; ")),
            self.not_judged_reason
                .as_ref()
                .map_or(String::new(), |r| format!(
                    "Not judged: {}",
                    crate::markup::esc(r)
                )),
            edition = DIN_18202_EDITION,
            rule = self.decision_rule,
            v = self.verdict,
            V = self.verdict.shout()
        )
    }
}

/// A dimension as built, judged.
#[derive(Debug, Clone, Serialize)]
pub struct DimensionSection {
    /// `length`, `thickness` or `height`.
    pub kind: DimensionKind,
    /// The faces it is measured between.
    pub faces: [u32; 2],
    /// The design's, metres.
    pub nominal_m: f64,
    /// As built, metres.
    pub measured_m: f64,
    /// The limit, metres.
    pub limit_m: f64,
    /// The expanded uncertainty (k = 2) of the measured size, metres.
    pub uncertainty_m: f64,
    /// By the report's decision rule.
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
    /// The expanded uncertainty (k = 2) of the gap, metres.
    pub uncertainty_m: f64,
    /// By the report's decision rule.
    pub verdict: Verdict,
}

/// report.json's `dimensions`: the element's dimensions and each upright face's plumb.
#[derive(Debug, Clone, Serialize)]
pub struct DimensionsSection {
    /// "DIN 18202:2019-07 Tables 1 and 2".
    pub standard: String,
    /// The decision rule the verdicts follow.
    pub decision_rule: DecisionRule,
    /// The printed height of the scan layer judged.
    pub printed_height_m: Option<f64>,
    /// The worst verdict; `not_judged` when nothing was seen well enough.
    pub verdict: Verdict,
    /// Between opposite faces, and to a top that was seen.
    pub dimensions: Vec<DimensionSection>,
    /// Per upright face.
    pub plumb: Vec<PlumbSection>,
}

impl DimensionsSection {
    fn of(
        grid: &FlatnessGrid,
        standard: DimensionsStandard,
        printed_height_m: Option<f64>,
        rule: DecisionRule,
    ) -> Self {
        let dimensions: Vec<DimensionSection> = grid
            .dimensions()
            .into_iter()
            .map(|d| DimensionSection {
                kind: d.kind,
                faces: d.faces,
                nominal_m: d.nominal,
                measured_m: d.measured,
                limit_m: d.limit,
                uncertainty_m: d.uncertainty,
                verdict: rule.decide(d.measured - d.nominal, d.uncertainty, d.limit),
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
                uncertainty_m: p.uncertainty,
                verdict: rule.decide(p.gap, p.uncertainty, p.limit),
            })
            .collect();
        let verdict = dimensions
            .iter()
            .map(|d| d.verdict)
            .chain(plumb.iter().map(|p| p.verdict))
            .max()
            .unwrap_or(Verdict::NotJudged);
        Self {
            standard: standard.to_string(),
            decision_rule: rule,
            printed_height_m,
            verdict,
            dimensions,
            plumb,
        }
    }

    /// One line for the summary: the standard, the rule, and what did not pass.
    pub fn summary_line(&self) -> String {
        let off: Vec<String> = self
            .dimensions
            .iter()
            .filter(|d| d.verdict >= Verdict::Inconclusive)
            .map(|d| {
                format!(
                    "{} {} {:+.1} ± {:.1} mm (limit ±{:.0} mm)",
                    d.kind,
                    d.verdict.shout(),
                    (d.measured_m - d.nominal_m) * 1e3,
                    d.uncertainty_m * 1e3,
                    d.limit_m * 1e3
                )
            })
            .chain(
                self.plumb
                    .iter()
                    .filter(|p| p.verdict >= Verdict::Inconclusive)
                    .map(|p| {
                        format!(
                            "face {} plumb {} {:+.1} ± {:.1} mm over {:.2} m (limit {:.0} mm)",
                            p.face,
                            p.verdict.shout(),
                            p.gap_m * 1e3,
                            p.uncertainty_m * 1e3,
                            p.height_m,
                            p.limit_m * 1e3
                        )
                    }),
            )
            .collect();
        let head = format!(
            "Dimensions and plumb to {} by the {} rule: {}",
            self.standard,
            self.decision_rule,
            self.verdict.shout()
        );
        if self.verdict == Verdict::NotJudged {
            format!("{head}: no two opposite faces, top or upright face was seen well enough.")
        } else if off.is_empty() {
            format!(
                "{head}, {} dimension(s) and {} face(s).",
                self.dimensions.len(),
                self.plumb.len()
            )
        } else {
            format!("{head}: {}.", off.join("; "))
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
                     </td><td>{:+.1} ± {:.1}</td><td>±{:.0}</td><td class=\"{v}\">{V}</td></tr>",
                    d.kind,
                    d.faces[0],
                    d.faces[1],
                    d.nominal_m * 1e3,
                    d.measured_m * 1e3,
                    (d.measured_m - d.nominal_m) * 1e3,
                    d.uncertainty_m * 1e3,
                    d.limit_m * 1e3,
                    v = d.verdict,
                    V = d.verdict.shout()
                )
            })
            .collect();
        let plumb: String = self
            .plumb
            .iter()
            .map(|p| {
                format!(
                    "<tr class=\"plumb\"><td>{}</td><td>{:.2}</td><td>{:+.1} ± {:.1}</td>\
                     <td>{:.0}</td><td class=\"{v}\">{V}</td></tr>",
                    p.face,
                    p.height_m,
                    p.gap_m * 1e3,
                    p.uncertainty_m * 1e3,
                    p.limit_m * 1e3,
                    v = p.verdict,
                    V = p.verdict.shout()
                )
            })
            .collect();
        format!(
            "<section class=\"dimensions\"><h2>Dimensions and plumb to {} <span class=\"verdict \
             {v}\">{V}</span></h2><p>Between opposite faces the design's distance plus each \
             face's median offset (a local bulge does not move it); a height to a top face that \
             was seen; each upright face's tilt, fitted to its cells, as the gap it makes over \
             the height seen.</p><table class=\"dimensions\"><tr><th>dimension</th>\
             <th>faces</th><th>design mm</th><th>as built mm</th><th>off ± U mm</th><th>limit mm</th>\
             <th>verdict</th></tr>{dims}</table><table class=\"plumb\"><tr><th>face</th>\
             <th>height m</th><th>top less foot ± U mm</th><th>limit mm</th><th>verdict</th></tr>\
             {plumb}</table></section>",
            crate::markup::esc(&self.standard),
            v = self.verdict,
            V = self.verdict.shout()
        )
    }
}
