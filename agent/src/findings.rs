//! Findings over each scan layer: the stations that scan the print at one printed height feed
//! one design-referenced M3C2 and one coverage state (per design sample, so memory grows with
//! the design), and every station's close turns the state so far into [`StationFindings`].
//!
//! A scan layer's stations are scanned one after the other; a station that starts sending while
//! another of its scan layer still sends is left out of the findings (and says so), because the
//! per-station state is shared.
//!
//! A station sent again straight after it closed (the cell's next attempt after an incomplete
//! report, or a cell process started again that sends it anew) replaces what its attempt before
//! added: the scan layer keeps its state from before the last station closed, and goes back to
//! it when that station begins again. Without this, the points an incomplete attempt got
//! through would count twice, and the findings (and the advice drawn from them) would differ
//! from a run where the attempt was complete the first time.

use std::sync::Arc;

use asbuilt_core::coverage::Viewpoint;
use asbuilt_core::printed::PrintedDesign;
use asbuilt_core::profiler::SweepParams;
use asbuilt_core::sampling::DesignSamples;
use asbuilt_core::scan_layer::{SampleState, ScanLayer, ScanLayerState, defaults};
use asbuilt_protocol::{DeviationFlags, PointDeviation, StationFindings, StationReport};
use nalgebra::{Isometry3, Point3};

use crate::config::FindingsConfig;
use crate::{info, warn};

type StationKey = (u64, u32);

/// Scan layers kept at once: the current one and the one before, for a late station.
const EPOCHS: usize = 2;

/// One scan layer's findings state (core's [`ScanLayer`]) and who feeds it.
pub(crate) struct Epoch {
    job: u64,
    design: Arc<PrintedDesign>,
    layer: ScanLayer,
    /// The station sending now.
    active: Option<u32>,
    /// The last station closed and the state from before it closed, until another station
    /// begins: that station begun again goes back to it.
    before_last: Option<(u32, ScanLayerState)>,
}

impl Epoch {
    fn is(&self, job: u64, design: &Arc<PrintedDesign>) -> bool {
        self.job == job && Arc::ptr_eq(&self.design, design)
    }
}

/// The agent's findings: each scan layer's design samples, fed with every station's points,
/// turned into [`asbuilt_protocol::StationFindings`] after each report.
pub struct FindingsStage {
    maker: EpochMaker,
    epochs: Vec<Epoch>,
    /// Design-frame points of the chunk being ingested, sized once for the largest chunk.
    scratch: Vec<Point3<f64>>,
    /// Keep every design sample's state with the findings (a reader drawing maps); the live
    /// agent does not.
    keep_samples: bool,
    samples: Vec<SampleState>,
    /// The crew's limits and decision rule each finding is judged by before it is sent.
    limits: asbuilt_core::verdict::Limits,
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
    /// The scan layer's state of `job` over `design`: its design samples, M3C2 and coverage.
    /// With a `floor` (a line profiler's pass) only the samples from that height up are kept:
    /// nothing lower is in the profiler's range, and the state stays the same size however tall
    /// the print grows.
    pub(crate) fn make(
        &self,
        job: u64,
        design: &Arc<PrintedDesign>,
        floor: Option<f64>,
    ) -> Option<Epoch> {
        let started = std::time::Instant::now();
        let params = self
            .config
            .scan_layer(self.tolerance, self.max_depth, design.height);
        let made =
            DesignSamples::generate(design.design(), self.config.spacing, defaults::SAMPLE_SEED)
                .map_err(|e| e.to_string())
                .and_then(|mut samples| {
                    if let Some(z) = floor {
                        samples.retain_from(z);
                    }
                    ScanLayer::new(&samples, design.sharp_edges().to_vec(), params)
                        .map_err(|e| e.to_string())
                });
        match made {
            Ok(layer) => {
                info!(
                    "findings: scan layer at {} of job {job}: {} design samples{}, {:.1} MB, \
                     ready in {:.2} s",
                    height_text(design.height),
                    layer.samples(),
                    floor.map_or(String::new(), |z| format!(" from {z:.3} m up")),
                    layer.bytes() as f64 / 1e6,
                    started.elapsed().as_secs_f64()
                );
                Some(Epoch {
                    job,
                    design: design.clone(),
                    layer,
                    active: None,
                    before_last: None,
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
    /// A stage for `config`; the scratch buffer is sized once for `max_points_per_chunk`.
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
            keep_samples: false,
            samples: Vec::new(),
            limits: asbuilt_core::verdict::Limits::from_tolerance(tolerance),
        }
    }

    /// Judges the findings by `limits` (the crew's, with the job's decision rule) instead of
    /// the tolerance's for every kind.
    pub fn judged_by(mut self, limits: asbuilt_core::verdict::Limits) -> Self {
        self.limits = limits;
        self
    }

    /// Keeps the design samples' states of the latest findings, for [`FindingsStage::samples`].
    pub fn keeping_samples(mut self) -> Self {
        self.keep_samples = true;
        self
    }

    /// The design samples' states behind the latest findings `end` returned (empty unless
    /// [`FindingsStage::keeping_samples`]).
    pub fn samples(&self) -> &[SampleState] {
        &self.samples
    }

    /// Forgets the scan layers of `job`: a new print under its number gathers afresh.
    pub fn forget_job(&mut self, job: u64) {
        self.epochs.retain(|e| e.job != job);
    }

    /// A station starts sending points compared with `design`. False when it is left out.
    /// `floor`: a pass's, as [`EpochMaker::make`] takes it.
    pub fn begin(
        &mut self,
        key: StationKey,
        design: &Arc<PrintedDesign>,
        floor: Option<f64>,
    ) -> bool {
        let i = match self.epochs.iter().position(|e| e.is(key.0, design)) {
            Some(i) => i,
            // Made here only when the printed height was not prepared off the loop.
            None => match self.maker.make(key.0, design, floor) {
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
                if let Some((station, before)) = e.before_last.take()
                    && station == key.1
                {
                    // Same samples, same methods: the state always fits.
                    e.layer.restore(&before);
                    info!(
                        "job {} station {}: sent again; what its attempt before added to the \
                         findings of its scan layer is taken back",
                        key.0, key.1
                    );
                }
                e.active = Some(key.1);
                e.layer.begin_station();
                true
            }
        }
    }

    /// What the scan layer of `job` over `design` gathered from its closed stations, when it is
    /// kept.
    pub fn layer_state(&self, job: u64, design: &Arc<PrintedDesign>) -> Option<ScanLayerState> {
        self.epochs
            .iter()
            .find(|e| e.is(job, design))
            .map(|e| e.layer.state())
    }

    /// The findings of the scan layer of `job` over `design` as they stood after the station of
    /// `report` closed (its last station): what that station's close drew, drawn again.
    pub fn findings_after(
        &self,
        design: &Arc<PrintedDesign>,
        report: &StationReport,
    ) -> Option<StationFindings> {
        let e = self.epochs.iter().find(|e| e.is(report.job, design))?;
        let sigma = if report.position_sigma.is_finite() {
            report.position_sigma
        } else {
            0.0
        };
        let (f, _) = e.layer.measure(sigma, &*e.design, false)?;
        let mut m = f.to_message(
            (report.job, report.station),
            e.layer.stations(),
            self.maker.tolerance,
            (report.layer, report.printed_height),
        );
        asbuilt_core::findings::judge_message(&mut m, &self.limits);
        Some(m)
    }

    /// Takes up a scan layer of `job` over `design` from a state its agent recorded; false
    /// when the state does not fit (another design or other settings). `last` is the station
    /// whose close that state followed and the state recorded before it (`None`: it was the
    /// scan layer's first), so that the station sent again replaces what it added. `floor`: a
    /// pass's, as [`EpochMaker::make`] takes it.
    pub fn restore(
        &mut self,
        job: u64,
        design: &Arc<PrintedDesign>,
        state: &ScanLayerState,
        last: Option<(u32, Option<&ScanLayerState>)>,
        floor: Option<f64>,
    ) -> bool {
        let Some(mut epoch) = self.maker.make(job, design, floor) else {
            return false;
        };
        let before_last = match last {
            Some((station, Some(before))) => {
                if !epoch.layer.restore(before) {
                    return false;
                }
                Some((station, epoch.layer.state()))
            }
            Some((station, None)) => Some((station, epoch.layer.state())),
            None => None,
        };
        if !epoch.layer.restore(state) {
            return false;
        }
        epoch.before_last = before_last;
        self.epochs.retain(|e| !e.is(job, design));
        self.keep(epoch);
        true
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
        e.layer.ingest(&self.scratch);
    }

    /// Leaves out what a station sent so far: it was interrupted, and its next attempt sends
    /// it all again.
    pub fn abandon(&mut self, key: StationKey) {
        if let Some(e) = active(&mut self.epochs, key) {
            e.active = None;
        }
    }

    /// A line profiler's next profile of a station that began, taken from `sensor`
    /// (`T_design_sensor`) with the field of view `params`.
    pub fn sweep(&mut self, key: StationKey, sensor: &Isometry3<f64>, params: SweepParams) {
        if let Some(e) = active(&mut self.epochs, key) {
            e.layer.sweep(sensor, params, &*e.design);
        }
    }

    /// Closes a station that saw the design from `view` and returns the findings of its scan
    /// layer so far; `None` when the station was not part of any (left out, or never began).
    pub fn end(
        &mut self,
        key: StationKey,
        view: Option<Viewpoint>,
        report: &StationReport,
    ) -> Option<StationFindings> {
        let tolerance = self.maker.tolerance;
        let e = active(&mut self.epochs, key)?;
        e.active = None;
        let Some(view) = view else {
            // Without a pose the points never came; nothing to add.
            return None;
        };
        let sigma = if report.position_sigma.is_finite() {
            report.position_sigma
        } else {
            0.0
        };
        e.before_last = Some((key.1, e.layer.state()));
        e.layer.end_station(view, sigma, &*e.design);
        let (f, samples) = e.layer.measure(sigma, &*e.design, self.keep_samples)?;
        self.samples = samples;
        let mut m = f.to_message(
            key,
            e.layer.stations(),
            tolerance,
            (report.layer, report.printed_height),
        );
        asbuilt_core::findings::judge_message(&mut m, &self.limits);
        Some(m)
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
