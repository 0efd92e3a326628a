//! What a crew can act on, from design-referenced M3C2 and coverage over one scan layer's
//! stations: per-layer width, shift and top height, connected areas out of tolerance, and
//! missing material, each with where it is.
//!
//! Everything works on the design samples (memory grows with the design only):
//! - **Width and shift per layer band**: on the side faces, a layer `w` wider and shifted by `t`
//!   moves the surface along the outward normal `n` by `d = w/2 + n·t`. A robust fit of
//!   `w/2, tₓ, t_y` to the M3C2 distances of the band (started from the fit that explains most
//!   of the band, so a bulge does not bias it; see `width`) gives both; one side alone cannot
//!   tell them apart and gives none.
//! - **Top height**: the mean M3C2 distance on the cap at the printed height.
//! - **Regions**: samples with a significant |distance| above the tolerance, linked when closer
//!   than four sample spacings; each region's extent, area and peak.
//! - **Missing material**: samples classified missing by coverage, linked the same way.
//!
//! Every value carries its expanded uncertainty U (k = 2, GUM): the fit's own (the residuals'
//! spread through the normal equations, counted once per cylinder's worth of samples because
//! neighbouring cylinders share their points), and the stations' pose σ. A width and a shift
//! are fitted only where opposite sides were seen, which no one station sees: the width takes
//! the difference of two stations' errors (`2σ²`), the shift their mean (`σ²/2`); a top and a
//! peak one station's (`σ²`). An area's edge is
//! known to a sample: each of its edge samples is in or out (rectangular, half a sample's area).
//!
//! Samples whose cylinder reaches over a sharp design edge (the surface turns by more than 30°
//! within the cylinder's radius, and three pose σ more, by which a station's error moves the
//! face beyond) are left out of fits and regions: there the cylinder averages two faces and
//! shows a deviation that is not in the print.

use nalgebra::{Point3, Vector3};
use rustc_hash::FxHashMap;

mod judged;
mod width;
pub use judged::Judged;
use width::fit_width;

use crate::cloud::CloudIndex;
use crate::coverage::{SampleClass, SampleOutcome};
use crate::m3c2::streaming::CoreResult;
use crate::verdict::COVERAGE_FACTOR;
use asbuilt_protocol::{RegionFinding, StationFindings};

/// What findings are drawn with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FindingParams {
    /// |d| beyond this is out of tolerance, metres.
    pub tolerance: f64,
    /// Layer height, metres; without it there are no per-layer rows.
    pub layer_height: Option<f64>,
    /// Height printed so far, metres; NaN when unknown (no top row then).
    pub printed_height: f64,
    /// Spacing of the design samples, metres.
    pub spacing: f64,
    /// M3C2 cylinder radius, metres.
    pub radius: f64,
    /// Regions and missing areas with fewer samples are noise.
    pub min_region_samples: usize,
    /// Coverage's threshold, metres: a coherent surface farther than this along the normal is
    /// excess or deficit, not missing material.
    pub coverage_threshold: f64,
    /// Missing areas smaller than this are left out, m²: a ledge that sticks out shadows a strip
    /// below it that the design says a station should see.
    pub min_missing_area_m2: f64,
}

/// One layer band's side faces: the row the agent publishes, one definition for both (NaN
/// where the sides seen cannot separate width and shift; read it with `width()`, `shift_xy()`).
pub use asbuilt_protocol::LayerFinding as LayerRow;

/// The top of the print against the printed height.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TopRow {
    /// Top of the print minus the printed height it should have, metres.
    pub height_deviation: f64,
    /// Design samples on the top with an M3C2 distance.
    pub samples: u32,
    /// The deviation's expanded uncertainty (k = 2), metres.
    pub uncertainty: f64,
}

/// Excess (d > tolerance), deficit (d < −tolerance) or missing material: the kind the agent's
/// `StationFindings` carry, one definition for both.
pub use asbuilt_protocol::RegionKind;

/// A connected area of the design out of tolerance, or missing. Design frame, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Region {
    /// Excess, deficit or missing.
    pub kind: RegionKind,
    /// Design samples in it.
    pub samples: u32,
    /// The design surface it covers, m².
    pub area_m2: f64,
    /// The mean position of its samples.
    pub centroid: Point3<f64>,
    /// The lower corner of its bounding box.
    pub min: Point3<f64>,
    /// The upper corner of its bounding box.
    pub max: Point3<f64>,
    /// Largest |distance| with its sign, metres; NaN for missing material.
    pub peak: f64,
    /// Where the peak was measured.
    pub peak_at: Point3<f64>,
    /// Mean signed distance; NaN for missing material.
    pub mean: f64,
    /// Layer bands it spans, when the layer height is known.
    pub layers: Option<(u32, u32)>,
    /// The peak's expanded uncertainty (k = 2), metres; NaN for missing material.
    pub peak_uncertainty: f64,
    /// The area's expanded uncertainty (k = 2), m².
    pub area_uncertainty: f64,
}

/// What a scan layer's stations show: layer bands, the top, areas out of tolerance, missing
/// material.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Findings {
    /// Per layer band, lowest first.
    pub layers: Vec<LayerRow>,
    /// The top, when it was seen.
    pub top: Option<TopRow>,
    /// Out-of-tolerance areas, largest first.
    pub regions: Vec<Region>,
    /// Missing material, largest first.
    pub missing: Vec<Region>,
    /// Each design sample's judgement, by sample number: what a map may paint.
    pub judged: Vec<Judged>,
}

/// Side faces: the normal within 30° of horizontal.
const SIDE_MAX_NZ: f64 = 0.5;
/// The cap: the normal within 25° of up.
const TOP_MIN_NZ: f64 = 0.9;

/// How much the mean of core points' distances varies beyond what their count says: each scan
/// point lands in about `π r²` over a sample's area of cylinders, so that many neighbouring
/// core points share their points.
fn overlap(p: &FindingParams, area_per_sample: f64) -> f64 {
    (std::f64::consts::PI * p.radius * p.radius / area_per_sample.max(f64::MIN_POSITIVE)).max(1.0)
}

/// `sharp_edges`: the design's, from [`crate::Design::sharp_edges`]; `pose_sigma`: the stations'
/// position σ per axis, metres (0 when unknown).
pub fn find(
    m3c2: &[CoreResult],
    coverage: &[SampleOutcome],
    sharp_edges: &[[Point3<f64>; 2]],
    area_per_sample: f64,
    p: &FindingParams,
    pose_sigma: f64,
) -> Findings {
    let pose = pose_of(pose_sigma);
    let shared = overlap(p, area_per_sample);
    let samples = sample_count(m3c2, coverage);
    let usable = usable_core_points(m3c2, coverage, sharp_edges, samples, reach(p, pose));
    let band_of = |z: f64| p.layer_height.map(|h| (z / h).floor().max(0.0) as u32);
    let mut out = Findings {
        layers: p
            .layer_height
            .map_or_else(Vec::new, |h| layer_rows(m3c2, &usable, h, (shared, pose))),
        top: top_row(m3c2, &usable, p, (shared, pose)),
        ..Findings::default()
    };
    let link = link(p);
    for (kind, sign) in [(RegionKind::Excess, 1.0), (RegionKind::Deficit, -1.0)] {
        let members: Vec<usize> = (0..m3c2.len())
            .filter(|&i| {
                usable[i]
                    && m3c2[i].significant
                    && sign * m3c2[i].distance.unwrap_or(0.0) > p.tolerance
            })
            .collect();
        for ids in components_of(m3c2, &members, link, p.min_region_samples) {
            out.regions.push(out_of_tolerance(
                kind,
                m3c2,
                &ids,
                (area_per_sample, pose),
                &band_of,
            ));
        }
    }
    let missing = missing_areas(m3c2, coverage, samples, area_per_sample, p);
    for group in &missing {
        let pts: Vec<Point3<f64>> = group.iter().map(|g| g.1).collect();
        out.missing
            .push(region(RegionKind::Missing, &pts, area_per_sample, &band_of));
    }
    out.judged = judged::judgement(samples, m3c2, &usable, &missing);
    out.regions.sort_by_key(|r| std::cmp::Reverse(r.samples));
    out.missing.sort_by_key(|r| std::cmp::Reverse(r.samples));
    out
}

/// A station's position σ as the findings take it: 0 when unknown.
fn pose_of(pose_sigma: f64) -> f64 {
    if pose_sigma.is_finite() {
        pose_sigma.max(0.0)
    } else {
        0.0
    }
}

/// Design samples M3C2 and coverage were built from: their sample indices line them up.
fn sample_count(m3c2: &[CoreResult], coverage: &[SampleOutcome]) -> usize {
    m3c2.iter()
        .map(|r| r.sample)
        .chain(coverage.iter().map(|o| o.sample))
        .max()
        .map_or(0, |m| m as usize + 1)
}

/// How near two samples must be to belong to one region: samples are random, so a thin strip
/// (the top of a sagging layer) needs a generous link to stay one region.
fn link(p: &FindingParams) -> f64 {
    4.0 * p.spacing
}

/// How far from a sharp edge a core point's cylinder must stay: a station's pose error moves the
/// face beyond an edge by up to about 3σ, and a cylinder that near the edge takes in its points
/// and reads a deviation that is not in the print.
fn reach(p: &FindingParams, pose: f64) -> f64 {
    p.radius + 3.0 * pose
}

/// The core points whose distance counts: with a distance, away from the design's sharp
/// edges, and on a sample a station could see (a cylinder on a face no station faces holds
/// nothing but stray points: mixed pixels behind an edge).
fn usable_core_points(
    m3c2: &[CoreResult],
    coverage: &[SampleOutcome],
    sharp_edges: &[[Point3<f64>; 2]],
    samples: usize,
    radius: f64,
) -> Vec<bool> {
    let mut seen = vec![coverage.is_empty(); samples];
    for o in coverage {
        seen[o.sample as usize] = matches!(o.class, SampleClass::Observed | SampleClass::Missing);
    }
    let mut usable = off_edges(m3c2, sharp_edges, radius);
    for (c, r) in usable.iter_mut().zip(m3c2) {
        *c &= seen[r.sample as usize] && r.distance.is_some();
    }
    usable
}

/// Per layer band of height `h`, lowest first: the mean distance on its sides and the width
/// and shift fitted to them, with their U from the fit (its variance times `shared`) and the
/// pose σ.
fn layer_rows(
    m3c2: &[CoreResult],
    usable: &[bool],
    h: f64,
    (shared, pose): (f64, f64),
) -> Vec<LayerRow> {
    let mut bands: FxHashMap<u32, Vec<usize>> = FxHashMap::default();
    for (i, r) in m3c2.iter().enumerate() {
        if usable[i] && r.normal.z.abs() < SIDE_MAX_NZ {
            bands
                .entry((r.position.z / h).floor().max(0.0) as u32)
                .or_default()
                .push(i);
        }
    }
    let mut keys: Vec<u32> = bands.keys().copied().collect();
    keys.sort_unstable();
    keys.into_iter()
        .map(|layer| {
            let idx = &bands[&layer];
            let d = |i: usize| m3c2[i].distance.unwrap_or(0.0);
            let mean = idx.iter().map(|&i| d(i)).sum::<f64>() / idx.len() as f64;
            let fit = fit_width(m3c2, idx);
            let k = COVERAGE_FACTOR;
            LayerRow {
                layer,
                z_min: layer as f64 * h,
                z_max: (layer + 1) as f64 * h,
                samples: idx.len() as u32,
                mean,
                width_deviation: fit.map_or(f64::NAN, |f| 2.0 * f.half_width),
                shift: fit.map_or([f64::NAN; 2], |f| f.shift),
                width_uncertainty: fit.map_or(f64::NAN, |f| {
                    k * (4.0 * shared * f.variance[0] + 2.0 * pose * pose).sqrt()
                }),
                shift_uncertainty: fit.map_or(f64::NAN, |f| {
                    k * (shared * f.variance[1].max(f.variance[2]) + 0.5 * pose * pose).sqrt()
                }),
                width_fit_uncertainty: fit
                    .map_or(f64::NAN, |f| k * (4.0 * shared * f.variance[0]).sqrt()),
                width_verdict: asbuilt_protocol::SurveyVerdict::NotJudged,
                shift_verdict: asbuilt_protocol::SurveyVerdict::NotJudged,
            }
        })
        .collect()
}

/// The top of the print against the printed height: the mean distance on the cap within half a
/// band of it; `None` without a printed height or samples there.
fn top_row(
    m3c2: &[CoreResult],
    usable: &[bool],
    p: &FindingParams,
    (shared, pose): (f64, f64),
) -> Option<TopRow> {
    if !p.printed_height.is_finite() {
        return None;
    }
    let band = p.layer_height.unwrap_or(p.spacing).max(p.spacing);
    let top: Vec<f64> = (0..m3c2.len())
        .filter(|&i| {
            usable[i]
                && m3c2[i].normal.z > TOP_MIN_NZ
                && (m3c2[i].position.z - p.printed_height).abs() < 0.5 * band
        })
        .filter_map(|i| m3c2[i].distance)
        .collect();
    (!top.is_empty()).then(|| {
        let n = top.len() as f64;
        let mean = top.iter().sum::<f64>() / n;
        let spread = if top.len() > 1 {
            top.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0)
        } else {
            0.0
        };
        TopRow {
            height_deviation: mean,
            samples: top.len() as u32,
            uncertainty: COVERAGE_FACTOR * (shared * spread / n + pose * pose).sqrt(),
        }
    })
}

/// The connected groups (within `link`) of core points `members`, as core point indices, that
/// hold at least `min` of them.
fn components_of(m3c2: &[CoreResult], members: &[usize], link: f64, min: usize) -> Vec<Vec<usize>> {
    let pos: Vec<Point3<f64>> = members.iter().map(|&i| m3c2[i].position).collect();
    components(&pos, link)
        .into_iter()
        .filter(|g| g.len() >= min)
        .map(|g| g.iter().map(|&k| members[k]).collect())
        .collect()
}

/// An area out of tolerance from its core points `ids`: extent, peak and mean distance.
fn out_of_tolerance(
    kind: RegionKind,
    m3c2: &[CoreResult],
    ids: &[usize],
    (area_per_sample, pose): (f64, f64),
    band_of: &dyn Fn(f64) -> Option<u32>,
) -> Region {
    let d: Vec<f64> = ids
        .iter()
        .map(|&i| m3c2[i].distance.unwrap_or(0.0))
        .collect();
    let peak_k = (0..d.len())
        .max_by(|&a, &b| d[a].abs().total_cmp(&d[b].abs()))
        .unwrap_or(0);
    let pts: Vec<Point3<f64>> = ids.iter().map(|&i| m3c2[i].position).collect();
    let mut r = region(kind, &pts, area_per_sample, band_of);
    r.peak = d[peak_k];
    r.peak_at = pts[peak_k];
    // The peak is one cylinder's mean: its points' spread over their count, and its station.
    let c = &m3c2[ids[peak_k]];
    let mean_var = c.spread.map_or(0.0, |s| s * s / c.count.max(1) as f64);
    r.peak_uncertainty = COVERAGE_FACTOR * (mean_var + pose * pose).sqrt();
    r.mean = d.iter().sum::<f64>() / d.len() as f64;
    r
}

/// The positions of the samples missing material. Coverage calls a sample missing when no scan
/// point lies within its threshold `t`. Where M3C2 finds a coherent surface beyond the
/// threshold, the material is there, only out of place (excess buries the sample,
/// under-extrusion hides it inside): that is a region, not missing material. A gap leaves at
/// most a mix of its neighbours' and its floor's points, with a spread no surface has.
fn missing_positions(
    m3c2: &[CoreResult],
    coverage: &[SampleOutcome],
    samples: usize,
    t: f64,
) -> Vec<(u32, Point3<f64>)> {
    let mut m3c2_of = vec![None; samples];
    for (i, r) in m3c2.iter().enumerate() {
        m3c2_of[r.sample as usize] = Some(i);
    }
    let out_of_place = |o: &SampleOutcome| {
        m3c2_of[o.sample as usize].is_some_and(|i: usize| {
            let r = &m3c2[i];
            match (r.distance, r.spread) {
                (Some(d), Some(s)) if r.count >= 5 => d > t || (d < -t && s < t),
                _ => false,
            }
        })
    };
    coverage
        .iter()
        .filter(|o| o.class == SampleClass::Missing && !out_of_place(o))
        .map(|o| (o.sample, o.position))
        .collect()
}

/// The missing areas the findings count: groups of samples where material is missing, each of
/// at least the smallest area that counts; each sample with its number and place.
fn missing_areas(
    m3c2: &[CoreResult],
    coverage: &[SampleOutcome],
    samples: usize,
    area_per_sample: f64,
    p: &FindingParams,
) -> Vec<Vec<(u32, Point3<f64>)>> {
    let missing = missing_positions(m3c2, coverage, samples, p.coverage_threshold);
    let min_missing = p
        .min_region_samples
        .max((p.min_missing_area_m2 / area_per_sample).ceil() as usize);
    let places: Vec<Point3<f64>> = missing.iter().map(|m| m.1).collect();
    components(&places, link(p))
        .into_iter()
        .filter(|group| group.len() >= min_missing)
        .map(|group| group.iter().map(|&g| missing[g]).collect())
        .collect()
}

fn region(
    kind: RegionKind,
    pts: &[Point3<f64>],
    area_per_sample: f64,
    band_of: &dyn Fn(f64) -> Option<u32>,
) -> Region {
    let mut min = pts[0];
    let mut max = pts[0];
    let mut sum = Vector3::zeros();
    for p in pts {
        min = min.inf(p);
        max = max.sup(p);
        sum += p.coords;
    }
    // Edge samples of a compact area of n: about its perimeter, 2√(πn), at most n.
    let n = pts.len() as f64;
    let edge = (2.0 * (std::f64::consts::PI * n).sqrt()).min(n);
    Region {
        kind,
        samples: pts.len() as u32,
        area_m2: n * area_per_sample,
        area_uncertainty: COVERAGE_FACTOR * area_per_sample * (edge / 12.0).sqrt(),
        peak_uncertainty: f64::NAN,
        centroid: Point3::from(sum / pts.len() as f64),
        min,
        max,
        peak: f64::NAN,
        peak_at: Point3::from(sum / pts.len() as f64),
        mean: f64::NAN,
        layers: band_of(min.z).zip(band_of(max.z)),
    }
}

/// Samples whose cylinder sees only their own face: farther than `radius` (and a millimetre)
/// from every sharp edge.
fn off_edges(m3c2: &[CoreResult], edges: &[[Point3<f64>; 2]], radius: f64) -> Vec<bool> {
    use rayon::prelude::*;
    let r = radius + 0.001;
    // Edges bucketed by the cells their bounding boxes (grown by r) touch.
    let cell = (4.0 * r).max(1e-6);
    let key = |v: f64| (v / cell).floor() as i64;
    let mut cells: FxHashMap<[i64; 3], Vec<u32>> = FxHashMap::default();
    for (k, e) in edges.iter().enumerate() {
        let lo = e[0].inf(&e[1]).map(|v| key(v - r));
        let hi = e[0].sup(&e[1]).map(|v| key(v + r));
        let span = (hi - lo).map(|d| d + 1);
        if span.x * span.y * span.z > 1_000_000 {
            // A very long edge against tiny cells: check it everywhere.
            cells.entry([i64::MIN; 3]).or_default().push(k as u32);
            continue;
        }
        for x in lo.x..=hi.x {
            for y in lo.y..=hi.y {
                for z in lo.z..=hi.z {
                    cells.entry([x, y, z]).or_default().push(k as u32);
                }
            }
        }
    }
    let everywhere = cells.get(&[i64::MIN; 3]).cloned().unwrap_or_default();
    m3c2.par_iter()
        .map(|c| {
            let p = c.position;
            let near = cells.get(&[key(p.x), key(p.y), key(p.z)]);
            !near
                .into_iter()
                .flatten()
                .chain(&everywhere)
                .any(|&k| segment_distance(&p, &edges[k as usize]) <= r)
        })
        .collect()
}

fn segment_distance(p: &Point3<f64>, e: &[Point3<f64>; 2]) -> f64 {
    let d = e[1] - e[0];
    let t = ((p - e[0]).dot(&d) / d.norm_squared().max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
    (p - (e[0] + d * t)).norm()
}

/// Connected groups of points closer than `link`, as indices into `pts`.
fn components(pts: &[Point3<f64>], link: f64) -> Vec<Vec<usize>> {
    let Ok(cloud) = CloudIndex::new(pts) else {
        // Empty: no groups. (Design samples are finite, and far fewer than 2³² of them.)
        return Vec::new();
    };
    let mut parent: Vec<usize> = (0..pts.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut near = Vec::new();
    for (i, p) in pts.iter().enumerate() {
        cloud.within(p, link, &mut near);
        for &j in &near {
            let (a, b) = (root(&mut parent, i), root(&mut parent, j as usize));
            if a != b {
                parent[a.max(b)] = a.min(b);
            }
        }
    }
    let mut groups: FxHashMap<usize, Vec<usize>> = FxHashMap::default();
    for i in 0..pts.len() {
        let r = root(&mut parent, i);
        groups.entry(r).or_default().push(i);
    }
    let mut out: Vec<Vec<usize>> = groups.into_values().collect();
    out.sort_by_key(|g| g[0]);
    out
}

impl Findings {
    /// The findings as the agent publishes them: of job `job`'s scan layer, after station
    /// `station`, the `stations`-th of that layer. Rows past the message's capacity are
    /// counted in `truncated`.
    pub fn to_message(
        &self,
        (job, station): (u64, u32),
        stations: u32,
        tolerance: f64,
        (layer, printed_height): (u32, f64),
    ) -> StationFindings {
        let mut m = StationFindings::new(job, station);
        m.layer = layer;
        m.printed_height = printed_height;
        m.tolerance = tolerance;
        m.stations = stations;
        if let Some(t) = self.top {
            m.top_height_deviation = t.height_deviation;
            m.top_samples = t.samples;
            m.top_uncertainty = t.uncertainty;
        }
        for &row in &self.layers {
            if m.layers.push(row).is_err() {
                m.truncated += 1;
            }
        }
        for r in &self.regions {
            if m.regions.push(region_message(r)).is_err() {
                m.truncated += 1;
            }
        }
        for r in &self.missing {
            if m.missing.push(region_message(r)).is_err() {
                m.truncated += 1;
            }
        }
        m
    }
}

/// Each finding of `m` held to `limits` by their decision rule, as the report holds them: a
/// band's width and shift at its band, the top at the scan layer's last layer, an area's peak
/// (a missing area's size) over the bands it spans. The agent sends them so judged.
pub fn judge_message(m: &mut StationFindings, limits: &crate::verdict::Limits) {
    use crate::verdict::LimitKind;
    let judge = |kind, value: f64, u: f64, layers| {
        if value.is_finite() {
            limits.judge(kind, (value, u), layers).0.into()
        } else {
            asbuilt_protocol::SurveyVerdict::NotJudged
        }
    };
    for r in &mut m.layers {
        let band = Some((r.layer, r.layer));
        r.width_verdict = judge(
            LimitKind::Width,
            r.width_deviation,
            r.width_uncertainty,
            band,
        );
        let shift = r.shift[0].hypot(r.shift[1]);
        r.shift_verdict = judge(LimitKind::Position, shift, r.shift_uncertainty, band);
    }
    m.top_verdict = judge(
        LimitKind::TopHeight,
        m.top_height_deviation,
        m.top_uncertainty,
        Some((m.layer, m.layer)),
    );
    for g in m.regions.iter_mut().chain(m.missing.iter_mut()) {
        let layers = (g.layers[0] != u32::MAX).then_some((g.layers[0], g.layers[1]));
        g.verdict = if g.kind == RegionKind::Missing {
            judge(
                LimitKind::MissingArea,
                g.area_m2,
                g.area_uncertainty,
                layers,
            )
        } else {
            judge(LimitKind::Surface, g.peak, g.peak_uncertainty, layers)
        };
    }
}

fn region_message(r: &Region) -> RegionFinding {
    RegionFinding {
        kind: r.kind,
        samples: r.samples,
        area_m2: r.area_m2,
        centroid: r.centroid.into(),
        min: r.min.into(),
        max: r.max.into(),
        peak: r.peak,
        peak_at: r.peak_at.into(),
        peak_uncertainty: r.peak_uncertainty,
        area_uncertainty: r.area_uncertainty,
        verdict: asbuilt_protocol::SurveyVerdict::NotJudged,
        mean: r.mean,
        layers: r.layers.map_or([u32::MAX; 2], |(a, b)| [a, b]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Core results on the two long faces of a wall (normals ±y), with distances from a model.
    fn wall_results(d: impl Fn(&Point3<f64>, &Vector3<f64>) -> f64) -> Vec<CoreResult> {
        let mut out = Vec::new();
        for side in [-1.0, 1.0] {
            for i in 0..200 {
                for k in 0..20 {
                    let p = Point3::new(-1.0 + i as f64 * 0.01, side * 0.0867, k as f64 * 0.01);
                    let n = Vector3::new(0.0, side, 0.0);
                    out.push(CoreResult {
                        sample: out.len() as u32,
                        position: p,
                        normal: n,
                        distance: Some(d(&p, &n)),
                        spread: Some(0.0005),
                        count: 50,
                        lod95: Some(0.002),
                        significant: d(&p, &n).abs() > 0.002,
                    });
                }
            }
        }
        out
    }

    fn params() -> FindingParams {
        FindingParams {
            tolerance: 0.005,
            layer_height: Some(0.02),
            printed_height: f64::NAN,
            spacing: 0.01,
            radius: 0.005,
            min_region_samples: 3,
            coverage_threshold: 0.003,
            min_missing_area_m2: 0.0,
        }
    }

    #[test]
    fn width_and_shift_are_separated_per_layer() {
        // Layer 0: 8 mm wider; layer 1 (z 0.1..0.2 → bands 5..9): shifted 6 mm toward +y.
        let r = wall_results(|p, n| if p.z < 0.1 { 0.004 } else { 0.006 * n.y });
        let f = find(&r, &[], &[], 1e-4, &params(), 0.001);
        let row = |l: u32| f.layers.iter().find(|r| r.layer == l).unwrap();
        assert!((row(2).width().unwrap() - 0.008).abs() < 1e-9);
        assert!(row(2).shift_xy().unwrap()[1].abs() < 1e-9);
        assert!(row(7).width().unwrap().abs() < 1e-9);
        assert!((row(7).shift_xy().unwrap()[1] - 0.006).abs() < 1e-6);
    }

    /// A band's width and shift, each side seen by its own station whose pose is off by 1 mm σ
    /// and each core point's distance off by 0.5 mm σ: U against twice the spread over repeated
    /// scans, within 20 %; and the same for a bump's peak.
    #[test]
    fn width_shift_and_peak_uncertainty_match_a_monte_carlo() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (pose, noise) = (
            Normal::new(0.0, 0.001).unwrap(),
            Normal::new(0.0, 0.0005).unwrap(),
        );
        let (mut widths, mut shifts, mut peaks) = (Vec::new(), Vec::new(), Vec::new());
        let (mut uw, mut us, mut up) = (0.0, 0.0, 0.0);
        let runs = 200;
        for _ in 0..runs {
            let e = [pose.sample(&mut rng), pose.sample(&mut rng)];
            let mut r = wall_results(|p, n| {
                let d = (p - Point3::new(0.3, 0.0867, 0.1)).norm();
                let bump = if n.y > 0.0 && d < 0.05 {
                    0.012 * (1.0 - d / 0.05)
                } else {
                    0.0
                };
                bump + e[usize::from(n.y > 0.0)] * n.y
            });
            for c in &mut r {
                *c.distance.as_mut().unwrap() += noise.sample(&mut rng);
                c.spread = Some(0.0005 * (c.count as f64).sqrt());
            }
            let f = find(&r, &[], &[], 1e-4, &params(), 0.001);
            let row = f.layers.iter().find(|r| r.layer == 2).unwrap();
            widths.push(row.width_deviation);
            shifts.push(row.shift[1]);
            uw += row.width_uncertainty / runs as f64;
            us += row.shift_uncertainty / runs as f64;
            let bump = f
                .regions
                .iter()
                .find(|g| g.kind == RegionKind::Excess)
                .unwrap();
            peaks.push(bump.peak);
            up += bump.peak_uncertainty / runs as f64;
        }
        for (what, v, u) in [
            ("width", widths, uw),
            ("shift", shifts, us),
            ("peak", peaks, up),
        ] {
            let mc = 2.0 * crate::flatness::tests::spread(&v);
            assert!(
                (u - mc).abs() < 0.2 * mc,
                "{what}: U {:.3} mm against the Monte Carlo's {:.3} mm",
                u * 1e3,
                mc * 1e3
            );
        }
    }

    #[test]
    fn one_side_alone_gives_no_width() {
        let r: Vec<CoreResult> = wall_results(|_, _| 0.003)
            .into_iter()
            .filter(|c| c.normal.y > 0.0)
            .collect();
        let f = find(&r, &[], &[], 1e-4, &params(), 0.001);
        assert!(f.layers.iter().all(|l| l.width().is_none()));
    }

    #[test]
    fn a_bump_is_one_region_with_its_peak_and_extent() {
        let c = Point3::new(0.3, 0.0867, 0.1);
        let r = wall_results(|p, n| {
            let d = (p - c).norm();
            if n.y > 0.0 && d < 0.05 {
                0.012 * (1.0 - d / 0.05)
            } else {
                0.0
            }
        });
        let f = find(&r, &[], &[], 1e-4, &params(), 0.001);
        assert_eq!(f.regions.len(), 1, "{:?}", f.regions);
        let g = &f.regions[0];
        assert_eq!(g.kind, RegionKind::Excess);
        assert!((g.peak - 0.012).abs() < 1e-9 && (g.peak_at - c).norm() < 1e-9);
        // |d| > 5 mm within 0.05 · (1 − 5/12) of the centre.
        let reach = 0.05 * (1.0 - 5.0 / 12.0);
        let extent = g.max.x - g.min.x;
        assert!(
            extent <= 2.0 * reach && extent > 2.0 * reach - 0.02,
            "{g:?}"
        );
        // The fit of that band ignores the bump.
        let row = f.layers.iter().find(|r| r.layer == 5).unwrap();
        assert!(row.width().unwrap().abs() < 1e-9, "{row:?}");
    }

    #[test]
    fn samples_next_to_an_edge_are_left_out() {
        let r = wall_results(|_, _| -0.02);
        // The wall's vertical edges at x = 0.995: the samples at x = 0.99 are 5 mm from them.
        let edges = [-1.0, 1.0].map(|y| {
            [
                Point3::new(0.995, y * 0.0867, 0.0),
                Point3::new(0.995, y * 0.0867, 0.2),
            ]
        });
        let f = find(&r, &[], &edges, 1e-4, &params(), 0.001);
        let total: u32 = f.regions.iter().map(|g| g.samples).sum();
        assert_eq!(total, 2 * 200 * 20 - 2 * 20);
        assert!(f.regions.iter().all(|g| g.max.x < 0.985));
        // 7 mm from the edges: beyond the cylinder's 5 mm and a millimetre with exact poses,
        // within them and three pose σ of 1 mm.
        let edges = edges.map(|e| e.map(|p| Point3::new(0.997, p.y, p.z)));
        let samples = |sigma: f64| -> u32 {
            find(&r, &[], &edges, 1e-4, &params(), sigma)
                .regions
                .iter()
                .map(|g| g.samples)
                .sum()
        };
        assert_eq!(samples(0.0), 2 * 200 * 20);
        assert_eq!(samples(0.001), 2 * 200 * 20 - 2 * 20);
    }

    /// The maps' judgement is the findings': the samples next to an edge are not judged; of the
    /// samples coverage calls missing, only those of an area the findings count are missing.
    #[test]
    fn each_sample_is_judged_as_the_findings_judge_it() {
        let r = wall_results(|_, _| 0.0);
        let edges = [[
            Point3::new(0.995, -0.0867, 0.0),
            Point3::new(0.995, -0.0867, 0.2),
        ]];
        // Coverage: a 10 × 10 patch missing, and single missing samples along the top.
        let outcome = |c: &CoreResult, class| SampleOutcome {
            sample: c.sample,
            position: c.position,
            normal: c.normal,
            reverse_distance: None,
            class,
        };
        let patch = |c: &CoreResult| {
            c.normal.y > 0.0 && (-0.5..-0.405).contains(&c.position.x) && c.position.z < 0.095
        };
        let lone = |c: &CoreResult| c.position.z > 0.185 && c.sample % 200 == 19;
        let coverage: Vec<SampleOutcome> = r
            .iter()
            .map(|c| {
                let missing = patch(c) || lone(c);
                outcome(
                    c,
                    if missing {
                        SampleClass::Missing
                    } else {
                        SampleClass::Observed
                    },
                )
            })
            .collect();
        let mut p = params();
        p.min_region_samples = 5;
        let f = find(&r, &coverage, &edges, 1e-4, &p, 0.0);
        let j = &f.judged;
        let count = |k: Judged| j.iter().filter(|&&x| x == k).count() as u32;
        assert_eq!(f.missing.len(), 1);
        assert_eq!(count(Judged::Missing), f.missing[0].samples);
        assert_eq!(count(Judged::Missing), 100);
        for c in &r {
            let want = if patch(c) {
                Judged::Missing
            } else if c.normal.y < 0.0 && c.position.x > 0.985 {
                Judged::NotJudged
            } else {
                Judged::Measured
            };
            assert_eq!(j[c.sample as usize], want, "{}", c.position);
        }
    }
}
