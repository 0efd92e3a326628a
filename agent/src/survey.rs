//! A surveyor's checks over each scan layer, live: the faces' flatness under a virtual
//! straightedge and the element's dimensions and plumb, judged by the standards in
//! `[tolerances]` (`flatness`, `dimensions`) after every station, logged and sent to the cell
//! as [`SurfaceFindings`]. The cells grow
//! with the design's faces, never with the scan; `asbuilt report` judges the recording the same
//! way into report.json.

use asbuilt_core::Design;
use asbuilt_core::flatness::{
    DimensionsStandard, Direction, FlatnessGrid, FlatnessStandard, StationView,
};
use asbuilt_core::verdict::{DecisionRule, Verdict};
use asbuilt_protocol::{
    AbruptRow, DimensionRow, FixedText, FlatnessRow, PointDeviation, SurfaceFindings,
    SurveyDecisionRule, SurveyVerdict,
};

use crate::{info, warn};

/// The faces' points of the scan layer being scanned, and the standards they are judged by.
pub struct Survey {
    grid: FlatnessGrid,
    flatness: Option<FlatnessStandard>,
    dimensions: Option<DimensionsStandard>,
    rule: DecisionRule,
    /// The scan layer gathered: job and printed height's bits.
    layer: Option<(u64, u64)>,
}

impl Survey {
    /// Cells over `design`'s planar faces; `None` when no standard is set.
    pub fn new(
        design: &Design,
        flatness: Option<FlatnessStandard>,
        dimensions: Option<DimensionsStandard>,
        rule: DecisionRule,
    ) -> Option<Self> {
        (flatness.is_some() || dimensions.is_some()).then(|| Self {
            grid: FlatnessGrid::new(design),
            flatness,
            dimensions,
            rule,
            layer: None,
        })
    }

    /// Forgets the scan layer gathered when it is of `job`: a new print under its number starts
    /// the faces over.
    pub fn forget_job(&mut self, job: u64) {
        if self.layer.is_some_and(|(j, _)| j == job) {
            self.grid.clear();
            self.layer = None;
        }
    }

    /// A chunk's deviations of `station` of `job` scanned at `printed_height`: a new scan
    /// layer starts the faces over.
    pub fn ingest(
        &mut self,
        job: u64,
        printed_height: f64,
        station: &StationView,
        devs: &[PointDeviation],
    ) {
        let layer = (job, printed_height.to_bits());
        if self.layer != Some(layer) {
            self.grid.clear();
            self.layer = Some(layer);
        }
        self.grid.add(devs, station);
    }

    /// Judges the scan layer so far after station `key` (job, station) of printed layer
    /// `layer` at `printed_height`, logs it and returns it for the cell.
    pub fn judge(&self, key: (u64, u32), layer: u32, printed_height: f64) -> SurfaceFindings {
        let (job, station) = key;
        let mut out = SurfaceFindings::new(job, station);
        out.layer = layer;
        out.printed_height = printed_height;
        out.decision_rule = match self.rule {
            DecisionRule::Iso14253_1 => SurveyDecisionRule::Iso14253_1,
            DecisionRule::Simple => SurveyDecisionRule::Simple,
        };
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
        let judged = self.grid.judge(standard);
        out.flatness_standard = FixedText::truncated(&standard.key());
        out.not_judged = judged.not_judged.len() as u32;
        for g in &judged.gaps {
            let row = FlatnessRow {
                face: g.face,
                direction: u8::from(g.direction == Direction::Across),
                verdict: g.verdict(self.rule).into(),
                span: g.span.unwrap_or(f64::NAN),
                gap: g.gap,
                support_distance: g.support_distance,
                limit: g.limit,
                uncertainty: g.uncertainty,
                at: g.at.coords.into(),
            };
            if out.flatness.push(row).is_err() {
                out.truncated += 1;
            }
        }
        for a in &judged.abrupt {
            let row = AbruptRow {
                face: a.face,
                direction: u8::from(a.direction == Direction::Across),
                verdict: a.verdict(self.rule).into(),
                step: a.step,
                distance: a.distance,
                limit: a.limit,
                uncertainty: a.uncertainty,
                at: a.between[0].coords.into(),
            };
            if out.abrupt.push(row).is_err() {
                out.truncated += 1;
            }
        }
        let governing: Vec<_> = judged.gaps.iter().filter(|g| g.span.is_none()).collect();
        let verdict = governing
            .iter()
            .map(|g| g.verdict(self.rule))
            .max()
            .unwrap_or(Verdict::NotJudged);
        let worst = governing
            .iter()
            .max_by(|a, b| (a.gap / a.limit).total_cmp(&(b.gap / b.limit)));
        let line = match worst {
            None => format!(
                "job {job} station {station}: flatness to {standard} over the scan layer so \
                 far: NOT JUDGED, no face was seen well enough to lay a straightedge on"
            ),
            Some(w) => format!(
                "job {job} station {station}: flatness to {standard} ({}) over the scan layer \
                 so far: {}, {} face-direction(s) judged, {} not; the worst {:.1} ± {:.1} mm \
                 {} on face {} with its supports {:.2} m apart (limit {:.1} mm) at ({:.2}, \
                 {:.2}, {:.2}) m",
                self.rule,
                verdict.shout(),
                governing.len(),
                judged.not_judged.len(),
                w.gap * 1e3,
                w.uncertainty * 1e3,
                w.direction.as_str().replace('_', " "),
                w.face,
                w.support_distance,
                w.limit * 1e3,
                w.at.x,
                w.at.y,
                w.at.z
            ),
        };
        if verdict > Verdict::Pass {
            warn!("{line}");
        } else {
            info!("{line}");
        }
    }

    /// The dimensions and plumb into `out`, logged.
    fn judge_dimensions(&self, standard: &DimensionsStandard, out: &mut SurfaceFindings) {
        let (job, station) = (out.job, out.station);
        out.dimensions_standard = FixedText::truncated("din18202");
        let rule = self.rule;
        // Each row, what to call it and how far it is off; dimensions, then plumb.
        let row = |kind, faces, (nominal, measured, limit, uncertainty)| DimensionRow {
            kind,
            verdict: SurveyVerdict::NotJudged,
            faces,
            nominal,
            measured,
            limit,
            uncertainty,
        };
        let dims = self.grid.dimensions().into_iter().map(|d| {
            let r = row(
                d.kind as u8,
                d.faces,
                (d.nominal, d.measured, d.limit, d.uncertainty),
            );
            (d.kind.as_str().to_string(), r, d.measured - d.nominal)
        });
        let plumb = self.grid.plumb().into_iter().map(|p| {
            let r = row(3, [p.face; 2], (p.height, p.gap, p.limit, p.uncertainty));
            (
                format!("face {} plumb over {:.2} m", p.face, p.height),
                r,
                p.gap,
            )
        });
        let mut off = Vec::new();
        for (what, mut r, deviation) in dims.chain(plumb) {
            let v = rule.decide(deviation, r.uncertainty, r.limit);
            r.verdict = v.into();
            if v > Verdict::Pass {
                off.push(format!(
                    "{what} {} {:+.1} ± {:.1} mm (limit ±{:.0})",
                    v.shout(),
                    deviation * 1e3,
                    r.uncertainty * 1e3,
                    r.limit * 1e3
                ));
            }
            if out.dimensions.push(r).is_err() {
                out.truncated += 1;
            }
        }
        if off.is_empty() {
            info!(
                "job {job} station {station}: dimensions and plumb to {standard} ({rule}) over \
                 the scan layer so far: PASS"
            );
        } else {
            warn!(
                "job {job} station {station}: dimensions and plumb to {standard} ({rule}) over \
                 the scan layer so far: {}",
                off.join("; ")
            );
        }
    }
}
