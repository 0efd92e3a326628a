//! Verdicts over a job's findings: pass, warn or fail for every finding, layer band and scan
//! layer against the crew's limits (core's `verdict`), each finding followed across scan layers
//! (since when, grown or shrunk, resolved), every layer band's history (width, shift and top in
//! each scan layer that saw it, and its creep), and the few lines a site manager reads first.
//!
//! Findings are matched across scan layers by what they are: a layer band's width, shift and
//! creep by the band, the top by itself, an area by its kind and an overlapping extent.

use std::collections::BTreeMap;

use asbuilt_core::verdict::{LimitKind, Limits, Verdict};
use asbuilt_protocol::{RegionFinding, RegionKind, StationFindings};
use serde::Serialize;

use crate::Section;

/// Areas farther apart than this are different findings, metres.
const AREA_MATCH_MARGIN: f64 = 0.05;
/// More than this share of a station's points beyond the maximum distance is worth a warning.
const NO_MATCH_WARN: f64 = 0.01;

/// The report's judgement: every finding, layer band, scan layer and station held to the limits.
#[derive(Debug, Clone, Serialize)]
pub struct Assessment {
    /// The limits everything was held to.
    pub limits: LimitsSection,
    /// The worst verdict of each job's latest scan layer.
    pub verdict: Verdict,
    /// What the page opens with: what is out of tolerance, where, since when, what changed.
    pub summary: Vec<String>,
    /// Per scan layer, in print order: its findings with their verdicts.
    pub scan_layers: Vec<ScanLayerVerdicts>,
    /// Per layer band, lowest first: its measures in every scan layer that saw it.
    pub layer_history: Vec<LayerHistory>,
    /// Each station's own verdict from its points.
    pub stations: Vec<StationVerdict>,
    /// All stations' points together, judged as one station's.
    pub overall: Option<StationVerdict>,
}

/// The limits, as report.json writes them.
#[derive(Debug, Clone, Serialize)]
pub struct LimitsSection {
    /// |width deviation| of a layer band.
    pub width_m: f64,
    /// |top of the print − printed height|.
    pub top_height_m: f64,
    /// |shift| of a layer band in the plan.
    pub position_m: f64,
    /// |peak deviation| of an area of the surface.
    pub surface_m: f64,
    /// Area of missing material.
    pub missing_area_m2: f64,
    /// |change of a layer band's width| since the first scan layer that saw it.
    pub creep_m: f64,
    /// A value beyond this fraction of its limit warns.
    pub warn_fraction: f64,
    /// `KIND=VALUE@FIRST-LAST`, in the order they apply.
    pub ranges: Vec<String>,
    /// How each value and its U were held to its limit.
    pub decision_rule: asbuilt_core::verdict::DecisionRule,
}

impl From<&Limits> for LimitsSection {
    fn from(l: &Limits) -> Self {
        Self {
            width_m: l.width,
            top_height_m: l.top_height,
            position_m: l.position,
            surface_m: l.surface,
            missing_area_m2: l.missing_area_m2,
            creep_m: l.creep,
            warn_fraction: l.warn_fraction,
            ranges: l
                .ranges
                .iter()
                .map(|r| format!("{}={}@{}-{}", r.kind.as_str(), r.value, r.first, r.last))
                .collect(),
            decision_rule: l.rule,
        }
    }
}

/// How many findings passed, warned and failed.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq, Eq)]
pub struct VerdictCounts {
    /// Within the warning fraction of their limit.
    pub pass: u32,
    /// Beyond the warning fraction, within the limit.
    pub warn: u32,
    /// Within their uncertainty of the limit.
    pub inconclusive: u32,
    /// Beyond the limit.
    pub fail: u32,
}

/// What a finding measures; report.json spells it as [`ItemKind::as_str`] does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ItemKind {
    /// A layer band's width deviation.
    Width,
    /// A layer band's shift in the plan.
    Position,
    /// A layer band's width change since first scanned.
    Creep,
    /// The top of the print against the printed height.
    TopHeight,
    /// An area with material outside the design.
    Excess,
    /// An area whose surface lies inside the design.
    Deficit,
    /// Missing material.
    Missing,
    /// The deepest gap under a straightedge on a face (`--flatness`; drawn on the maps only).
    Flatness,
}

impl ItemKind {
    /// `width`, `position`, `creep`, `top_height`, `excess`, `deficit`, `missing` or
    /// `flatness`.
    pub fn as_str(self) -> &'static str {
        match self {
            ItemKind::Width => "width",
            ItemKind::Position => "position",
            ItemKind::Creep => "creep",
            ItemKind::TopHeight => "top_height",
            ItemKind::Excess => "excess",
            ItemKind::Deficit => "deficit",
            ItemKind::Missing => "missing",
            ItemKind::Flatness => "flatness",
        }
    }
}

impl From<RegionKind> for ItemKind {
    fn from(k: RegionKind) -> Self {
        match k {
            RegionKind::Excess => ItemKind::Excess,
            RegionKind::Deficit => ItemKind::Deficit,
            RegionKind::Missing => ItemKind::Missing,
        }
    }
}

impl std::fmt::Display for ItemKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How a finding changed since the previous scan layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Change {
    /// The previous scan layer did not show it.
    New,
    /// Larger by more than the step (the limit beyond the warning fraction, or a tenth).
    Grown,
    /// Smaller by more than the step.
    Shrunk,
    /// Within the step.
    Steady,
}

impl Change {
    /// `new`, `grown`, `shrunk` or `steady`.
    pub fn as_str(self) -> &'static str {
        match self {
            Change::New => "new",
            Change::Grown => "grown",
            Change::Shrunk => "shrunk",
            Change::Steady => "steady",
        }
    }
}

impl std::fmt::Display for Change {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl ScanLayerVerdicts {
    /// "After 24 layers (printed 0.480 m)", or "All stations" for a job not scanned while
    /// printing.
    pub fn title(&self) -> String {
        match self.printed_height {
            Some(h) => format!("After {} layers (printed {h:.3} m)", self.layer + 1),
            None => "All stations".to_string(),
        }
    }
}

impl VerdictCounts {
    fn add(&mut self, v: Verdict) {
        match v {
            Verdict::Pass => self.pass += 1,
            Verdict::Warn => self.warn += 1,
            Verdict::Inconclusive => self.inconclusive += 1,
            Verdict::Fail => self.fail += 1,
            Verdict::NotJudged => {}
        }
    }
}

/// One scan layer's verdicts.
#[derive(Debug, Clone, Serialize)]
pub struct ScanLayerVerdicts {
    /// The job.
    pub job: u64,
    /// The scan layer: the last layer printed (from 0) when it was scanned.
    pub layer: u32,
    /// Height of the print when it was scanned, metres; `None` when not printing.
    pub printed_height: Option<f64>,
    /// Stations whose points went into its findings.
    pub stations: u32,
    /// The worst verdict of its findings.
    pub verdict: Verdict,
    /// Over the findings below.
    pub counts: VerdictCounts,
    /// Warnings and failures, failures first; `label` marks them on the maps.
    pub items: Vec<Item>,
    /// Every layer band seen, with the worst verdict of what touches it.
    pub layers: Vec<LayerVerdict>,
    /// Findings of the previous scan layer that this one no longer shows.
    pub resolved: Vec<String>,
}

/// A layer band's verdict in one scan layer.
#[derive(Debug, Clone, Serialize)]
pub struct LayerVerdict {
    /// The band's layer, from 0.
    pub layer: u32,
    /// The worst verdict of what touches it.
    pub verdict: Verdict,
}

/// One finding with its verdict.
#[derive(Debug, Clone, Serialize)]
pub struct Item {
    /// "1", "2", … within the scan layer, as drawn on its maps.
    pub label: String,
    /// What was measured.
    pub kind: ItemKind,
    /// Against its limit.
    pub verdict: Verdict,
    /// Signed metres (m² for missing material).
    pub value: f64,
    /// Its expanded uncertainty U (k = 2), in the value's unit; `None` where not known.
    pub uncertainty: Option<f64>,
    /// The limit it was held to, in the value's unit.
    pub limit: f64,
    /// First and last layer band, when known.
    pub layers: Option<[u32; 2]>,
    /// Heights it spans, metres.
    pub z: [f64; 2],
    /// Where it is (an area's centre); `None` for a whole layer band.
    pub at: Option<[f64; 3]>,
    /// An area's extent.
    pub extent: Option<[[f64; 3]; 2]>,
    /// The scan layer that first showed it (and every one since).
    pub since: u32,
    /// Against the previous scan layer.
    pub change: Change,
    /// Its value in the previous scan layer, when that one showed it.
    pub previous: Option<f64>,
    /// One line a person reads.
    pub text: String,
}

/// One layer band through every scan layer that saw it.
#[derive(Debug, Clone, Serialize)]
pub struct LayerHistory {
    /// The job.
    pub job: u64,
    /// The band's layer, from 0.
    pub layer: u32,
    /// The band's bottom, metres.
    pub z_min: f64,
    /// The band's top, metres.
    pub z_max: f64,
    /// Its measures in each scan layer, in print order.
    pub scans: Vec<LayerScan>,
    /// Relative width (see [`LayerScan::width_relative`]) in the latest scan layer minus that in
    /// the first, metres: creep or sag under the layers above.
    pub width_change: Option<f64>,
    /// The creep's verdict against its limit, once two scan layers saw the band.
    pub creep_verdict: Option<Verdict>,
}

/// A layer band's measures in one scan layer.
#[derive(Debug, Clone, Serialize)]
pub struct LayerScan {
    /// The scan layer.
    pub scan_layer: u32,
    /// Height of the print then, metres.
    pub printed_height: Option<f64>,
    /// Design samples on the band's sides with an M3C2 distance.
    pub samples: u32,
    /// Mean M3C2 distance on the band's sides, metres.
    pub mean: Option<f64>,
    /// Width deviation, metres, when the sides seen could tell it from a shift.
    pub width: Option<f64>,
    /// Width minus the median width of the scan layer's bands: what is left when the stations'
    /// pose errors, which widen or narrow every band of a scan layer alike, are taken out.
    pub width_relative: Option<f64>,
    /// The relative width's expanded uncertainty (k = 2): its fit's alone.
    pub width_relative_uncertainty: Option<f64>,
    /// Shift in x and y, metres, when the sides seen could tell it from a width.
    pub shift: Option<[f64; 2]>,
    /// Top of the print minus the printed height, when this band was the top.
    pub top: Option<f64>,
}

/// A station's (or all stations') verdict from its points.
#[derive(Debug, Clone, Serialize)]
pub struct StationVerdict {
    /// The station's id.
    pub id: String,
    /// Against the surface limit.
    pub verdict: Verdict,
    /// Why, in one line.
    pub reason: String,
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// The verdicts of a job's findings (the latest of each scan layer), stations and all stations
/// together.
pub fn assess(
    findings: &[StationFindings],
    stations: &[Section],
    overall: Option<&Section>,
    limits: &Limits,
) -> Assessment {
    let mut by_job: BTreeMap<u64, Vec<&StationFindings>> = BTreeMap::new();
    for f in findings {
        by_job.entry(f.job).or_default().push(f);
    }
    let mut scan_layers = Vec::new();
    let mut layer_history = Vec::new();
    for layers in by_job.values_mut() {
        layers.sort_by_key(|f| f.layer);
        let (verdicts, history) = job_verdicts(layers, limits);
        scan_layers.extend(verdicts);
        layer_history.extend(history);
    }
    let stations: Vec<_> = stations.iter().map(|s| station(s, limits)).collect();
    let latest: Vec<&ScanLayerVerdicts> = by_job
        .keys()
        .filter_map(|j| scan_layers.iter().rev().find(|s| s.job == *j))
        .collect();
    let overall = overall.map(|s| station(s, limits));
    let mut summary = summary(&latest, &scan_layers, &stations);
    // Without findings (C2M alone) the points are all there is to judge the job by.
    let verdict = if latest.is_empty() {
        if let Some(o) = &overall {
            summary.insert(
                0,
                format!(
                    "No findings (they need coverage and M3C2): judged by all points together, \
                     {}: {}.",
                    o.verdict.as_str().to_uppercase(),
                    o.reason
                ),
            );
        }
        overall.as_ref().map_or(Verdict::Pass, |o| o.verdict)
    } else {
        latest
            .iter()
            .map(|s| s.verdict)
            .max()
            .unwrap_or(Verdict::Pass)
    };
    Assessment {
        limits: limits.into(),
        verdict,
        summary,
        scan_layers,
        layer_history,
        stations,
        overall,
    }
}

/// One job's scan layers' verdicts, in the order of `layers` (each scan layer's latest
/// findings, by layer), and every band's history. A scan layer's verdicts depend on it and the
/// ones before, never after: the verdicts of the layers so far are the report's, so a live view
/// numbers its findings as the report will.
pub fn job_verdicts(
    layers: &[&StationFindings],
    limits: &Limits,
) -> (Vec<ScanLayerVerdicts>, Vec<LayerHistory>) {
    let history = history(layers, limits);
    let mut out: Vec<ScanLayerVerdicts> = Vec::with_capacity(layers.len());
    for f in layers {
        let s = scan_layer(f, &history, out.last(), limits);
        out.push(s);
    }
    (out, history)
}

/// Every band's measures across the scan layers, and its creep.
fn history(layers: &[&StationFindings], limits: &Limits) -> Vec<LayerHistory> {
    let mut bands: BTreeMap<u32, LayerHistory> = BTreeMap::new();
    for f in layers {
        let top_band = f.layers.iter().map(|r| r.layer).max();
        let median =
            asbuilt_core::stats::median(f.layers.iter().filter_map(|r| finite(r.width_deviation)));
        for r in &f.layers {
            let h = bands.entry(r.layer).or_insert_with(|| LayerHistory {
                job: f.job,
                layer: r.layer,
                z_min: r.z_min,
                z_max: r.z_max,
                scans: Vec::new(),
                width_change: None,
                creep_verdict: None,
            });
            let width = finite(r.width_deviation);
            h.scans.push(LayerScan {
                scan_layer: f.layer,
                printed_height: finite(f.printed_height),
                samples: r.samples,
                mean: finite(r.mean),
                width,
                width_relative: width.zip(median).map(|(w, m)| w - m),
                width_relative_uncertainty: width.and(finite(r.width_fit_uncertainty)),
                shift: (r.shift[0].is_finite() && r.shift[1].is_finite()).then_some(r.shift),
                top: (Some(r.layer) == top_band)
                    .then(|| finite(f.top_height_deviation))
                    .flatten(),
            });
        }
    }
    for h in bands.values_mut() {
        if let Some(change) = creep_at(h, u32::MAX) {
            h.width_change = Some(change.0);
            let (v, _) = limits.judge(LimitKind::Creep, change, Some((h.layer, h.layer)));
            h.creep_verdict = Some(v);
        }
    }
    bands.into_values().collect()
}

/// The change of a band's relative width from the first scan layer that measured it up to scan
/// layer `at`, with its U (the two fits' together; relative widths leave the poses out); `None`
/// until two have.
fn creep_at(h: &LayerHistory, at: u32) -> Option<(f64, f64)> {
    let mut widths = h
        .scans
        .iter()
        .filter(|s| s.scan_layer <= at)
        .filter_map(|s| {
            s.width_relative
                .map(|w| (w, s.width_relative_uncertainty.unwrap_or(f64::NAN)))
        });
    let first = widths.next()?;
    let last = widths.next_back()?;
    Some((last.0 - first.0, first.1.hypot(last.1)))
}

fn mm(v: f64) -> String {
    format!("{:+.1} mm", v * 1e3)
}

fn xyz(p: [f64; 3]) -> String {
    format!("({:.2}, {:.2}, {:.2}) m", p[0], p[1], p[2])
}

fn layers_text(l: Option<[u32; 2]>) -> String {
    match l {
        Some([a, b]) if a == b => format!("layer {a}"),
        Some([a, b]) => format!("layers {a}–{b}"),
        None => "layers unknown".into(),
    }
}

/// A finding before it is compared with the previous scan layer.
struct Raw {
    kind: ItemKind,
    limit_kind: LimitKind,
    value: f64,
    /// U (k = 2); NaN where not known (then it proves nothing either way).
    uncertainty: f64,
    layers: Option<[u32; 2]>,
    z: [f64; 2],
    at: Option<[f64; 3]>,
    extent: Option<[[f64; 3]; 2]>,
}

fn raw_items(f: &StationFindings, history: &[LayerHistory]) -> Vec<Raw> {
    let mut out = Vec::new();
    for r in &f.layers {
        let band = Some([r.layer, r.layer]);
        let z = [r.z_min, r.z_max];
        let mut push = |kind, limit_kind, (value, uncertainty): (f64, f64)| {
            if value.is_finite() {
                out.push(Raw {
                    kind,
                    limit_kind,
                    value,
                    uncertainty,
                    layers: band,
                    z,
                    at: None,
                    extent: None,
                });
            }
        };
        push(
            ItemKind::Width,
            LimitKind::Width,
            (r.width_deviation, r.width_uncertainty),
        );
        push(
            ItemKind::Position,
            LimitKind::Position,
            (r.shift[0].hypot(r.shift[1]), r.shift_uncertainty),
        );
        let band_history = history.iter().find(|h| h.layer == r.layer);
        if let Some(c) = band_history.and_then(|h| creep_at(h, f.layer)) {
            push(ItemKind::Creep, LimitKind::Creep, c);
        }
    }
    if f.top_height_deviation.is_finite() {
        let h = f.printed_height;
        out.push(Raw {
            kind: ItemKind::TopHeight,
            limit_kind: LimitKind::TopHeight,
            value: f.top_height_deviation,
            uncertainty: f.top_uncertainty,
            layers: Some([f.layer, f.layer]),
            z: [h, h + f.top_height_deviation],
            at: None,
            extent: None,
        });
    }
    for g in f.regions.iter().chain(f.missing.iter()) {
        out.push(area(g));
    }
    out
}

fn area(g: &RegionFinding) -> Raw {
    let missing = g.kind == RegionKind::Missing;
    Raw {
        kind: g.kind.into(),
        limit_kind: if missing {
            LimitKind::MissingArea
        } else {
            LimitKind::Surface
        },
        value: if missing { g.area_m2 } else { g.peak },
        uncertainty: if missing {
            g.area_uncertainty
        } else {
            g.peak_uncertainty
        },
        layers: (g.layers[0] != u32::MAX).then_some(g.layers),
        z: [g.min[2], g.max[2]],
        at: Some(g.centroid),
        extent: Some([g.min, g.max]),
    }
}

fn same_finding(a: &Raw, b: &Item) -> bool {
    if a.kind != b.kind {
        return false;
    }
    match (a.extent, b.extent) {
        (Some([lo, hi]), Some([blo, bhi])) => (0..3)
            .all(|i| lo[i] <= bhi[i] + AREA_MATCH_MARGIN && blo[i] <= hi[i] + AREA_MATCH_MARGIN),
        // Layer rows by their band, the top by itself.
        _ => a.kind == ItemKind::TopHeight || a.layers == b.layers,
    }
}

fn describe(raw: &Raw) -> String {
    let (kind, value, layers, at) = (raw.kind, raw.value, raw.layers, raw.at);
    let u = raw.uncertainty;
    let pm = |scale: f64| {
        if u.is_finite() && u > 0.0 {
            format!(" ± {:.1}", u * scale)
        } else {
            String::new()
        }
    };
    match kind {
        ItemKind::Width => format!(
            "{} width {:+.1}{} mm",
            layers_text(layers),
            value * 1e3,
            pm(1e3)
        ),
        ItemKind::Position => format!(
            "{} shifted {:.1}{} mm",
            layers_text(layers),
            value * 1e3,
            pm(1e3)
        ),
        ItemKind::Creep => format!(
            "{} width changed {} since first scanned (beyond the scan layer's common change)",
            layers_text(layers),
            mm(value)
        ),
        ItemKind::TopHeight => format!("top of the print {:+.1}{} mm", value * 1e3, pm(1e3)),
        ItemKind::Flatness => format!(
            "gap {:.1} mm under the straightedge at {}",
            value * 1e3,
            at.map_or_else(String::new, xyz)
        ),
        ItemKind::Missing => format!(
            "missing material, {:.0}{} cm², {} at {}",
            value * 1e4,
            pm(1e4),
            layers_text(layers),
            at.map_or_else(String::new, xyz)
        ),
        ItemKind::Excess | ItemKind::Deficit => format!(
            "{kind} {:+.1}{} mm, {} at {}",
            value * 1e3,
            pm(1e3),
            layers_text(layers),
            at.map_or_else(String::new, xyz)
        ),
    }
}

/// How a finding of `value` against `limit` changed since the scan layer `before` held it: by
/// more than the margin between the warning and the limit (at least a tenth of the limit) it
/// grew or shrank.
fn change_since(value: f64, before: Option<&Item>, limits: &Limits, limit: f64) -> Change {
    let Some(b) = before else {
        return Change::New;
    };
    let d = value.abs() - b.value.abs();
    let step = (1.0 - limits.warn_fraction).max(0.1) * limit;
    if d > step {
        Change::Grown
    } else if d < -step {
        Change::Shrunk
    } else {
        Change::Steady
    }
}

fn scan_layer(
    f: &StationFindings,
    history: &[LayerHistory],
    previous: Option<&ScanLayerVerdicts>,
    limits: &Limits,
) -> ScanLayerVerdicts {
    let mut counts = VerdictCounts::default();
    let mut band_verdicts: BTreeMap<u32, Verdict> =
        f.layers.iter().map(|r| (r.layer, Verdict::Pass)).collect();
    let mut items = Vec::new();
    let mut matched_previous = vec![false; previous.map_or(0, |p| p.items.len())];
    for raw in raw_items(f, history) {
        let layers = raw.layers.map(|[a, b]| (a, b));
        let (verdict, limit) = limits.judge(raw.limit_kind, (raw.value, raw.uncertainty), layers);
        counts.add(verdict);
        if let Some([a, b]) = raw.layers {
            for (_, v) in band_verdicts.range_mut(a..=b) {
                *v = (*v).max(verdict);
            }
        }
        if verdict == Verdict::Pass {
            continue;
        }
        let before = previous.and_then(|p| {
            let i = p.items.iter().position(|it| same_finding(&raw, it))?;
            matched_previous[i] = true;
            Some(&p.items[i])
        });
        let change = change_since(raw.value, before, limits, limit);
        items.push((
            verdict,
            Item {
                label: String::new(),
                kind: raw.kind,
                verdict,
                value: raw.value,
                uncertainty: finite(raw.uncertainty),
                limit,
                layers: raw.layers,
                z: raw.z,
                at: raw.at,
                extent: raw.extent,
                since: before.map_or(f.layer, |b| b.since),
                change,
                previous: before.map(|b| b.value),
                text: describe(&raw),
            },
        ));
    }
    // Failures first; within a verdict, in the order of the findings (largest areas first).
    items.sort_by_key(|(v, _)| std::cmp::Reverse(*v));
    let items: Vec<Item> = items
        .into_iter()
        .enumerate()
        .map(|(i, (_, mut it))| {
            it.label = (i + 1).to_string();
            it
        })
        .collect();
    let resolved = previous
        .map(|p| {
            p.items
                .iter()
                .zip(&matched_previous)
                .filter(|(_, m)| !**m)
                .map(|(it, _)| it.text.clone())
                .collect()
        })
        .unwrap_or_default();
    let verdict = items
        .iter()
        .map(|i| i.verdict)
        .max()
        .unwrap_or(Verdict::Pass);
    ScanLayerVerdicts {
        job: f.job,
        layer: f.layer,
        printed_height: finite(f.printed_height),
        stations: f.stations,
        verdict,
        counts,
        items,
        layers: band_verdicts
            .into_iter()
            .map(|(layer, verdict)| LayerVerdict { layer, verdict })
            .collect(),
        resolved,
    }
}

/// A station's verdict is about the measurement, not the part: the part's deviations are the
/// findings'. A station whose typical point is off the design (a wrong pose, the wrong part)
/// fails; one with local deviations beyond the surface limit, or many points that found no
/// design, warns and points to the findings.
fn station(s: &Section, limits: &Limits) -> StationVerdict {
    let limit = limits.surface;
    let d = &s.distances;
    let (verdict, reason) = match (d.median_abs, d.p95_abs) {
        _ if d.matched == 0 => (Verdict::Fail, "no point matched the design".to_string()),
        (Some(m), _) if m > limit => (
            Verdict::Fail,
            format!(
                "half its points are more than {:.1} mm off the design: check the pose and the part",
                m * 1e3
            ),
        ),
        (_, Some(p)) if p > limit => (
            Verdict::Warn,
            format!(
                "5 % of its points are beyond {:.1} mm: local deviations, see the findings",
                p * 1e3
            ),
        ),
        _ if (d.no_match as f64) > NO_MATCH_WARN * s.points as f64 => (
            Verdict::Warn,
            format!(
                "{:.1} % of its points found no design within the maximum distance",
                100.0 * d.no_match as f64 / s.points.max(1) as f64
            ),
        ),
        _ => (
            Verdict::Pass,
            format!(
                "95 % of its points within {:.1} mm",
                d.p95_abs.unwrap_or(0.0) * 1e3
            ),
        ),
    };
    StationVerdict {
        id: s.id.clone(),
        verdict,
        reason,
    }
}

fn summary(
    latest: &[&ScanLayerVerdicts],
    all: &[ScanLayerVerdicts],
    stations: &[StationVerdict],
) -> Vec<String> {
    let mut out = Vec::new();
    for s in latest {
        out.push(format!(
            "{}: {}: {} out of tolerance, {} to watch.",
            s.title(),
            s.verdict.as_str().to_uppercase(),
            s.counts.fail,
            s.counts.warn
        ));
        for it in s.items.iter().filter(|i| i.verdict == Verdict::Fail) {
            // Offline, without a printed height, there is one scan layer and no "since".
            let since = match (s.printed_height, it.change) {
                (None, _) => String::new(),
                (Some(_), Change::New) => ", new".to_string(),
                (Some(_), c) => format!(
                    ", since the scan after {} layers{}",
                    it.since + 1,
                    if c == Change::Steady {
                        String::new()
                    } else {
                        format!(", {c} since the last scan")
                    }
                ),
            };
            out.push(format!(
                "[{}] {} (limit {}){since}.",
                it.label,
                it.text,
                it.limit_text(),
            ));
        }
        let previous = all.iter().rfind(|p| p.job == s.job && p.layer < s.layer);
        if let Some(p) = previous {
            let new: Vec<&Item> = s.items.iter().filter(|i| i.change == Change::New).collect();
            let grown = s.items.iter().filter(|i| i.change == Change::Grown).count();
            out.push(format!(
                "Since the scan after {} layers: {} new, {} grown, {} resolved.",
                p.layer + 1,
                new.len(),
                grown,
                s.resolved.len()
            ));
        }
    }
    let failed: Vec<&str> = stations
        .iter()
        .filter(|s| s.verdict == Verdict::Fail)
        .map(|s| s.id.as_str())
        .collect();
    if !failed.is_empty() {
        out.push(format!(
            "Stations whose measurement is in doubt: {}.",
            failed.join(", ")
        ));
    }
    out
}

impl Item {
    /// "±5.0 mm", or "20 cm²" for missing material.
    pub fn limit_text(&self) -> String {
        if self.kind == ItemKind::Missing {
            format!("{:.0} cm²", self.limit * 1e4)
        } else {
            format!("±{:.1} mm", self.limit * 1e3)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use asbuilt_protocol::LayerFinding;

    const T: f64 = 0.005;

    /// Scan layer `layer` with bands 0..=layer; `width(band)` their width deviations.
    fn scan(layer: u32, width: impl Fn(u32) -> f64) -> StationFindings {
        let mut f = StationFindings::new(1, 4);
        f.layer = layer;
        f.printed_height = 0.02 * f64::from(layer + 1);
        f.tolerance = T;
        f.stations = 4;
        f.top_height_deviation = 0.0;
        f.top_uncertainty = 0.0005;
        for band in 0..=layer {
            let z = 0.02 * f64::from(band);
            f.layers
                .push(LayerFinding {
                    layer: band,
                    z_min: z,
                    z_max: z + 0.02,
                    samples: 100,
                    mean: 0.0,
                    width_deviation: width(band),
                    shift: [0.0, 0.0],
                    width_uncertainty: 0.0005,
                    shift_uncertainty: 0.0005,
                    width_fit_uncertainty: 0.0003,
                    width_verdict: asbuilt_protocol::SurveyVerdict::NotJudged,
                    shift_verdict: asbuilt_protocol::SurveyVerdict::NotJudged,
                })
                .unwrap();
        }
        f
    }

    fn bulge(at_x: f64, peak: f64) -> RegionFinding {
        RegionFinding {
            kind: RegionKind::Excess,
            samples: 20,
            area_m2: 0.002,
            centroid: [at_x, 0.1, 0.1],
            min: [at_x - 0.05, 0.09, 0.05],
            max: [at_x + 0.05, 0.1, 0.15],
            peak,
            peak_at: [at_x, 0.1, 0.1],
            peak_uncertainty: 0.0005,
            area_uncertainty: 0.0001,
            verdict: asbuilt_protocol::SurveyVerdict::NotJudged,
            mean: peak / 2.0,
            layers: [2, 7],
        }
    }

    #[test]
    fn a_band_that_widens_under_the_layers_above_is_creep_but_a_common_offset_is_not() {
        // Scan 1 after 10 layers: all bands on design. Scan 2 after 20: every band 3 mm wider
        // (a station's pose error), band 1 another 6 mm (creep under the load above).
        let first = scan(9, |_| 0.0);
        let second = scan(19, |b| 0.003 + if b == 1 { 0.006 } else { 0.0 });
        let a = assess(&[first, second], &[], None, &Limits::from_tolerance(T));
        let band1 = &a.layer_history[1];
        assert!((band1.width_change.unwrap() - 0.006).abs() < 1e-12);
        assert_eq!(band1.creep_verdict, Some(Verdict::Fail));
        for h in a
            .layer_history
            .iter()
            .filter(|h| h.layer != 1 && h.layer < 10)
        {
            assert!(h.width_change.unwrap().abs() < 1e-12, "{h:?}");
            assert_eq!(h.creep_verdict, Some(Verdict::Pass));
        }
        // Seen once: no change to tell.
        assert_eq!(a.layer_history[15].width_change, None);
        let s = &a.scan_layers[1];
        let creep: Vec<_> = s
            .items
            .iter()
            .filter(|i| i.kind == ItemKind::Creep)
            .collect();
        assert_eq!(creep.len(), 1);
        assert_eq!(creep[0].layers, Some([1, 1]));
        // Band 1 is 9 mm wide: the width fails too; the others at 3 mm pass (warn from 3.75).
        let widths: Vec<_> = s
            .items
            .iter()
            .filter(|i| i.kind == ItemKind::Width)
            .collect();
        assert_eq!(widths.len(), 1);
        assert_eq!(s.layers[1].verdict, Verdict::Fail);
        assert_eq!(s.layers[2].verdict, Verdict::Pass);
        assert_eq!(a.verdict, Verdict::Fail);
    }

    #[test]
    fn an_area_is_followed_across_scan_layers_and_resolved_when_it_goes() {
        let mut a1 = scan(9, |_| 0.0);
        a1.regions.push(bulge(0.5, 0.008)).unwrap();
        let mut a2 = scan(19, |_| 0.0);
        // The same bulge, a little larger and moved by less than the match margin.
        a2.regions.push(bulge(0.52, 0.012)).unwrap();
        a2.regions.push(bulge(-0.5, 0.007)).unwrap();
        let a3 = scan(29, |_| 0.0);
        let a = assess(&[a1, a2, a3], &[], None, &Limits::from_tolerance(T));
        let s2 = &a.scan_layers[1];
        let old = s2.items.iter().find(|i| i.at.unwrap()[0] > 0.0).unwrap();
        assert_eq!((old.since, old.change), (9, Change::Grown));
        assert_eq!(old.previous, Some(0.008));
        let new = s2.items.iter().find(|i| i.at.unwrap()[0] < 0.0).unwrap();
        assert_eq!((new.since, new.change), (19, Change::New));
        let s3 = &a.scan_layers[2];
        assert_eq!(s3.verdict, Verdict::Pass);
        assert_eq!(s3.resolved.len(), 2);
        assert_eq!(a.verdict, Verdict::Pass);
        assert!(
            a.summary[0].starts_with("After 30 layers"),
            "{:?}",
            a.summary
        );
        assert!(a.summary[1].contains("2 resolved"), "{:?}", a.summary);
    }

    #[test]
    fn the_verdicts_of_the_scan_layers_so_far_are_the_reports() {
        // Creep, a followed bulge and a resolved one: everything that looks back.
        let mut a = scan(9, |_| 0.0);
        a.regions.push(bulge(0.5, 0.008)).unwrap();
        let mut b = scan(19, |b| 0.003 + if b == 1 { 0.006 } else { 0.0 });
        b.regions.push(bulge(0.52, 0.012)).unwrap();
        let c = scan(29, |b| if b == 1 { 0.012 } else { 0.0 });
        let all = [a, b, c];
        let limits = Limits::from_tolerance(T);
        let report = assess(&all, &[], None, &limits);
        let json = |v: &ScanLayerVerdicts| format!("{v:?}");
        for k in 1..=all.len() {
            let so_far: Vec<&StationFindings> = all[..k].iter().collect();
            let (live, _) = job_verdicts(&so_far, &limits);
            assert_eq!(live.len(), k);
            for (l, r) in live.iter().zip(&report.scan_layers) {
                assert_eq!(json(l), json(r), "scan layer {}", l.layer);
            }
        }
        assert!(report.scan_layers[2].items.len() > 1);
    }

    #[test]
    fn crew_limits_per_layer_range_turn_a_failure_into_a_pass() {
        let f = scan(9, |b| if (2..=4).contains(&b) { 0.012 } else { 0.0 });
        let mut limits = Limits::from_tolerance(T);
        let strict = assess(std::slice::from_ref(&f), &[], None, &limits);
        assert_eq!(strict.scan_layers[0].counts.fail, 3);
        limits.set("width=20mm@2-4".parse().unwrap());
        let lenient = assess(&[f], &[], None, &limits);
        assert_eq!(lenient.scan_layers[0].counts.fail, 0);
        assert_eq!(lenient.scan_layers[0].verdict, Verdict::Pass);
        assert_eq!(lenient.limits.ranges, vec!["width=0.02@2-4".to_string()]);
    }
}
