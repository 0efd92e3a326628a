//! `report.json` and the summary table.

use asbuilt_protocol::{DeviationStats, Histogram, RejectCounts, StationReport};
use serde::Serialize;

use asbuilt_core::coverage::CoverageSummary;
use asbuilt_core::findings::Findings;
use asbuilt_core::layers::BandRow;
use asbuilt_core::m3c2::streaming::StreamingSummary;
use nalgebra::Point3;

/// `report.json`: the design, the parameters, every station and all of them together, the
/// findings and their verdicts.
#[derive(Debug, Serialize)]
pub struct Report {
    /// The asbuilt release that wrote it.
    pub asbuilt_version: &'static str,
    /// The design and its index.
    pub design: DesignSection,
    /// What the comparison was run with.
    pub parameters: Parameters,
    /// The comparisons that ran; C2M always does, since it places and validates the points.
    pub methods: Vec<&'static str>,
    /// Each station, in order.
    pub stations: Vec<Section>,
    /// All stations' points together.
    pub overall: Section,
    /// Per layer band, lowest first, with `--layer-height`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub layers: Option<Vec<BandMethods>>,
    /// M3C2 between the scan and a reference cloud, with `--reference`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub m3c2_two_cloud: Option<TwoCloudSection>,
    /// Findings, the latest of each scan layer: drawn again from a recording's chunks with the
    /// agent's own stage (`report`), or the job's (`inspect --method all`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub findings: Vec<asbuilt_protocol::StationFindings>,
    /// The advice for the layers still to print after each scan layer (its last station's),
    /// drawn again from a recording whose agent had `[corrections]` on. report.json names
    /// their flags ([`CorrectionRow`]).
    #[serde(
        skip_serializing_if = "Vec::is_empty",
        serialize_with = "corrections_by_name"
    )]
    pub corrections: Vec<asbuilt_protocol::LayerCorrection>,
    /// The deepest gap under a virtual straightedge per face, direction and span, judged by a
    /// standard (`--flatness`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flatness: Option<crate::flatness::FlatnessSection>,
    /// The element's dimensions and each upright face's plumb, judged by a standard
    /// (`--dimensions`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dimensions: Option<crate::flatness::DimensionsSection>,
    /// Verdicts against the crew's limits, each finding followed across scan layers, the layer
    /// history and the summary the page opens with; with findings.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub assessment: Option<crate::Assessment>,
    /// What the reader should know: open designs, stations that failed, sizes that disagree.
    pub warnings: Vec<String>,
    /// Each scan layer's deviation maps, for report.html.
    #[serde(skip)]
    pub maps: Vec<crate::maps::ScanLayerMaps>,
}

/// The design as loaded and indexed.
#[derive(Debug, Serialize)]
pub struct DesignSection {
    /// The design file.
    pub path: String,
    /// The units it was declared in, `m` or `mm`.
    pub units: String,
    /// Vertices after loading.
    pub vertices: usize,
    /// Triangles after loading (degenerate ones dropped).
    pub triangles: usize,
    /// What loading found: open boundaries, dropped triangles.
    pub warnings: Vec<String>,
    /// The C2M index's cell size.
    pub index_cell_size_m: f64,
    /// Cells the C2M index keeps.
    pub index_cells: usize,
    /// The C2M index's memory.
    pub index_bytes: usize,
}

impl DesignSection {
    /// The design file as loaded (`counts`: its vertices and triangles; `warnings`: what
    /// loading found) and indexed.
    pub fn new(
        path: String,
        units: asbuilt_core::Units,
        counts: (usize, usize),
        warnings: Vec<String>,
        index: &asbuilt_core::c2m::IndexStats,
    ) -> Self {
        Self {
            path,
            units: units.to_string(),
            vertices: counts.0,
            triangles: counts.1,
            warnings,
            index_cell_size_m: index.cell_size,
            index_cells: index.cells,
            index_bytes: index.bytes,
        }
    }
}

/// What the comparison was run with. Metres.
#[derive(Debug, Serialize)]
pub struct Parameters {
    /// |d| at most this is within tolerance.
    pub tolerance_m: f64,
    /// Points farther from the design have no match.
    pub max_distance_m: f64,
    /// The histogram covers ±this.
    pub histogram_range_m: f64,
    /// Spacing of the design samples (coverage and M3C2 core points).
    pub spacing_m: f64,
    /// A design sample with a scan point this close is observed.
    pub coverage_threshold_m: f64,
    /// What raised the coverage threshold where the scan is sparser.
    #[serde(skip_serializing_if = "String::is_empty")]
    pub coverage_spacing: String,
    /// M3C2 cylinder diameter.
    pub projection_diameter_m: f64,
    /// M3C2 cylinder half-length: the largest deviation it measures.
    pub max_depth_m: f64,
    /// The printed height the design was cut at, when printing.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub printed_height_m: Option<f64>,
    /// Nominal layer height, for the per-layer rows.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub layer_height_m: Option<f64>,
    /// The reference cloud of two-cloud M3C2.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference: Option<String>,
}

/// One station, or the whole job. Distances in metres; NaN (no matched point) is `null`.
#[derive(Debug, Serialize)]
pub struct Section {
    /// The station's id, or `overall`.
    pub id: String,
    /// How the station's report ended, when not complete (`Incomplete`, `TimedOut`,
    /// `Partial`, `Interrupted`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub status: Option<String>,
    /// Which try at the station this is, from the second on (the cell sent it again).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub attempt: Option<u8>,
    /// The scan file it was read from (offline).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scan: Option<String>,
    /// Every point that arrived.
    pub points: u64,
    /// Points that could be compared.
    pub valid: u64,
    /// Points rejected, whatever the reason.
    pub rejected: u64,
    /// Points rejected, by reason.
    pub rejected_by_reason: RejectSection,
    /// The signed distances (C2M) of its valid points.
    #[serde(flatten)]
    pub distances: DistanceSection,
    /// Matched points beyond +tolerance (excess material).
    pub above_tolerance: u64,
    /// Matched points beyond −tolerance (missing material).
    pub below_tolerance: u64,
    /// Histogram of the signed distances.
    pub histogram: HistogramSection,
    /// What the other methods (C2C, coverage, M3C2) found for it.
    #[serde(flatten)]
    pub suite: SuiteSection,
}

/// The distance statistics of one method, signed (C2M) or unsigned (C2C). Metres; `None`
/// where no point matched.
#[derive(Debug, Serialize)]
pub struct DistanceSection {
    /// Points with a distance.
    pub matched: u64,
    /// Points with none within the maximum distance.
    pub no_match: u64,
    /// Mean distance.
    pub mean: Option<f64>,
    /// Standard deviation.
    pub std: Option<f64>,
    /// Root mean square.
    pub rms: Option<f64>,
    /// Smallest distance.
    pub min: Option<f64>,
    /// Largest distance.
    pub max: Option<f64>,
    /// Median |d| (histogram estimate).
    pub median_abs: Option<f64>,
    /// 95th percentile of |d| (histogram estimate).
    pub p95_abs: Option<f64>,
    /// Points with |d| within the tolerance.
    pub within_tolerance: u64,
}

impl DistanceSection {
    /// From the statistics of the matched points, and the count of those without a match.
    pub fn new(s: &DeviationStats, no_match: u64) -> Self {
        Self {
            matched: s.count,
            no_match,
            mean: finite(s.mean),
            std: finite(s.std),
            rms: finite(s.rms),
            min: finite(s.min),
            max: finite(s.max),
            median_abs: finite(s.median_abs),
            p95_abs: finite(s.p95_abs),
            within_tolerance: s.within,
        }
    }

    /// Matched points within the tolerance, per cent; `None` when nothing matched.
    pub fn in_tolerance_percent(&self) -> Option<f64> {
        (self.matched > 0).then(|| 100.0 * self.within_tolerance as f64 / self.matched as f64)
    }

    /// Mean, standard deviation, median |d| and 95 % |d| in millimetres, `none` where absent:
    /// the columns of the station tables.
    pub fn mm_columns(&self, none: &str) -> [String; 4] {
        [self.mean, self.std, self.median_abs, self.p95_abs].map(|v| mm(v, none))
    }
}

/// A distance in millimetres to the micrometre, `none` where there is none.
pub fn mm(v: Option<f64>, none: &str) -> String {
    v.map_or_else(|| none.to_string(), |v| format!("{:.3}", v * 1e3))
}

/// Rejected points by reason.
#[derive(Debug, Serialize)]
pub struct RejectSection {
    /// NaN or infinite coordinates.
    pub non_finite: u64,
    /// Beyond the maximum range from the scanner.
    pub out_of_range: u64,
    /// Marked invalid by the scanner.
    pub scanner_invalid: u64,
    /// Arrived before (or without) their station's pose.
    pub without_pose: u64,
    /// In chunks rejected whole (oversized, malformed).
    pub in_rejected_chunks: u64,
    /// Lines of a text scan file that were not points.
    pub malformed_lines: u64,
}

/// The signed-distance histogram, metres.
#[derive(Debug, Serialize)]
pub struct HistogramSection {
    /// Lower edge of the first bin.
    pub low: f64,
    /// Upper edge of the last bin.
    pub high: f64,
    /// Distances below `low`.
    pub underflow: u64,
    /// Distances at or above `high`.
    pub overflow: u64,
    /// Counts of the equal bins between `low` and `high`.
    pub bins: Vec<u64>,
}

/// A correction as report.json gives it: its flags as names, without the message's padding and
/// version.
#[derive(Serialize)]
struct CorrectionRow<'a> {
    job: u64,
    station: u32,
    attempt: u8,
    layer: u32,
    from_layer: u32,
    first_layers: u32,
    flags: Vec<&'static str>,
    z_first: f64,
    z_then: f64,
    drift_per_layer: f64,
    flow: f64,
    path_offset: [f64; 2],
    top: &'a asbuilt_protocol::Evidence,
    width: &'a asbuilt_protocol::Evidence,
    shift: &'a asbuilt_protocol::Evidence,
}

fn corrections_by_name<S: serde::Serializer>(
    cs: &[asbuilt_protocol::LayerCorrection],
    s: S,
) -> Result<S::Ok, S::Error> {
    s.collect_seq(cs.iter().map(|c| CorrectionRow {
        job: c.job,
        station: c.station,
        attempt: c.attempt,
        layer: c.layer,
        from_layer: c.from_layer,
        first_layers: c.first_layers,
        flags: asbuilt_protocol::CorrectionFlags(c.flags).names(),
        z_first: c.z_first,
        z_then: c.z_then,
        drift_per_layer: c.drift_per_layer,
        flow: c.flow,
        path_offset: c.path_offset,
        top: &c.top,
        width: &c.width,
        shift: &c.shift,
    }))
}

impl Report {
    /// Gives the stations, findings and layer bands their verdicts against `limits`.
    pub fn assess(&mut self, limits: &asbuilt_core::verdict::Limits) {
        let mut a = crate::assess(&self.findings, &self.stations, Some(&self.overall), limits);
        // Judged by a standard too: the job's verdict is the worse, and the summary names it.
        if let Some(d) = &self.dimensions {
            a.verdict = a.verdict.max(d.verdict);
            a.summary.insert(0, d.summary_line());
        }
        if let Some(f) = &self.flatness {
            a.verdict = a.verdict.max(f.verdict);
            a.summary.insert(0, f.summary_line());
        }
        self.assessment = Some(a);
    }
}

pub(crate) fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

impl Section {
    /// A station's section from its report; `scan` and `malformed_lines` come from the file
    /// it was read from, offline.
    pub fn from_report(r: &StationReport, scan: Option<String>, malformed_lines: u64) -> Self {
        let s = &r.stats;
        let rej: RejectCounts = r.rejected;
        let h: Histogram = r.histogram;
        let rejected = rej.total() + malformed_lines;
        Self {
            id: r.name.as_str().to_string(),
            status: None,
            attempt: None,
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
            distances: DistanceSection::new(s, r.no_match),
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

/// The verdict and the summary the page opens with, as lines for a terminal; empty without an
/// assessment.
pub fn verdict_text(report: &Report) -> String {
    let Some(a) = &report.assessment else {
        return String::new();
    };
    let mut out = format!("verdict: {}\n", a.verdict.as_str().to_uppercase());
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
        let d = &s.distances;
        let max_abs = match (d.min, d.max) {
            (Some(a), Some(b)) => Some(if a.abs() > b.abs() { a } else { b }),
            _ => None,
        };
        let in_tol = d
            .in_tolerance_percent()
            .map_or("-".into(), |p| format!("{p:.1}"));
        let [mean, std, median, p95] = d.mm_columns("-");
        out.push_str(&format!(
            "{:<12} {:>9} {:>8} {:>8} {mean:>9} {std:>8} {median:>8} {p95:>9} {:>9} {in_tol:>8}\n",
            s.id,
            s.points,
            s.rejected,
            d.no_match,
            mm(max_abs, "-"),
        ));
    }
    out
}

/// Coverage: which design samples the scan observed. Counts of design samples.
#[derive(Debug, Serialize)]
pub struct CoverageSection {
    /// Design samples, each standing for `area_per_sample_m2`.
    pub observed: u64,
    /// Facing a station in range with a clear view, and no scan point near: missing material.
    pub missing: u64,
    /// Facing a station in range, but the design itself blocks the view.
    pub occluded: u64,
    /// No station could have seen it (out of range, facing away, grazing).
    pub not_scanned: u64,
    /// The design surface the missing samples stand for, m².
    pub missing_area_m2: f64,
    /// The design surface one sample stands for, m².
    pub area_per_sample_m2: f64,
    /// The scanner's angular step the threshold was raised by, mrad (given or measured);
    /// absent with a fixed threshold.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub angular_step_mrad: Option<f64>,
    /// Signed distance from each design sample to the nearest scan point within reach
    /// (negative: the scan lies inside the design). Overall only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reverse_c2c: Option<DistanceSection>,
}

impl CoverageSection {
    pub(crate) fn new(s: &CoverageSummary, area: f64) -> Self {
        Self {
            observed: s.observed,
            missing: s.missing,
            occluded: s.occluded,
            not_scanned: s.not_scanned,
            missing_area_m2: s.missing_area_m2,
            area_per_sample_m2: area,
            angular_step_mrad: s.angular_step.map(|a| a * 1e3),
            reverse_c2c: None,
        }
    }
}

/// M3C2 at the design samples, along the design's normals. Metres.
#[derive(Debug, Serialize)]
pub struct M3c2Section {
    /// Core points, those with scan points in their cylinder, the significant ones, and the
    /// mean and extremes of their distances.
    #[serde(flatten)]
    pub summary: StreamingSummary,
    /// The registration error in the level of detection: the stations' pose sigma.
    pub registration_sigma_m: f64,
}

impl M3c2Section {
    pub(crate) fn new(s: &StreamingSummary, sigma: f64) -> Self {
        Self {
            summary: s.clone(),
            registration_sigma_m: sigma,
        }
    }
}

/// What the suite adds to one station's (or the job's) section.
#[derive(Debug, Default, Serialize)]
pub struct SuiteSection {
    /// C2C, with `--method c2c`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub c2c: Option<DistanceSection>,
    /// Coverage, with `--method coverage`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coverage: Option<CoverageSection>,
    /// M3C2, with `--method m3c2`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub m3c2: Option<M3c2Section>,
    /// Points more than the tolerance above the printed height: excess material, or layers
    /// printed after the height was given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub above_printed_height: Option<u64>,
}

impl SuiteSection {
    /// One line for the methods beside C2M, in millimetres and square centimetres; empty when
    /// only C2M ran.
    pub fn methods_line(&self) -> String {
        let mut parts = Vec::new();
        if let Some(c) = &self.c2c {
            parts.push(format!("C2C median {} mm", crate::mm(c.median_abs, "-")));
        }
        if let Some(c) = &self.coverage {
            parts.push(format!(
                "coverage: {} observed, {} missing ({:.1} cm²), {} occluded, {} not scanned{}",
                c.observed,
                c.missing,
                c.missing_area_m2 * 1e4,
                c.occluded,
                c.not_scanned,
                c.angular_step_mrad
                    .map(|a| format!(" (gaps up to the scan spacing allowed: {a:.2} mrad step)"))
                    .unwrap_or_default()
            ));
        }
        if let Some(m) = &self.m3c2 {
            parts.push(format!(
                "M3C2: {} of {} core points measured, {} significant",
                m.summary.with_points, m.summary.core_points, m.summary.significant
            ));
        }
        if let Some(a) = self.above_printed_height {
            parts.push(format!("{a} points above the printed height"));
        }
        parts.join("; ")
    }
}

/// One method's distances in a layer band. Metres.
#[derive(Debug, Serialize)]
pub struct BandStats {
    /// Points (or core points) in the band.
    pub count: u32,
    /// Mean distance.
    pub mean: f64,
    /// Standard deviation; `None` for fewer than two.
    pub std: Option<f64>,
}

impl From<&BandRow> for BandStats {
    fn from(r: &BandRow) -> Self {
        Self {
            count: r.count,
            mean: r.mean,
            std: r.std,
        }
    }
}

/// One layer band in `inspect --layer-height`'s table: what each method measured there
/// (not the findings' width and shift rows, which are `core::findings::LayerRow`).
#[derive(Debug, Serialize)]
pub struct BandMethods {
    /// The band's layer, from 0.
    pub layer: u32,
    /// The band's bottom, metres.
    pub z_min: f64,
    /// The band's top, metres.
    pub z_max: f64,
    /// Where the scan's points in this band top out (98th percentile of their heights).
    pub top_m: Option<f64>,
    /// C2M in the band.
    pub c2m: Option<BandStats>,
    /// C2C in the band.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub c2c: Option<BandStats>,
    /// M3C2 in the band.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub m3c2: Option<BandStats>,
    /// Missing material in the band, m².
    #[serde(skip_serializing_if = "Option::is_none")]
    pub missing_area_m2: Option<f64>,
}

/// Two-cloud M3C2 between `--reference` and the scans, at core points subsampled from the
/// reference.
#[derive(Debug, Serialize)]
pub struct TwoCloudSection {
    /// The reference cloud file.
    pub reference: String,
    /// Its points.
    pub reference_points: usize,
    /// Scan points compared.
    pub scan_points: usize,
    /// Core points subsampled from the reference.
    pub core_points: usize,
    /// Core points with a distance.
    pub with_distance: usize,
    /// Core points whose distance exceeds their level of detection.
    pub significant: usize,
    /// Mean distance, metres.
    pub mean_distance: Option<f64>,
    /// Neighbourhood diameter for the normals, metres.
    pub normal_diameter_m: f64,
}

/// The job-level additions.
#[derive(Debug, Default, Serialize)]
pub struct SuiteTotals {
    /// The section's methods over every station.
    #[serde(flatten)]
    pub section: SuiteSection,
    /// Per layer band, lowest first, with `--layer-height`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub layers: Option<Vec<BandMethods>>,
    /// Two-cloud M3C2 against `--reference`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub m3c2_two_cloud: Option<TwoCloudSection>,
    /// For the rerun view: missing samples with their reverse distance, and M3C2 core points
    /// with distance and significance.
    #[serde(skip)]
    pub missing_view: Vec<(Point3<f64>, f32, bool)>,
    /// M3C2 core points with distance and significance, for the rerun view.
    #[serde(skip)]
    pub m3c2_view: Vec<(Point3<f64>, f32, bool)>,
    /// With M3C2 and coverage: the job's findings, as the agent draws them for a scan layer,
    /// and the stations they come from.
    #[serde(skip)]
    pub findings: Option<(Findings, u32)>,
    /// With the findings: every design sample's state behind them, for the maps.
    #[serde(skip)]
    pub samples: Vec<asbuilt_core::scan_layer::SampleState>,
}
