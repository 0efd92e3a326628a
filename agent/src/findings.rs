//! Findings over each scan layer: the stations that scan the print at one printed height feed
//! one design-referenced M3C2 and one coverage state (per design sample, so memory grows with
//! the design), and every station's close turns the state so far into [`StationFindings`].
//!
//! A scan layer's stations are scanned one after the other; a station that starts sending while
//! another of its scan layer still sends is left out of the findings (and says so), because the
//! per-station state is shared.

use std::sync::Arc;

use asbuilt_core::coverage::{Coverage, CoverageParams};
use asbuilt_core::findings::{self, FindingParams, Findings, Region};
use asbuilt_core::m3c2::streaming::{StreamingM3c2, StreamingParams};
use asbuilt_core::printed::PrintedDesign;
use asbuilt_core::sampling::DesignSamples;
use asbuilt_protocol::{
    DeviationFlags, LayerFinding, PointDeviation, RegionFinding, StationFindings, StationReport,
};
use nalgebra::Point3;

use crate::config::FindingsConfig;
use crate::{info, warn};

type StationKey = (u64, u32);

/// M3C2 cylinders with fewer points give a distance but never a significant change.
const MIN_POINTS: u32 = 5;
/// Scan layers kept at once: the current one and the one before, for a late station.
const EPOCHS: usize = 2;
const SAMPLE_SEED: u64 = 1;

/// One scan layer's findings state: its design samples, streaming M3C2 and coverage.
pub(crate) struct Epoch {
    job: u64,
    design: Arc<PrintedDesign>,
    /// Where M3C2 cylinders would average two faces.
    sharp_edges: Vec<[Point3<f64>; 2]>,
    m3c2: StreamingM3c2,
    coverage: Coverage,
    area_per_sample: f64,
    stations: u32,
    /// The station sending now.
    active: Option<u32>,
}

impl Epoch {
    fn is(&self, job: u64, design: &Arc<PrintedDesign>) -> bool {
        self.job == job && Arc::ptr_eq(&self.design, design)
    }
}

pub struct FindingsStage {
    maker: EpochMaker,
    epochs: Vec<Epoch>,
    /// Design-frame points of the chunk being ingested, sized once for the largest chunk.
    scratch: Vec<Point3<f64>>,
}

/// Makes a scan layer's state: design samples of the printed design, streaming M3C2 and
/// coverage over them. Cloned into the thread that prepares a printed height, so that this
/// work (tens of milliseconds on a large design) stays off the event loop.
#[derive(Clone)]
pub(crate) struct EpochMaker {
    config: FindingsConfig,
    tolerance: f64,
    max_depth: f64,
}

impl EpochMaker {
    pub(crate) fn make(&self, job: u64, design: &Arc<PrintedDesign>) -> Option<Epoch> {
        let c = &self.config;
        let started = std::time::Instant::now();
        let made = DesignSamples::generate(design.design(), c.spacing, SAMPLE_SEED)
            .map_err(|e| e.to_string())
            .and_then(|samples| {
                let m3c2 = StreamingM3c2::new(
                    &samples,
                    StreamingParams {
                        projection_diameter: c.projection_diameter(),
                        max_depth: self.max_depth,
                        min_points: MIN_POINTS,
                    },
                )
                .map_err(|e| e.to_string())?;
                let threshold = c.coverage_threshold(self.tolerance);
                let mut params = CoverageParams::with_threshold(threshold, 2.0 * threshold);
                params.max_incidence_deg = c.max_incidence_deg;
                // Lattice gaps are allowed up to the reach, twice the threshold.
                params.spacing = c.coverage_spacing();
                let coverage = Coverage::new(&samples, params).map_err(|e| e.to_string())?;
                Ok((samples.len(), samples.area_per_sample, m3c2, coverage))
            });
        match made {
            Ok((n, area_per_sample, m3c2, coverage)) => {
                info!(
                    "findings: scan layer at {} of job {job}: {n} design samples, {:.1} MB, ready \
                     in {:.2} s",
                    height_text(design.height),
                    (m3c2.bytes() + coverage.bytes()) as f64 / 1e6,
                    started.elapsed().as_secs_f64()
                );
                Some(Epoch {
                    job,
                    sharp_edges: design.sharp_edges().to_vec(),
                    design: design.clone(),
                    m3c2,
                    coverage,
                    area_per_sample,
                    stations: 0,
                    active: None,
                })
            }
            Err(e) => {
                warn!(
                    "findings: scan layer at {} of job {job} cannot be set up ({e}); no findings \
                     for it",
                    height_text(design.height)
                );
                None
            }
        }
    }
}

impl FindingsStage {
    pub fn new(
        config: FindingsConfig,
        tolerance: f64,
        max_distance: f64,
        max_points_per_chunk: usize,
    ) -> Self {
        Self {
            maker: EpochMaker {
                max_depth: config.max_depth.unwrap_or(max_distance),
                config,
                tolerance,
            },
            epochs: Vec::with_capacity(EPOCHS),
            scratch: Vec::with_capacity(max_points_per_chunk),
        }
    }

    /// A station starts sending points compared with `design`. False when it is left out.
    pub fn begin(&mut self, key: StationKey, design: &Arc<PrintedDesign>) -> bool {
        let i = match self.epochs.iter().position(|e| e.is(key.0, design)) {
            Some(i) => i,
            // Made here only when the printed height was not prepared off the loop.
            None => match self.maker.make(key.0, design) {
                Some(e) => self.keep(e),
                None => return false,
            },
        };
        let e = &mut self.epochs[i];
        match e.active {
            Some(other) if other != key.1 => {
                warn!(
                    "job {} station {}: starts while station {other} of the same scan layer still \
                     sends; its points are left out of the findings",
                    key.0, key.1
                );
                false
            }
            _ => {
                e.active = Some(key.1);
                e.m3c2.begin_station();
                e.coverage.begin_station();
                true
            }
        }
    }

    /// What makes a scan layer's state, for a thread that prepares a printed height.
    pub(crate) fn maker(&self) -> EpochMaker {
        self.maker.clone()
    }

    /// A scan layer's state made off the loop, kept for the stations that will compare with its
    /// design.
    pub(crate) fn adopt(&mut self, epoch: Epoch) {
        if !self.epochs.iter().any(|e| e.is(epoch.job, &epoch.design)) {
            self.keep(epoch);
        }
    }

    fn keep(&mut self, epoch: Epoch) -> usize {
        if self.epochs.len() == EPOCHS {
            self.epochs.remove(0);
        }
        self.epochs.push(epoch);
        self.epochs.len() - 1
    }

    /// A chunk's deviations (design-frame positions) of a station that began.
    pub fn ingest(&mut self, key: StationKey, devs: &[PointDeviation]) {
        let Some(e) = active(&mut self.epochs, key) else {
            return;
        };
        self.scratch.clear();
        self.scratch.extend(
            devs.iter()
                .filter(|d| !d.flags.contains(DeviationFlags::REJECTED))
                .map(|d| Point3::from(d.position))
                .filter(|p| p.coords.iter().all(|v| v.is_finite())),
        );
        e.m3c2.ingest(&self.scratch);
        e.coverage.ingest(&self.scratch);
    }

    /// Closes a station scanned from `origin` and returns the findings of its scan layer so
    /// far; `None` when the station was not part of any (left out, or never began).
    pub fn end(
        &mut self,
        key: StationKey,
        origin: Option<Point3<f64>>,
        report: &StationReport,
    ) -> Option<StationFindings> {
        let (tolerance, layer_height, spacing) = (
            self.maker.tolerance,
            self.maker.config.layer_height,
            self.maker.config.spacing,
        );
        let radius = 0.5 * self.maker.config.projection_diameter();
        let min_region_samples = self.maker.config.min_region_samples;
        let coverage_threshold = self.maker.config.coverage_threshold(tolerance);
        let min_missing_area_m2 = self.maker.config.min_missing_area_m2;
        let e = active(&mut self.epochs, key)?;
        e.active = None;
        let Some(origin) = origin else {
            // Without a pose the points never came; nothing to add.
            return None;
        };
        let sigma = if report.position_sigma.is_finite() {
            report.position_sigma
        } else {
            0.0
        };
        e.coverage.end_station(origin, &*e.design);
        e.m3c2.end_station(sigma);
        e.stations += 1;
        let f = findings::find(
            &e.m3c2.results(sigma),
            &e.coverage.outcomes(&*e.design),
            &e.sharp_edges,
            e.area_per_sample,
            &FindingParams {
                tolerance,
                layer_height,
                printed_height: e.design.height,
                spacing,
                radius,
                min_region_samples,
                coverage_threshold,
                min_missing_area_m2,
            },
        );
        Some(to_message(&f, key, e.stations, tolerance, report))
    }
}

/// The scan layer `key`'s station is sending to.
fn active(epochs: &mut [Epoch], key: StationKey) -> Option<&mut Epoch> {
    epochs
        .iter_mut()
        .find(|e| e.job == key.0 && e.active == Some(key.1))
}

fn height_text(h: f64) -> String {
    if h.is_finite() {
        format!("{:.3} m", h)
    } else {
        "full height".into()
    }
}

fn to_message(
    f: &Findings,
    key: StationKey,
    stations: u32,
    tolerance: f64,
    report: &StationReport,
) -> StationFindings {
    let mut m = StationFindings::new(key.0, key.1);
    m.layer = report.layer;
    m.printed_height = report.printed_height;
    m.tolerance = tolerance;
    m.stations = stations;
    if let Some(t) = f.top {
        m.top_height_deviation = t.height_deviation;
        m.top_samples = t.samples;
    }
    for r in &f.layers {
        let row = LayerFinding {
            layer: r.layer,
            z_min: r.z_min,
            z_max: r.z_max,
            samples: r.samples,
            mean: r.mean,
            width_deviation: r.width_deviation.unwrap_or(f64::NAN),
            shift: r.shift.unwrap_or([f64::NAN; 2]),
        };
        if m.layers.push(row).is_err() {
            m.truncated += 1;
        }
    }
    for r in &f.regions {
        if m.regions.push(region(r)).is_err() {
            m.truncated += 1;
        }
    }
    for r in &f.missing {
        if m.missing.push(region(r)).is_err() {
            m.truncated += 1;
        }
    }
    m
}

fn region(r: &Region) -> RegionFinding {
    RegionFinding {
        kind: r.kind,
        samples: r.samples,
        area_m2: r.area_m2,
        centroid: r.centroid.into(),
        min: r.min.into(),
        max: r.max.into(),
        peak: r.peak,
        peak_at: r.peak_at.into(),
        mean: r.mean,
        layers: r.layers.map_or([u32::MAX; 2], |(a, b)| [a, b]),
    }
}
