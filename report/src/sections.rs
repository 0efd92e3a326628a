//! `report.json` and the summary table.

use asbuilt_protocol::{Histogram, RejectCounts, StationReport};
use serde::Serialize;

use crate::suite::{BandMethods, SuiteSection, TwoCloudSection};

#[derive(Debug, Serialize)]
pub struct Report {
    pub asbuilt_version: &'static str,
    pub design: DesignSection,
    pub parameters: Parameters,
    /// The comparisons that ran; C2M always does, since it places and validates the points.
    pub methods: Vec<&'static str>,
    pub stations: Vec<Section>,
    pub overall: Section,
    /// Per layer band, lowest first, with `--layer-height`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub layers: Option<Vec<BandMethods>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub m3c2_two_cloud: Option<TwoCloudSection>,
    /// Findings, the latest of each scan layer: drawn again from a recording's chunks with the
    /// agent's own stage (`report`), or the job's (`inspect --method all`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub findings: Vec<asbuilt_protocol::StationFindings>,
    /// Verdicts against the crew's limits, each finding followed across scan layers, the layer
    /// history and the summary the page opens with; with findings.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub assessment: Option<crate::Assessment>,
    pub warnings: Vec<String>,
    /// Each scan layer's deviation maps, for report.html.
    #[serde(skip)]
    pub maps: Vec<crate::maps::ScanLayerMaps>,
}

#[derive(Debug, Serialize)]
pub struct DesignSection {
    pub path: String,
    pub units: String,
    pub vertices: usize,
    pub triangles: usize,
    pub warnings: Vec<String>,
    pub index_cell_size_m: f64,
    pub index_cells: usize,
    pub index_bytes: usize,
}

#[derive(Debug, Serialize)]
pub struct Parameters {
    pub tolerance_m: f64,
    pub max_distance_m: f64,
    pub histogram_range_m: f64,
    pub spacing_m: f64,
    pub coverage_threshold_m: f64,
    /// What raised the coverage threshold where the scan is sparser.
    #[serde(skip_serializing_if = "String::is_empty")]
    pub coverage_spacing: String,
    pub projection_diameter_m: f64,
    pub max_depth_m: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub printed_height_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub layer_height_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference: Option<String>,
}

/// One station, or the whole job. Distances in metres; NaN (no matched point) is `null`.
#[derive(Debug, Serialize)]
pub struct Section {
    pub id: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scan: Option<String>,
    pub points: u64,
    pub valid: u64,
    pub rejected: u64,
    pub rejected_by_reason: RejectSection,
    pub no_match: u64,
    pub matched: u64,
    pub mean: Option<f64>,
    pub std: Option<f64>,
    pub rms: Option<f64>,
    pub min: Option<f64>,
    pub max: Option<f64>,
    pub median_abs: Option<f64>,
    pub p95_abs: Option<f64>,
    pub within_tolerance: u64,
    pub above_tolerance: u64,
    pub below_tolerance: u64,
    pub histogram: HistogramSection,
    #[serde(flatten)]
    pub suite: SuiteSection,
}

#[derive(Debug, Serialize)]
pub struct RejectSection {
    pub non_finite: u64,
    pub out_of_range: u64,
    pub scanner_invalid: u64,
    pub without_pose: u64,
    pub in_rejected_chunks: u64,
    pub malformed_lines: u64,
}

#[derive(Debug, Serialize)]
pub struct HistogramSection {
    pub low: f64,
    pub high: f64,
    pub underflow: u64,
    pub overflow: u64,
    pub bins: Vec<u64>,
}

impl Report {
    /// Gives the stations, findings and layer bands their verdicts against `limits`.
    pub fn assess(&mut self, limits: &asbuilt_core::verdict::Limits) {
        self.assessment = Some(crate::assess(
            &self.findings,
            &self.stations,
            Some(&self.overall),
            limits,
        ));
    }
}

pub(crate) fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

impl Section {
    /// Matched points within the tolerance, per cent; `None` when nothing matched.
    pub fn in_tolerance_percent(&self) -> Option<f64> {
        (self.matched > 0).then(|| 100.0 * self.within_tolerance as f64 / self.matched as f64)
    }

    pub fn from_report(r: &StationReport, scan: Option<String>, malformed_lines: u64) -> Self {
        let s = &r.stats;
        let rej: RejectCounts = r.rejected;
        let h: Histogram = r.histogram;
        let rejected = rej.total() + malformed_lines;
        Self {
            id: r.name.as_str().to_string(),
            scan,
            points: r.points_received + malformed_lines,
            valid: r.points_received - rej.total(),
            rejected,
            rejected_by_reason: RejectSection {
                non_finite: rej.non_finite,
                out_of_range: rej.out_of_range,
                scanner_invalid: rej.scanner_invalid,
                without_pose: rej.without_pose,
                in_rejected_chunks: rej.in_rejected_chunks,
                malformed_lines,
            },
            no_match: r.no_match,
            matched: s.count,
            mean: finite(s.mean),
            std: finite(s.std),
            rms: finite(s.rms),
            min: finite(s.min),
            max: finite(s.max),
            median_abs: finite(s.median_abs),
            p95_abs: finite(s.p95_abs),
            within_tolerance: s.within,
            above_tolerance: s.above,
            below_tolerance: s.below,
            histogram: HistogramSection {
                low: h.low,
                high: h.high,
                underflow: h.underflow,
                overflow: h.overflow,
                bins: h.bins.to_vec(),
            },
            suite: SuiteSection::default(),
        }
    }
}

fn mm(v: Option<f64>) -> String {
    v.map(|v| format!("{:.3}", v * 1e3))
        .unwrap_or_else(|| "-".into())
}

/// The verdict and the summary the page opens with, as lines for a terminal; empty without an
/// assessment.
pub fn verdict_text(report: &Report) -> String {
    let Some(a) = &report.assessment else {
        return String::new();
    };
    let mut out = format!("verdict: {}\n", a.verdict.to_uppercase());
    for line in &a.summary {
        out.push_str("  ");
        out.push_str(line);
        out.push('\n');
    }
    out
}

/// A table a person reads at the end of a run. Distances in millimetres.
pub fn summary_table(report: &Report) -> String {
    let mut out = format!(
        "{:<12} {:>9} {:>8} {:>8} {:>9} {:>8} {:>8} {:>9} {:>9} {:>8}\n",
        "station",
        "points",
        "rejected",
        "no-match",
        "mean mm",
        "std mm",
        "|d|50 mm",
        "|d|95 mm",
        "max mm",
        "in tol %"
    );
    for s in report
        .stations
        .iter()
        .chain(std::iter::once(&report.overall))
    {
        if std::ptr::eq(s, &report.overall) {
            out.push_str(&"-".repeat(98));
            out.push('\n');
        }
        let max_abs = match (s.min, s.max) {
            (Some(a), Some(b)) => Some(if a.abs() > b.abs() { a } else { b }),
            _ => None,
        };
        let in_tol = s
            .in_tolerance_percent()
            .map_or("-".into(), |p| format!("{p:.1}"));
        out.push_str(&format!(
            "{:<12} {:>9} {:>8} {:>8} {:>9} {:>8} {:>8} {:>9} {:>9} {:>8}\n",
            s.id,
            s.points,
            s.rejected,
            s.no_match,
            mm(s.mean),
            mm(s.std),
            mm(s.median_abs),
            mm(s.p95_abs),
            mm(max_abs),
            in_tol
        ));
    }
    out
}
