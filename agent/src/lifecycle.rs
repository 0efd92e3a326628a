//! Stations from begin to report: which chunks belong where, when a station may close, and what
//! is counted when something is wrong. No I/O: chunks come in through [`ChunkSource`] and
//! results go out through [`Outputs`], so the daemon feeds this from shared memory and the tests
//! feed it from plain vectors.
//!
//! Memory is fixed at start-up: `open_stations` slots, `pending_chunks` held chunks (held, not
//! copied: a held iceoryx2 sample stays in shared memory), a ring of recently closed stations.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use std::sync::Arc;

use asbuilt_core::frames::FrameChain;
use std::sync::mpsc;

use asbuilt_core::corrections::{CorrectionLimits, Corrector};
use asbuilt_core::layers::CutError;
use asbuilt_core::printed::{PrintedDesign, PrintedDesigns};
use asbuilt_core::scan_layer::ScanLayerState;
use asbuilt_core::station::{InspectParams, StationInspector, Tally};
use asbuilt_protocol::{
    AgentStatus, ChunkHeader, DeviationHeader, InputRejects, LayerCorrection, Message,
    PointDeviation, PoseSnapshot, RejectCounts, ScanPoint, StationEvent, StationEventKind,
    StationFindings, StationReport, StationStatus,
};

use crate::attempts::{ClosedStations, StationKey, attempt_of};
use crate::findings::FindingsStage;

use crate::sequence::{ChunkVerdict, SequenceTracker};
use crate::{info, warn};

/// A received scan chunk: a header and its points, wherever they live.
pub trait ChunkSource {
    /// The chunk's header.
    fn header(&self) -> &ChunkHeader;
    /// The chunk's points, scanner frame.
    fn points(&self) -> &[ScanPoint];
}

/// A chunk read back from a recording.
impl ChunkSource for (ChunkHeader, Vec<ScanPoint>) {
    fn header(&self) -> &ChunkHeader {
        &self.0
    }
    fn points(&self) -> &[ScanPoint] {
        &self.1
    }
}

/// Where results go.
pub trait Outputs {
    /// Publishes one deviation chunk of `n` entries: `fill` writes the entries into the buffer it
    /// is given (shared memory when there is one) and returns the chunk's header.
    fn deviations(
        &mut self,
        n: usize,
        fill: &mut dyn FnMut(&mut [PointDeviation]) -> DeviationHeader,
    );
    /// Publishes a station's report.
    fn report(&mut self, report: &StationReport);
    /// Everything a station's report was computed from, just before the report: a reader of a
    /// recording merges these into its overall statistics.
    fn tally(&mut self, _tally: &Tally) {}
    /// Findings of a station's scan layer, after its report (when `[findings]` is on).
    fn findings(&mut self, _findings: &StationFindings) {}
    /// Advice for the layers still to print, after the findings (when `[corrections]` is on).
    fn correction(&mut self, _correction: &LayerCorrection) {}
    /// The scan layer's flatness, dimensions and plumb so far, after a report (when
    /// `[tolerances]` names a standard).
    fn surface(&mut self, _surface: &asbuilt_protocol::SurfaceFindings) {}
    /// Whether [`Outputs::scan_layer_state`] is wanted (an agent that records for resuming).
    fn wants_scan_layer_state(&self) -> bool {
        false
    }
    /// The scan layer's state after the station of `report` closed, when wanted.
    fn scan_layer_state(
        &mut self,
        _report: &StationReport,
        _state: &asbuilt_core::scan_layer::ScanLayerState,
    ) {
    }
    /// The design samples' states behind `findings`, right after them, when the findings stage
    /// keeps them (a reader of a recording drawing maps).
    fn samples(
        &mut self,
        _findings: &StationFindings,
        _samples: &[asbuilt_core::scan_layer::SampleState],
    ) {
    }
}

/// Why a recorded scan layer state cannot be taken up (the resume replays the layer instead).
#[derive(Debug, thiserror::Error)]
pub enum RestoreError {
    /// The printed design at the state's height cannot be prepared.
    #[error("the printed design at its height cannot be prepared: {0}")]
    Design(#[from] asbuilt_core::printed::PrintedError),
    /// This agent's configuration has no findings to take the state up into.
    #[error("findings are off in this configuration")]
    FindingsOff,
    /// The state was made for another design or other `[findings]` settings.
    #[error("the recorded state does not fit this design and these [findings] settings")]
    DoesNotFit,
}

/// What bounds the lifecycle's memory and how long it waits.
#[derive(Debug, Clone, Copy)]
pub struct LifecycleLimits {
    /// Chunks with more points are rejected.
    pub max_points_per_chunk: usize,
    /// Chunks held while their station's pose has not arrived.
    pub pending_chunks: usize,
    /// Stations open at the same time.
    pub open_stations: usize,
    /// Time without a message after which an open station closes as timed out.
    pub station_timeout: Duration,
}

/// How many closed stations are remembered, to tell a late chunk from one of an unknown station.
const CLOSED_MEMORY: usize = 64;

/// How long a station that said it is done, with chunks missing, stays open while the queues are
/// empty. Its End travels on another service than its chunks, possibly from another process (the
/// robot controller while the scanner driver still sends): chunks sent just before it must not
/// arrive to a closed station and be lost. The event loop wakes at least every 250 ms, so an
/// incomplete station is reported within about half a second of its End.
pub const END_GRACE: Duration = Duration::from_millis(200);

struct OpenStation {
    key: StationKey,
    /// Which try at the station this is (1 the first).
    attempt: u16,
    begin: Option<StationEvent>,
    end: Option<StationEvent>,
    pose: Option<PoseSnapshot>,
    /// Sequence of a chunk flagged `last`.
    last_sequence: Option<u64>,
    /// When the scanner first said it is done (End event or a chunk flagged last).
    finished_at: Option<Instant>,
    inspector: StationInspector,
    /// The design as printed when this station scanned (the whole design until told).
    design: Arc<PrintedDesign>,
    /// The printed height whose design is being prepared for this station; its chunks wait.
    awaiting: Option<f64>,
    /// Whether the findings stage took this station (decided at its first chunk).
    findings: Option<bool>,
    tracker: SequenceTracker,
    empty: u64,
    oversized: u64,
    last_activity: Instant,
}

impl OpenStation {
    fn expected_chunks(&self) -> u64 {
        let announced = self
            .end
            .or(self.begin)
            .map(|e| e.expected_chunks as u64)
            .unwrap_or(0);
        if announced > 0 {
            announced
        } else {
            self.last_sequence.map(|s| s + 1).unwrap_or(0)
        }
    }

    fn expected_points(&self) -> u64 {
        self.end
            .map(|e| e.expected_points)
            .filter(|&n| n > 0)
            .or(self.begin.map(|e| e.expected_points))
            .unwrap_or(0)
    }

    /// The scanner said it is done (End event or a chunk flagged last).
    fn finished_sending(&self) -> bool {
        self.end.is_some() || self.last_sequence.is_some()
    }

    fn name(&self) -> String {
        self.begin
            .or(self.end)
            .map(|e| e.name.as_str().to_string())
            .filter(|n| !n.is_empty())
            .unwrap_or_else(|| format!("station-{}", self.key.1))
    }
}

struct Pending<C> {
    chunk: C,
    since: Instant,
}

/// Counters for the status message, kept across stations.
#[derive(Debug, Clone, Copy, Default)]
pub struct Counters {
    /// Points of accepted chunks processed.
    pub points_processed: u64,
    /// Accepted chunks processed.
    pub chunks_processed: u64,
    /// Stations reported.
    pub stations_reported: u64,
    /// Points rejected in the stations already reported; [`Lifecycle::fill_status`] adds those
    /// of the open ones.
    pub rejected_points: RejectCounts,
    /// Inputs rejected whole, by reason.
    pub input: InputRejects,
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// A printed height prepared on a worker thread, with how long its section and (for findings)
/// its cut mesh and its scan layer's findings state took.
struct Prepared {
    design: Arc<PrintedDesign>,
    /// The section, and with findings the cut mesh and its sharp edges beside it.
    section: Duration,
    /// The findings' design samples, M3C2 and coverage over them.
    mesh: Option<Duration>,
    epoch: Option<crate::findings::Epoch>,
}

/// A printed height being prepared on a worker thread.
struct Preparation {
    height: f64,
    since: Instant,
    done: mpsc::Receiver<Result<Prepared, CutError>>,
}

/// Every station of every job from Begin to report: poses, chunks in order, timeouts, the
/// printed design of each height, the findings after each report. Pure and synchronous: the
/// daemon feeds it messages and the time, a recording's reader does the same.
pub struct Lifecycle<C> {
    designs: PrintedDesigns,
    preparing: Vec<Preparation>,
    findings: Option<FindingsStage>,
    /// Advice after each findings, when `[corrections]` is on.
    corrector: Option<Corrector>,
    /// Flatness, dimensions and plumb over each scan layer, when `[tolerances]` names a
    /// standard.
    survey: Option<crate::survey::Survey>,
    frames: FrameChain,
    config: InspectParams,
    limits: LifecycleLimits,
    open: Vec<OpenStation>,
    pending: VecDeque<Pending<C>>,
    closed: ClosedStations,
    /// Counters for the status message.
    pub counters: Counters,
}

impl<C: ChunkSource> Lifecycle<C> {
    /// A lifecycle over `designs` (the design and its printed heights) placing points through
    /// `frames`.
    pub fn new(
        designs: PrintedDesigns,
        frames: FrameChain,
        config: InspectParams,
        limits: LifecycleLimits,
    ) -> Self {
        Self {
            designs,
            preparing: Vec::new(),
            findings: None,
            corrector: None,
            survey: None,
            frames,
            config,
            limits,
            open: Vec::with_capacity(limits.open_stations),
            pending: VecDeque::with_capacity(limits.pending_chunks),
            closed: ClosedStations::new(CLOSED_MEMORY),
            counters: Counters::default(),
        }
    }

    /// Whether findings are drawn (a findings stage is on).
    pub fn has_findings(&self) -> bool {
        self.findings.is_some()
    }

    /// Turns on findings over each scan layer's stations.
    pub fn with_findings(mut self, stage: FindingsStage) -> Self {
        self.findings = Some(stage);
        self
    }

    /// Judges the faces by the standards `survey` holds after every station.
    pub fn with_survey(mut self, survey: Option<crate::survey::Survey>) -> Self {
        self.survey = survey;
        self
    }

    /// Whether advice follows the findings (`[corrections]` is on).
    pub fn has_corrections(&self) -> bool {
        self.corrector.is_some()
    }

    /// Turns on advice for the layers still to print after each findings.
    pub fn with_corrections(mut self, limits: CorrectionLimits) -> Self {
        self.corrector = Some(Corrector::new(limits));
        self
    }

    /// Takes up advice the agent before this one gave (from its recording), in order.
    pub fn restore_correction(&mut self, c: &LayerCorrection) {
        if let Some(k) = self.corrector.as_mut() {
            k.restore(c);
        }
    }

    /// Findings out, then the advice they lead to.
    fn findings_out(
        &mut self,
        f: &StationFindings,
        report: &StationReport,
        out: &mut impl Outputs,
    ) {
        out.findings(f);
        if let Some(k) = self.corrector.as_mut() {
            let c = k.advise(f, report.attempt.max(1), report.position_sigma);
            info!(
                "job {} station {}: advice from layer {}: z {:+.2} mm a layer ({} layers), then \
                 {:+.2}; flow {:.3}; path ({:+.1}, {:+.1}) mm",
                c.job,
                c.station,
                c.from_layer,
                c.z_first * 1e3,
                c.first_layers,
                c.z_then * 1e3,
                c.flow,
                c.path_offset[0] * 1e3,
                c.path_offset[1] * 1e3
            );
            out.correction(&c);
        }
    }

    /// The printed layer an open station's Begin gave (0 until it is known).
    pub fn layer_of(&self, job: u64, station: u32) -> u32 {
        self.find(&(job, station))
            .and_then(|i| self.open[i].begin)
            .map_or(0, |b| b.layer)
    }

    /// Stations begun and not yet reported.
    pub fn stations_open(&self) -> usize {
        self.open.len()
    }

    /// Chunks held while their station's pose has not arrived.
    pub fn chunks_waiting(&self) -> usize {
        self.pending.len()
    }

    /// Fills the counting fields of a status message.
    pub fn fill_status(&self, s: &mut AgentStatus) {
        s.points_processed = self.counters.points_processed;
        s.chunks_processed = self.counters.chunks_processed;
        s.stations_reported = self.counters.stations_reported;
        s.rejected_points = self.counters.rejected_points;
        for station in &self.open {
            s.rejected_points += station.inspector.tally().rejected;
        }
        s.input = self.counters.input;
        s.stations_open = self.open.len() as u32;
        s.chunks_waiting = self.pending.len() as u32;
    }

    /// Whether a Begin or pose for this station can be taken without closing another station
    /// early: it is open or reported already, or a slot is free.
    pub fn has_room_for(&self, job: u64, station: u32) -> bool {
        let key = (job, station);
        self.find(&key).is_some()
            || self.closed.last_attempt(key).is_some()
            || self.open.len() < self.limits.open_stations
    }

    /// True when a chunk with this header can be processed now (its station is open with a
    /// pose). The daemon reads the event and pose queues before giving up on a chunk.
    pub fn is_ready_for(&self, h: &ChunkHeader) -> bool {
        self.find(&(h.job, h.station))
            .is_some_and(|i| self.ready(i))
    }

    /// Whether this chunk's station waits for its printed design.
    pub fn awaits_design(&self, h: &ChunkHeader) -> bool {
        self.find(&(h.job, h.station))
            .is_some_and(|i| self.open[i].awaiting.is_some())
    }

    /// A station's chunks can be compared: it has its pose and its printed design.
    fn ready(&self, i: usize) -> bool {
        self.open[i].pose.is_some() && self.open[i].awaiting.is_none()
    }

    /// Whether a printed height is being prepared: the event loop then wakes often enough to
    /// take it up as soon as it is done.
    pub fn is_preparing(&self) -> bool {
        !self.preparing.is_empty()
    }

    /// Takes up the printed heights prepared since the last call: their stations compare with
    /// them from now on and the chunks they held are processed.
    pub fn poll_designs(&mut self, now: Instant, out: &mut impl Outputs) {
        self.take_prepared(now, out, false);
    }

    /// Waits for every printed height being prepared and takes them up: for a reader of a
    /// recording, which has no robot to keep serving.
    pub fn wait_designs(&mut self, now: Instant, out: &mut impl Outputs) {
        self.take_prepared(now, out, true);
    }

    fn take_prepared(&mut self, now: Instant, out: &mut impl Outputs, block: bool) {
        let mut k = 0;
        while k < self.preparing.len() {
            let received = if block {
                self.preparing[k]
                    .done
                    .recv()
                    .map_err(|_| mpsc::TryRecvError::Disconnected)
            } else {
                self.preparing[k].done.try_recv()
            };
            let result = match received {
                Ok(r) => r.map_err(|e| e.to_string()),
                Err(mpsc::TryRecvError::Empty) => {
                    k += 1;
                    continue;
                }
                Err(mpsc::TryRecvError::Disconnected) => {
                    Err("the preparing thread stopped without a result".to_string())
                }
            };
            let p = self.preparing.swap_remove(k);
            let design = match result {
                Ok(prepared) => {
                    let d = prepared.design;
                    if let (Some(e), Some(stage)) = (prepared.epoch, self.findings.as_mut()) {
                        stage.adopt(e);
                    }
                    let (cut, samples) = match prepared.mesh {
                        Some(m) => (
                            " and the cut mesh with its edges",
                            format!(
                                ", then the findings' samples, M3C2 and coverage {:.1} ms",
                                ms(m)
                            ),
                        ),
                        None => ("", String::new()),
                    };
                    info!(
                        "design at printed height {:.3} m ready in {:.1} ms (section of {} \
                         triangles{cut} {:.1} ms{samples})",
                        p.height,
                        ms(now.saturating_duration_since(p.since)),
                        d.section().map_or(0, |s| s.triangles()),
                        ms(prepared.section),
                    );
                    self.designs.insert(d.clone());
                    d
                }
                Err(e) => {
                    warn!(
                        "printed height {} m: {e}; comparing with the whole design",
                        p.height
                    );
                    self.designs.full().clone()
                }
            };
            let waiting: Vec<StationKey> = self
                .open
                .iter()
                .filter(|s| s.awaiting == Some(p.height))
                .map(|s| s.key)
                .collect();
            for key in waiting {
                if let Some(i) = self.find(&key) {
                    let s = &mut self.open[i];
                    s.inspector.set_index(design.clone());
                    s.design = design.clone();
                    s.awaiting = None;
                    self.release_pending(key, now, out);
                }
            }
        }
    }

    /// Counts and logs a message of another version; true when it can be read.
    fn readable<M: Message>(&mut self, version: u16, what: std::fmt::Arguments<'_>) -> bool {
        match asbuilt_protocol::check_version::<M>(version) {
            Ok(()) => true,
            Err(e) => {
                self.counters.input.version_mismatch += 1;
                warn!("{what} ignored: {e}");
                false
            }
        }
    }

    /// Takes a station's Begin or End.
    pub fn on_event(&mut self, ev: &StationEvent, now: Instant, out: &mut impl Outputs) {
        if !self.readable::<StationEvent>(ev.version, format_args!("station event")) {
            return;
        }
        let key = (ev.job, ev.station);
        let attempt = attempt_of(ev.attempt.into());
        if ev.kind() == Some(StationEventKind::Begin)
            && self.closed.is_sent_anew(key, attempt, ev.timestamp_ns)
        {
            // A cell process started again does not know its predecessor's attempts.
            info!(
                "job {} station {} attempt {attempt}: begins anew, later than the reported one \
                 (a cell started again); served again",
                key.0, key.1
            );
            self.closed.forget(key);
        }
        if self.is_over(key, attempt, out) {
            // An End after a chunk flagged last closed the station is the usual order.
            if ev.kind() != Some(StationEventKind::End) {
                info!(
                    "job {} station {} attempt {attempt}: Begin of an attempt already reported \
                     or given up (a repeat, or the service's history), ignored",
                    key.0, key.1
                );
            }
            return;
        }
        match ev.kind() {
            Some(StationEventKind::Begin) => {
                let i = self.open_slot(key, attempt, now, out);
                self.print_height(i, ev.printed_height, now);
                let s = &mut self.open[i];
                if s.begin.is_some() {
                    warn!("job {} station {}: Begin repeated", key.0, key.1);
                }
                s.begin = Some(*ev);
                s.last_activity = now;
                info!(
                    "job {} station {} ({}) begins, layer {}{}",
                    key.0,
                    key.1,
                    s.name(),
                    ev.layer,
                    attempt_text(attempt)
                );
                self.release_pending(key, now, out);
            }
            Some(StationEventKind::End) => match self.find(&key) {
                Some(i) => {
                    let s = &mut self.open[i];
                    s.end = Some(*ev);
                    s.last_activity = now;
                    s.finished_at.get_or_insert(now);
                    self.close_if_complete(i, out);
                }
                None if self.closed.last_attempt(key).is_some() => {
                    // Closed already by a chunk flagged last: nothing to add.
                }
                None => {
                    self.counters.input.events_invalid += 1;
                    warn!(
                        "job {} station {}: End for a station that is not open, ignored",
                        key.0, key.1
                    );
                }
            },
            None => {
                self.counters.input.events_invalid += 1;
                warn!(
                    "job {} station {}: station event of unknown kind {} ignored",
                    key.0, key.1, ev.kind
                );
            }
        }
    }

    /// Takes a station's pose; the chunks waiting for it are processed.
    pub fn on_pose(&mut self, pose: &PoseSnapshot, now: Instant, out: &mut impl Outputs) {
        if !self.readable::<PoseSnapshot>(pose.version, format_args!("pose")) {
            return;
        }
        let key = (pose.job, pose.station);
        let attempt = attempt_of(pose.attempt.into());
        if self.is_over(key, attempt, out) {
            info!(
                "job {} station {} attempt {attempt}: pose for an attempt already reported or \
                 given up, ignored",
                key.0, key.1
            );
            return;
        }
        let t = match self.frames.t_design_scanner(pose) {
            Ok(t) => t,
            Err(e) => {
                self.counters.input.poses_invalid += 1;
                warn!("job {} station {}: pose rejected: {e}", key.0, key.1);
                return;
            }
        };
        let i = self.open_slot(key, attempt, now, out);
        let s = &mut self.open[i];
        if s.pose.is_some() {
            warn!(
                "job {} station {}: a new pose replaces the previous one for the chunks that follow",
                key.0, key.1
            );
        }
        s.pose = Some(*pose);
        s.inspector.set_pose(t);
        s.last_activity = now;
        self.release_pending(key, now, out);
    }

    /// Takes a scan chunk: processed now, held for its station's pose, or rejected and counted.
    pub fn on_chunk(&mut self, chunk: C, now: Instant, out: &mut impl Outputs) {
        let h = *chunk.header();
        let n = chunk.points().len();
        if !self.readable::<ChunkHeader>(h.version, format_args!("scan chunk ({n} points)")) {
            return;
        }
        let key = (h.job, h.station);
        let attempt = attempt_of(h.attempt);
        if self.is_over(key, attempt, out) {
            self.counters.input.chunks_after_close += 1;
            warn!(
                "job {} station {} attempt {attempt}: chunk {} arrived after the attempt's \
                 report, dropped ({} points)",
                key.0,
                key.1,
                h.sequence,
                chunk.points().len()
            );
            return;
        }
        match self.find(&key) {
            Some(i) if self.ready(i) => {
                self.process(i, &chunk, now, out);
                self.close_if_complete(i, out);
            }
            None if h.sequence > 0 && !self.holds_any_of(key) => {
                self.began_before_us(chunk, attempt, out)
            }
            _ => self.hold(chunk, now),
        }
    }

    /// Whether a message of `attempt` of `key` comes too late: that attempt (or a later one)
    /// was reported, or a later one is open. A message of a later attempt than the open one
    /// means the cell gave up on the open one: it closes as interrupted.
    fn is_over(&mut self, key: StationKey, attempt: u16, out: &mut impl Outputs) -> bool {
        if self.closed.covers(key, attempt) {
            return true;
        }
        match self.find(&key) {
            Some(i) if self.open[i].attempt > attempt => true,
            Some(i) if self.open[i].attempt < attempt => {
                info!(
                    "job {} station {}: attempt {attempt} begins while attempt {} is open; the \
                     cell gave that one up",
                    key.0, key.1, self.open[i].attempt
                );
                self.close(i, Some(StationStatus::Interrupted), out);
                false
            }
            _ => false,
        }
    }

    /// Whether a chunk of `key` waits for its station's pose.
    fn holds_any_of(&self, key: StationKey) -> bool {
        self.pending.iter().any(|p| {
            let h = p.chunk.header();
            (h.job, h.station) == key
        })
    }

    /// A chunk past the first of a station this agent never saw begin: the station began
    /// before this agent started (it replaced one that stopped), so its first chunks went to
    /// the one before and are lost. Holding the chunk for a Begin that will not come would
    /// keep the cell waiting for the station timeout: the chunk is dropped at once and counted,
    /// and the attempt is reported interrupted so that the cell sends the station again.
    fn began_before_us(&mut self, chunk: C, attempt: u16, out: &mut impl Outputs) {
        let h = *chunk.header();
        self.counters.input.chunks_unknown_station += 1;
        warn!(
            "job {} station {} attempt {attempt}: chunk {} arrived without its station's Begin \
             and first chunks (the station began before this agent started); dropped, and the \
             attempt is reported interrupted",
            h.job, h.station, h.sequence
        );
        let mut report = StationReport::new(h.job, h.station);
        report.points_received = chunk.points().len() as u64;
        report.rejected.without_pose = chunk.points().len() as u64;
        // Its Begin was sent before this chunk: a later one is the station sent anew.
        self.report_interrupted(report, attempt, h.timestamp_ns, out);
    }

    /// Reports an attempt that is not open here as interrupted (`report` says what is known
    /// of it), and remembers it as over; `begun_ns` is when its Begin was sent, or before.
    fn report_interrupted(
        &mut self,
        mut report: StationReport,
        attempt: u16,
        begun_ns: u64,
        out: &mut impl Outputs,
    ) {
        report.attempt = attempt.min(u8::MAX.into()) as u8;
        report.status = StationStatus::Interrupted as u8;
        self.counters.rejected_points += report.rejected;
        self.counters.stations_reported += 1;
        out.report(&report);
        self.closed
            .push((report.job, report.station), attempt, begun_ns);
    }

    /// Closes `attempt` of `key` as interrupted: the agent that had it open stopped (a resumed
    /// agent after replaying its recording, a reader of a recording where the resumed agent
    /// said so). An attempt not open here is reported interrupted all the same.
    /// `begin` names the attempt: its job, station and attempt, and the name, layer and printed
    /// height the report carries when the station is not open here.
    pub fn interrupt(&mut self, begin: &StationEvent, out: &mut impl Outputs) {
        let key = (begin.job, begin.station);
        let attempt = attempt_of(begin.attempt.into());
        if self.closed.covers(key, attempt) {
            return;
        }
        match self.find(&key) {
            Some(i) if self.open[i].attempt == attempt => {
                self.close(i, Some(StationStatus::Interrupted), out)
            }
            Some(i) if self.open[i].attempt > attempt => {}
            found => {
                if let Some(i) = found {
                    self.close(i, Some(StationStatus::Interrupted), out);
                }
                let mut report = StationReport::new(key.0, key.1);
                report.name = begin.name;
                report.layer = begin.layer;
                report.printed_height = begin.printed_height;
                self.report_interrupted(report, attempt, asbuilt_protocol::unix_time_ns(), out);
            }
        }
    }

    /// Closes every open station as interrupted (an agent resuming from its recording: the
    /// stations it replayed that never ended were open when the agent before it stopped).
    pub fn interrupt_open(&mut self, out: &mut impl Outputs) -> Vec<StationKey> {
        let mut keys = Vec::new();
        while let Some(s) = self.open.first() {
            keys.push(s.key);
            self.close(0, Some(StationStatus::Interrupted), out);
        }
        keys
    }

    /// Takes up the scan layer of `job` at `printed_height` (NaN: the whole design) from the
    /// state the agent before recorded after its last station: the printed design is prepared
    /// here and now, and the layer's next stations go on from that state. `last` is that
    /// station and the state recorded before it first closed (`None`: it was the layer's first),
    /// so that it can be sent again (see [`FindingsStage`]).
    pub fn restore_scan_layer(
        &mut self,
        job: u64,
        printed_height: f64,
        state: &ScanLayerState,
        last: Option<(u32, Option<&ScanLayerState>)>,
    ) -> Result<(), RestoreError> {
        let design = if printed_height.is_finite() {
            self.designs.at(printed_height)?
        } else {
            self.designs.full().clone()
        };
        let stage = self.findings.as_mut().ok_or(RestoreError::FindingsOff)?;
        if stage.restore(job, &design, state, last) {
            Ok(())
        } else {
            Err(RestoreError::DoesNotFit)
        }
    }

    /// Publishes the findings the station of `report` drew when it closed, drawn again from its
    /// scan layer's state: the agent before this one stopped before they were on disk.
    pub fn findings_after(&mut self, report: &StationReport, out: &mut impl Outputs) {
        let design = if report.printed_height.is_finite() {
            match self.designs.at(report.printed_height) {
                Ok(d) => d,
                Err(_) => return,
            }
        } else {
            self.designs.full().clone()
        };
        if let Some(f) = self
            .findings
            .as_ref()
            .and_then(|s| s.findings_after(&design, report))
        {
            self.findings_out(&f, report, out);
        }
    }

    /// Remembers that `attempt` of `key` was reported by the agent before this one (from its
    /// recording), so that its repeats and late messages change nothing.
    /// `begun_ns` is when that attempt's Begin was sent (0 when unknown).
    pub fn remember_reported(&mut self, key: StationKey, attempt: u16, begun_ns: u64) {
        if !self.closed.covers(key, attempt) {
            self.closed.push(key, attempt_of(attempt), begun_ns);
        }
    }

    /// The input queues are empty: a station whose scanner said it is done, at least
    /// [`END_GRACE`] ago, closes now, even if chunks are missing.
    pub fn on_idle(&mut self, now: Instant, out: &mut impl Outputs) {
        let mut i = 0;
        while i < self.open.len() {
            let s = &self.open[i];
            // A station waiting for its printed design has its chunks still queued.
            let settled = s
                .finished_at
                .is_some_and(|t| now.saturating_duration_since(t) >= END_GRACE);
            if settled && s.awaiting.is_none() {
                self.close(i, None, out);
            } else {
                i += 1;
            }
        }
    }

    /// Closes stations and drops held chunks that have waited longer than the station timeout.
    pub fn on_tick(&mut self, now: Instant, out: &mut impl Outputs) {
        let timeout = self.limits.station_timeout;
        let mut i = 0;
        while i < self.open.len() {
            if now.duration_since(self.open[i].last_activity) > timeout {
                let s = &self.open[i];
                warn!(
                    "job {} station {}: no message for {:.1} s, closing it as timed out",
                    s.key.0,
                    s.key.1,
                    timeout.as_secs_f64()
                );
                self.close(i, Some(StationStatus::TimedOut), out);
            } else {
                i += 1;
            }
        }
        while self
            .pending
            .front()
            .is_some_and(|p| now.duration_since(p.since) > timeout)
        {
            let p = self.pending.pop_front().expect("checked non-empty");
            self.drop_unknown(&p.chunk);
        }
    }

    /// Shutdown: every open station gets a partial report; held chunks without a station are
    /// counted.
    pub fn shutdown(&mut self, out: &mut impl Outputs) {
        while !self.open.is_empty() {
            self.close(0, Some(StationStatus::Partial), out);
        }
        while let Some(p) = self.pending.pop_front() {
            self.drop_unknown(&p.chunk);
        }
    }

    /// Compares station `i` with the design cut at the printed height, if the station has not
    /// compared any point yet. A height not seen recently is prepared on a worker thread (the
    /// loop goes on reading, timing out and reporting); the station's chunks wait for it.
    fn print_height(&mut self, i: usize, height: f64, now: Instant) {
        if !height.is_finite() || self.open[i].inspector.tally().points_received > 0 {
            return;
        }
        if let Some(d) = self.designs.cached(height) {
            let s = &mut self.open[i];
            s.inspector.set_index(d.clone());
            s.design = d;
            s.awaiting = None;
            return;
        }
        self.open[i].awaiting = Some(height);
        if self.preparing.iter().any(|p| p.height == height) {
            return;
        }
        let (tx, done) = mpsc::channel();
        let preparer = self.designs.preparer();
        // Findings sample the printed design as a mesh and set up the scan layer's M3C2 and
        // coverage over the samples: make those off the loop too.
        let maker = self.findings.as_ref().map(|f| f.maker());
        let job = self.open[i].key.0;
        let spawned = std::thread::Builder::new()
            .name("design-height".into())
            .spawn(move || {
                let started = Instant::now();
                // With findings, the cut mesh they sample is made beside the section.
                let prepared = preparer.prepare(height, maker.is_some()).map(|design| {
                    let section = started.elapsed();
                    let design = Arc::new(design);
                    let epoch = maker.as_ref().and_then(|m| m.make(job, &design));
                    let mesh = maker.is_some().then(|| started.elapsed() - section);
                    Prepared {
                        design,
                        section,
                        mesh,
                        epoch,
                    }
                });
                let _ = tx.send(prepared);
            });
        match spawned {
            Ok(_) => self.preparing.push(Preparation {
                height,
                since: now,
                done,
            }),
            Err(e) => {
                let key = self.open[i].key;
                warn!(
                    "job {} station {}: cannot start preparing printed height {height} m ({e}); \
                     comparing with the whole design",
                    key.0, key.1
                );
                self.open[i].awaiting = None;
            }
        }
    }

    fn find(&self, key: &StationKey) -> Option<usize> {
        self.open.iter().position(|s| &s.key == key)
    }

    fn open_slot(
        &mut self,
        key: StationKey,
        attempt: u16,
        now: Instant,
        out: &mut impl Outputs,
    ) -> usize {
        if let Some(i) = self.find(&key) {
            return i;
        }
        if self.open.len() == self.limits.open_stations {
            let oldest = (0..self.open.len())
                .min_by_key(|&i| self.open[i].last_activity)
                .expect("at least one station is open");
            let s = &self.open[oldest];
            warn!(
                "more than {} stations open: closing job {} station {} early to make room",
                self.limits.open_stations, s.key.0, s.key.1
            );
            self.close(oldest, Some(StationStatus::Incomplete), out);
        }
        self.open.push(OpenStation {
            key,
            attempt,
            begin: None,
            end: None,
            pose: None,
            last_sequence: None,
            finished_at: None,
            inspector: StationInspector::new(
                self.designs.full().clone(),
                nalgebra::Isometry3::identity(),
                self.config,
            ),
            design: self.designs.full().clone(),
            awaiting: None,
            findings: None,
            tracker: SequenceTracker::new(),
            empty: 0,
            oversized: 0,
            last_activity: now,
        });
        self.open.len() - 1
    }

    fn hold(&mut self, chunk: C, now: Instant) {
        let h = *chunk.header();
        if self.pending.len() == self.limits.pending_chunks {
            match self.pending.pop_front() {
                Some(old) => {
                    self.counters.input.chunks_pending_overflow += 1;
                    let oh = *old.chunk.header();
                    warn!(
                        "job {} station {}: chunk {} waited for a pose in a full buffer and was \
                         pushed out ({} points)",
                        oh.job,
                        oh.station,
                        oh.sequence,
                        old.chunk.points().len()
                    );
                    self.reject_held(old.chunk);
                }
                None => {
                    // No buffer at all (pending_chunks = 0): reject at once.
                    self.counters.input.chunks_pending_overflow += 1;
                    self.reject_held(chunk);
                    return;
                }
            }
        }
        if let Some(i) = self.find(&(h.job, h.station)) {
            self.open[i].last_activity = now;
        }
        self.pending.push_back(Pending { chunk, since: now });
    }

    /// A held chunk that will never be processed: counted against its station when it is open.
    fn reject_held(&mut self, chunk: C) {
        let h = *chunk.header();
        match self.find(&(h.job, h.station)) {
            Some(i) => {
                let s = &mut self.open[i];
                s.tracker.offer(h.sequence);
                s.inspector
                    .reject(chunk.points().len() as u64, |r| &mut r.without_pose);
            }
            None => self.drop_unknown(&chunk),
        }
    }

    /// Removes the first held chunk of a station, keeping the others in arrival order.
    fn take_pending(&mut self, key: StationKey) -> Option<Pending<C>> {
        let at = self.pending.iter().position(|p| {
            let h = p.chunk.header();
            (h.job, h.station) == key
        })?;
        self.pending.remove(at)
    }

    fn drop_unknown(&mut self, chunk: &C) {
        let h = chunk.header();
        self.counters.input.chunks_unknown_station += 1;
        warn!(
            "job {} station {}: chunk {} dropped, the station never began (no Begin event or \
             pose) ({} points)",
            h.job,
            h.station,
            h.sequence,
            chunk.points().len()
        );
    }

    /// Processes the held chunks of a station that just became ready, in arrival order.
    fn release_pending(&mut self, key: StationKey, now: Instant, out: &mut impl Outputs) {
        let Some(i) = self.find(&key) else { return };
        if !self.ready(i) {
            return;
        }
        while let Some(p) = self.take_pending(key) {
            self.process(i, &p.chunk, now, out);
        }
        self.close_if_complete(i, out);
    }

    fn process(&mut self, i: usize, chunk: &C, now: Instant, out: &mut impl Outputs) {
        let h = *chunk.header();
        let points = chunk.points();
        let n = points.len();
        let s = &mut self.open[i];
        s.last_activity = now;
        if h.last != 0 {
            s.last_sequence = Some(h.sequence);
            s.finished_at.get_or_insert(now);
        }
        let input = &mut self.counters.input;
        if h.point_count as usize != n {
            input.chunks_malformed += 1;
            s.tracker.offer(h.sequence);
            s.inspector.reject(n as u64, |r| &mut r.in_rejected_chunks);
            warn!(
                "job {} station {}: chunk {} declares {} points but carries {}, rejected",
                h.job, h.station, h.sequence, h.point_count, n
            );
            return;
        }
        let verdict = s.tracker.offer(h.sequence);
        match verdict {
            ChunkVerdict::Duplicate | ChunkVerdict::TooOld => {
                if verdict == ChunkVerdict::Duplicate {
                    input.chunks_duplicate += 1;
                } else {
                    input.chunks_out_of_order += 1;
                }
                s.inspector.reject(n as u64, |r| &mut r.in_rejected_chunks);
                warn!(
                    "job {} station {}: chunk {} {}, dropped",
                    h.job,
                    h.station,
                    h.sequence,
                    if verdict == ChunkVerdict::Duplicate {
                        "repeated"
                    } else {
                        "too far out of order to tell whether it is new"
                    }
                );
                return;
            }
            ChunkVerdict::Accept | ChunkVerdict::AcceptLate => {}
        }
        if n == 0 {
            input.chunks_empty += 1;
            s.empty += 1;
            return;
        }
        if n > self.limits.max_points_per_chunk {
            input.chunks_oversized += 1;
            s.oversized += 1;
            s.inspector.reject(n as u64, |r| &mut r.in_rejected_chunks);
            warn!(
                "job {} station {}: chunk {} has {} points, more than limits.max_points_per_chunk \
                 = {}, rejected",
                h.job, h.station, h.sequence, n, self.limits.max_points_per_chunk
            );
            return;
        }
        let stage = &mut self.findings;
        let in_findings = match (s.findings, stage.as_mut()) {
            (Some(taken), _) => taken,
            (None, Some(st)) => *s.findings.insert(st.begin(s.key, &s.design)),
            (None, None) => false,
        };
        let inspector = &mut s.inspector;
        let survey = &mut self.survey;
        let height = s.design.height;
        let view = asbuilt_core::flatness::StationView {
            key: (h.job, h.station),
            origin: s
                .pose
                .filter(|_| survey.is_some())
                .and_then(|p| self.frames.t_design_scanner(&p).ok())
                .map(|t| nalgebra::Point3::from(t.translation.vector)),
            position_sigma: s.pose.map_or(f64::NAN, |p| p.position_sigma),
        };
        out.deviations(n, &mut |buf| {
            let outcome = inspector.process(points, buf);
            if in_findings && let Some(st) = stage.as_mut() {
                st.ingest((h.job, h.station), buf);
            }
            if let Some(sv) = survey.as_mut() {
                sv.ingest(h.job, height, &view, buf);
            }
            let mut d = DeviationHeader::new(h.job, h.station, h.sequence);
            d.timestamp_ns = h.timestamp_ns;
            d.point_count = n as u32;
            d.rejected = outcome.rejected;
            d.no_match = outcome.no_match;
            d.out_of_tolerance = outcome.out_of_tolerance;
            d
        });
        self.counters.points_processed += n as u64;
        self.counters.chunks_processed += 1;
    }

    fn close_if_complete(&mut self, i: usize, out: &mut impl Outputs) {
        let s = &self.open[i];
        if s.finished_sending() && s.tracker.is_complete(s.expected_chunks()) {
            self.close(i, None, out);
        }
    }

    fn close(&mut self, i: usize, forced: Option<StationStatus>, out: &mut impl Outputs) {
        let key = self.open[i].key;
        // Held chunks of this station will never get a pose now.
        while let Some(p) = self.take_pending(key) {
            self.reject_held(p.chunk);
        }
        let s = self.open.swap_remove(i);
        let expected = s.expected_chunks();
        let mut report = s.inspector.report(key.0, key.1, &s.name());
        report.attempt = s.attempt.min(u8::MAX.into()) as u8;
        let mut chunks = s.tracker.finish(expected);
        chunks.empty = s.empty;
        chunks.oversized = s.oversized;
        report.chunks = chunks;
        if let Some(e) = s.begin.or(s.end) {
            report.layer = e.layer;
            report.printed_height = e.printed_height;
        }
        report.position_sigma = s.pose.map(|p| p.position_sigma).unwrap_or(f64::NAN);
        let expected_points = s.expected_points();
        let complete = s.pose.is_some()
            && s.tracker.is_complete(expected)
            && (expected_points == 0 || report.points_received == expected_points)
            && s.finished_sending();
        let status = forced.unwrap_or(if complete {
            StationStatus::Complete
        } else {
            StationStatus::Incomplete
        });
        report.status = status as u8;
        let interrupted = status == StationStatus::Interrupted;
        let mut drawn = None;
        if s.findings == Some(true)
            && let Some(stage) = self.findings.as_mut()
        {
            if interrupted {
                // An interrupted try adds nothing: its next attempt scans the station again.
                stage.abandon(key);
            } else {
                let origin = s
                    .pose
                    .and_then(|p| self.frames.t_design_scanner(&p).ok())
                    .map(|t| nalgebra::Point3::from(t.translation.vector));
                drawn = stage.end(key, origin, &report);
                // The scan layer's state goes out before the report: a report on disk means
                // its layer's state is too, for an agent that resumes the job.
                if drawn.is_some()
                    && out.wants_scan_layer_state()
                    && let Some(state) = stage.layer_state(key.0, &s.design)
                {
                    out.scan_layer_state(&report, &state);
                }
            }
        }
        out.tally(s.inspector.tally());
        out.report(&report);
        if !interrupted && let Some(sv) = &self.survey {
            out.surface(&sv.judge(key, report.layer, report.printed_height));
        }
        if let Some(f) = drawn {
            info!(
                "job {} station {}: findings over {} station(s) of layer {}: top {:+.1} mm, {} \
                 layer(s) out of tolerance, {} region(s), {} missing area(s)",
                key.0,
                key.1,
                f.stations,
                f.layer,
                f.top_height_deviation * 1e3,
                f.layers_out_of_tolerance().count(),
                f.regions.len(),
                f.missing.len()
            );
            self.findings_out(&f, &report, out);
            if let Some(stage) = self.findings.as_ref()
                && !stage.samples().is_empty()
            {
                out.samples(&f, stage.samples());
            }
        }
        self.counters.stations_reported += 1;
        self.counters.rejected_points += report.rejected;
        let begun = s
            .begin
            .map_or_else(asbuilt_protocol::unix_time_ns, |b| b.timestamp_ns);
        self.closed.push(key, s.attempt, begun);
        let st = &report.stats;
        info!(
            "job {} station {} ({}){} {:?}: {} points, {} matched, {} rejected, {} no match; chunks \
             {} received / {} expected, {} missing; median |d| {:.3} mm, p95 {:.3} mm",
            key.0,
            key.1,
            report.name.as_str(),
            attempt_text(s.attempt),
            status,
            report.points_received,
            st.count,
            report.rejected.total(),
            report.no_match,
            chunks.received,
            chunks.expected,
            chunks.missing,
            st.median_abs * 1e3,
            st.p95_abs * 1e3
        );
    }
}

/// " attempt n" after a station's name, for a second try or later.
fn attempt_text(attempt: u16) -> String {
    if attempt > 1 {
        format!(" attempt {attempt}")
    } else {
        String::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use asbuilt_core::C2mParams;
    use asbuilt_core::design::shapes;
    use asbuilt_protocol::{PoseMode, ScanPointFlags};

    struct Owned(ChunkHeader, Vec<ScanPoint>);
    impl ChunkSource for Owned {
        fn header(&self) -> &ChunkHeader {
            &self.0
        }
        fn points(&self) -> &[ScanPoint] {
            &self.1
        }
    }

    #[derive(Default)]
    struct Collect {
        deviations: Vec<(DeviationHeader, Vec<PointDeviation>)>,
        reports: Vec<StationReport>,
    }
    impl Outputs for Collect {
        fn deviations(
            &mut self,
            n: usize,
            fill: &mut dyn FnMut(&mut [PointDeviation]) -> DeviationHeader,
        ) {
            let mut buf = vec![PointDeviation::default(); n];
            let h = fill(&mut buf);
            self.deviations.push((h, buf));
        }
        fn report(&mut self, r: &StationReport) {
            self.reports.push(*r);
        }
    }

    /// A 1 m cube centred at the origin; points on its top face, 2 mm above it.
    fn cube() -> PrintedDesigns {
        let d = shapes::cuboid(
            nalgebra::Point3::new(-0.5, -0.5, -0.5),
            nalgebra::Point3::new(0.5, 0.5, 0.5),
        );
        PrintedDesigns::new(d, C2mParams::within(0.05)).unwrap()
    }

    fn limits() -> LifecycleLimits {
        LifecycleLimits {
            max_points_per_chunk: 100,
            pending_chunks: 4,
            open_stations: 2,
            station_timeout: Duration::from_secs(10),
        }
    }

    fn chunk(station: u32, seq: u64, n: usize) -> Owned {
        let pts = (0..n)
            .map(|i| ScanPoint::new(-0.4 + 0.008 * i as f32, 0.1, 0.502))
            .collect();
        Owned(ChunkHeader::new(1, station, seq, n as u32), pts)
    }

    fn pose(station: u32) -> PoseSnapshot {
        PoseSnapshot::new(1, station, PoseMode::DesignScanner)
    }

    fn event(kind: StationEventKind, station: u32, chunks: u32) -> StationEvent {
        let mut e = StationEvent::new(kind, 1, station);
        e.expected_chunks = chunks;
        e
    }

    /// Station `station`'s Begin, announcing `chunks` chunks, and its pose.
    fn begin_with_pose(
        lc: &mut Lifecycle<Owned>,
        out: &mut Collect,
        t: Instant,
        station: u32,
        chunks: u32,
    ) {
        lc.on_event(&event(StationEventKind::Begin, station, chunks), t, out);
        lc.on_pose(&pose(station), t, out);
    }

    #[test]
    fn a_clean_station_reports_complete_when_its_last_chunk_is_in() {
        let (mut lc, mut out, t) = setup();
        begin_with_pose(&mut lc, &mut out, t, 7, 0);
        for s in 0..3 {
            lc.on_chunk(chunk(7, s, 50), t, &mut out);
        }
        assert!(out.reports.is_empty());
        lc.on_event(&event(StationEventKind::End, 7, 3), t, &mut out);
        assert_eq!(out.reports.len(), 1);
        let r = out.reports[0];
        assert_eq!(r.status(), Some(StationStatus::Complete));
        assert_eq!(r.points_received, 150);
        assert_eq!(r.stats.count, 150);
        assert!((r.stats.mean - 0.002).abs() < 1e-6, "{}", r.stats.mean);
        assert_eq!(out.deviations.len(), 3);
        assert_eq!(out.deviations[2].0.sequence, 2);
        assert_eq!(lc.stations_open(), 0);
    }

    /// A lifecycle on the cube, nothing received yet, with what it sends and the time it starts.
    fn setup() -> (Lifecycle<Owned>, Collect, Instant) {
        let lc = Lifecycle::new(cube(), FrameChain::default(), cfg(), limits());
        (lc, Collect::default(), Instant::now())
    }

    fn cfg() -> InspectParams {
        InspectParams::with_tolerance(0.005)
    }

    #[test]
    fn chunks_before_their_pose_wait_and_are_then_processed() {
        let (mut lc, mut out, t) = setup();
        lc.on_chunk(chunk(3, 0, 10), t, &mut out);
        lc.on_event(&event(StationEventKind::Begin, 3, 2), t, &mut out);
        lc.on_chunk(chunk(3, 1, 10), t, &mut out);
        assert_eq!(lc.chunks_waiting(), 2);
        lc.on_pose(&pose(3), t, &mut out);
        assert_eq!(lc.chunks_waiting(), 0);
        lc.on_event(&event(StationEventKind::End, 3, 2), t, &mut out);
        let r = out.reports[0];
        assert_eq!(r.status(), Some(StationStatus::Complete));
        assert_eq!(r.stats.count, 20);
    }

    #[test]
    fn a_station_knows_the_layer_its_begin_gave() {
        let (mut lc, mut out, t) = setup();
        assert_eq!(lc.layer_of(4, 1), 0);
        let mut begin = event(StationEventKind::Begin, 1, 2);
        begin.job = 4;
        begin.layer = 17;
        lc.on_event(&begin, t, &mut out);
        assert_eq!(lc.layer_of(4, 1), 17);
        assert_eq!(lc.layer_of(4, 2), 0);
    }

    #[test]
    fn an_end_that_overtakes_its_last_chunks_waits_for_them() {
        let (mut lc, mut out, t) = setup();
        begin_with_pose(&mut lc, &mut out, t, 2, 3);
        lc.on_chunk(chunk(2, 0, 10), t, &mut out);
        lc.on_event(&event(StationEventKind::End, 2, 3), t, &mut out);
        // The queues run empty before the last chunks, sent by another process, are seen.
        lc.on_idle(t + END_GRACE / 2, &mut out);
        assert!(out.reports.is_empty());
        lc.on_chunk(chunk(2, 1, 10), t + END_GRACE / 2, &mut out);
        lc.on_chunk(chunk(2, 2, 10), t + END_GRACE / 2, &mut out);
        assert_eq!(out.reports[0].status(), Some(StationStatus::Complete));
        assert_eq!(out.reports[0].stats.count, 30);

        // A chunk that never comes: the station is reported incomplete after the grace.
        begin_with_pose(&mut lc, &mut out, t, 3, 2);
        lc.on_chunk(chunk(3, 0, 10), t, &mut out);
        lc.on_event(&event(StationEventKind::End, 3, 2), t, &mut out);
        lc.on_idle(t + END_GRACE / 2, &mut out);
        assert_eq!(out.reports.len(), 1);
        lc.on_idle(t + END_GRACE, &mut out);
        assert_eq!(out.reports[1].status(), Some(StationStatus::Incomplete));
        assert_eq!(out.reports[1].chunks.missing, 1);
    }

    #[test]
    fn a_station_without_pose_is_reported_with_every_point_counted() {
        let (mut lc, mut out, t) = setup();
        lc.on_event(&event(StationEventKind::Begin, 3, 0), t, &mut out);
        for s in 0..6 {
            lc.on_chunk(chunk(3, s, 10), t, &mut out);
        }
        // Two were pushed out of the 4-chunk buffer.
        assert_eq!(lc.counters.input.chunks_pending_overflow, 2);
        lc.on_event(&event(StationEventKind::End, 3, 6), t, &mut out);
        lc.on_idle(t + END_GRACE, &mut out);
        let r = out.reports[0];
        assert_eq!(r.status(), Some(StationStatus::Incomplete));
        assert_eq!(r.points_received, 60);
        assert_eq!(r.rejected.without_pose, 60);
        assert_eq!(r.chunks.missing, 0);
        assert_eq!(r.stats.count, 0);
    }

    #[test]
    fn bad_chunks_are_counted_by_reason_and_good_points_kept() {
        let (mut lc, mut out, t) = setup();
        begin_with_pose(&mut lc, &mut out, t, 1, 0);
        let mut c = chunk(1, 0, 10);
        c.1[0].xyz[0] = f32::NAN;
        c.1[1].flags = ScanPointFlags(ScanPointFlags::INVALID);
        c.1[2].xyz = [1e6, 0.0, 0.0];
        lc.on_chunk(c, t, &mut out);
        lc.on_chunk(chunk(1, 0, 10), t, &mut out); // repeat
        lc.on_chunk(chunk(1, 1, 0), t, &mut out); // empty
        lc.on_chunk(chunk(1, 2, 101), t, &mut out); // oversized
        let mut lying = chunk(1, 3, 10);
        lying.0.point_count = 11;
        lc.on_chunk(lying, t, &mut out);
        let mut future = chunk(1, 4, 10);
        future.0.version = 9;
        lc.on_chunk(future, t, &mut out);
        lc.on_chunk(chunk(1, 5, 10), t, &mut out);
        lc.on_event(&event(StationEventKind::End, 1, 6), t, &mut out);
        lc.on_idle(t + END_GRACE, &mut out);
        let r = out.reports[0];
        let i = lc.counters.input;
        assert_eq!(
            (
                i.chunks_duplicate,
                i.chunks_empty,
                i.chunks_oversized,
                i.chunks_malformed,
                i.version_mismatch
            ),
            (1, 1, 1, 1, 1)
        );
        assert_eq!(r.rejected.non_finite, 1);
        assert_eq!(r.rejected.scanner_invalid, 1);
        assert_eq!(r.rejected.out_of_range, 1);
        assert_eq!(r.rejected.in_rejected_chunks, 10 + 101 + 10);
        assert_eq!(r.stats.count, 7 + 10);
        assert_eq!(r.chunks.missing, 1, "chunk 4 was never usable");
        assert_eq!((r.chunks.empty, r.chunks.oversized), (1, 1));
        assert_eq!(r.status(), Some(StationStatus::Incomplete));
        assert_eq!(lc.counters.rejected_points.total(), r.rejected.total());
    }

    #[test]
    fn silence_closes_a_station_as_timed_out_and_late_chunks_are_counted() {
        let (mut lc, mut out, t) = setup();
        begin_with_pose(&mut lc, &mut out, t, 2, 0);
        lc.on_chunk(chunk(2, 0, 10), t, &mut out);
        lc.on_chunk(chunk(9, 0, 10), t, &mut out); // never begins
        lc.on_tick(t + Duration::from_secs(5), &mut out);
        assert!(out.reports.is_empty());
        lc.on_tick(t + Duration::from_secs(11), &mut out);
        assert_eq!(out.reports[0].status(), Some(StationStatus::TimedOut));
        assert_eq!(out.reports[0].stats.count, 10);
        assert_eq!(lc.counters.input.chunks_unknown_station, 1);
        lc.on_chunk(chunk(2, 1, 10), t, &mut out);
        assert_eq!(lc.counters.input.chunks_after_close, 1);
    }

    #[test]
    fn shutdown_writes_partial_reports() {
        let (mut lc, mut out, t) = setup();
        lc.on_pose(&pose(4), t, &mut out);
        lc.on_chunk(chunk(4, 0, 10), t, &mut out);
        lc.shutdown(&mut out);
        assert_eq!(out.reports[0].status(), Some(StationStatus::Partial));
        assert_eq!(out.reports[0].stats.count, 10);
    }

    #[test]
    fn too_many_open_stations_close_the_least_recent_one() {
        let (mut lc, mut out, t) = setup();
        for (k, s) in [1u32, 2, 3].into_iter().enumerate() {
            lc.on_event(
                &event(StationEventKind::Begin, s, 0),
                t + Duration::from_millis(k as u64),
                &mut out,
            );
        }
        assert_eq!(lc.stations_open(), 2);
        assert_eq!(out.reports.len(), 1);
        assert_eq!(out.reports[0].station, 1);
        assert_eq!(out.reports[0].status(), Some(StationStatus::Incomplete));
    }

    #[test]
    fn a_bad_pose_is_rejected_and_the_station_waits_for_a_good_one() {
        let (mut lc, mut out, t) = setup();
        let mut p = pose(5);
        p.rotation_xyzw = [0.0, 0.0, 0.0, 3.0];
        lc.on_pose(&p, t, &mut out);
        assert_eq!(lc.counters.input.poses_invalid, 1);
        lc.on_chunk(chunk(5, 0, 10), t, &mut out);
        assert_eq!(lc.chunks_waiting(), 1);
        lc.on_pose(&pose(5), t, &mut out);
        assert_eq!(lc.chunks_waiting(), 0);
        assert_eq!(out.deviations.len(), 1);
    }

    #[test]
    fn a_new_printed_height_is_prepared_off_the_loop_while_its_chunks_wait() {
        let (mut lc, mut out, t) = setup();
        let mut begin = event(StationEventKind::Begin, 7, 2);
        // Cut at z = 0.3: the points 2 mm above the full cube's top are 0.202 m above the cap,
        // beyond the maximum distance.
        begin.printed_height = 0.3;
        lc.on_event(&begin, t, &mut out);
        lc.on_pose(&pose(7), t, &mut out);
        lc.on_chunk(chunk(7, 0, 50), t, &mut out);
        // The chunk waits for the design; the loop went on without preparing it.
        assert!(lc.is_preparing());
        assert!(out.deviations.is_empty());
        assert_eq!(lc.chunks_waiting(), 1);
        let waited = Instant::now();
        while lc.is_preparing() {
            assert!(waited.elapsed() < Duration::from_secs(10), "never prepared");
            std::thread::sleep(Duration::from_millis(1));
            lc.poll_designs(Instant::now(), &mut out);
        }
        assert_eq!(out.deviations.len(), 1, "the held chunk went through");
        lc.on_chunk(chunk(7, 1, 50), t, &mut out);
        lc.on_event(&event(StationEventKind::End, 7, 2), t, &mut out);
        assert_eq!(out.reports.len(), 1);
        assert_eq!(
            out.reports[0].no_match, 100,
            "compared with the cut, not the whole cube"
        );
        // A second station at the same height uses the prepared design at once.
        lc.on_event(&begin_at(8, 0.3), t, &mut out);
        lc.on_pose(&pose(8), t, &mut out);
        lc.on_chunk(chunk(8, 0, 10), t, &mut out);
        assert!(!lc.is_preparing());
        assert_eq!(out.deviations.len(), 3);
    }

    fn begin_at(station: u32, height: f64) -> StationEvent {
        let mut e = event(StationEventKind::Begin, station, 1);
        e.printed_height = height;
        e
    }

    fn with_attempt(mut c: Owned, attempt: u16) -> Owned {
        c.0.attempt = attempt;
        c
    }

    /// A Begin (from a service's history, or repeated) of a station attempt already reported
    /// opens nothing: the attempt is reported once.
    #[test]
    fn a_begin_of_a_reported_attempt_opens_nothing() {
        let (mut lc, mut out, t) = setup();
        begin_with_pose(&mut lc, &mut out, t, 5, 1);
        lc.on_chunk(chunk(5, 0, 10), t, &mut out);
        lc.on_event(&event(StationEventKind::End, 5, 1), t, &mut out);
        assert_eq!(out.reports.len(), 1);
        begin_with_pose(&mut lc, &mut out, t, 5, 1);
        lc.on_event(&event(StationEventKind::End, 5, 1), t, &mut out);
        assert_eq!(lc.stations_open(), 0);
        lc.on_tick(t + Duration::from_secs(60), &mut out);
        lc.shutdown(&mut out);
        assert_eq!(out.reports.len(), 1, "{:?}", out.reports);
    }

    /// The cell sends a station again as attempt 2: the open attempt 1 closes interrupted
    /// (adding nothing to findings), attempt 2 is processed on its own, and what attempt 1
    /// still sends is dropped and counted.
    #[test]
    fn a_second_attempt_replaces_the_first_and_late_chunks_of_the_first_are_dropped() {
        let (mut lc, mut out, t) = setup();
        begin_with_pose(&mut lc, &mut out, t, 2, 2);
        lc.on_chunk(chunk(2, 0, 10), t, &mut out);
        let mut begin = event(StationEventKind::Begin, 2, 2);
        begin.attempt = 2;
        lc.on_event(&begin, t, &mut out);
        let mut p = pose(2);
        p.attempt = 2;
        lc.on_pose(&p, t, &mut out);
        assert_eq!(out.reports.len(), 1);
        assert_eq!(out.reports[0].status(), Some(StationStatus::Interrupted));
        assert_eq!(out.reports[0].attempt, 1);
        lc.on_chunk(chunk(2, 1, 10), t, &mut out);
        assert_eq!(lc.counters.input.chunks_after_close, 1);
        lc.on_chunk(with_attempt(chunk(2, 0, 10), 2), t, &mut out);
        lc.on_chunk(with_attempt(chunk(2, 1, 10), 2), t, &mut out);
        let mut end = event(StationEventKind::End, 2, 2);
        end.attempt = 2;
        lc.on_event(&end, t, &mut out);
        assert_eq!(out.reports.len(), 2);
        let r = out.reports[1];
        assert_eq!((r.status(), r.attempt), (Some(StationStatus::Complete), 2));
        assert_eq!(r.stats.count, 20);
    }

    /// A chunk past the first of a station never begun: the station began before this agent
    /// started. It is dropped at once, not held for the station timeout, and the attempt is
    /// reported interrupted once, so the cell sends it again.
    #[test]
    fn a_station_that_began_before_the_agent_is_reported_interrupted_at_once() {
        let (mut lc, mut out, t) = setup();
        lc.on_chunk(chunk(9, 4, 10), t, &mut out);
        lc.on_chunk(chunk(9, 5, 10), t, &mut out);
        assert_eq!(lc.chunks_waiting(), 0);
        assert_eq!(out.reports.len(), 1);
        assert_eq!(out.reports[0].status(), Some(StationStatus::Interrupted));
        assert_eq!(lc.counters.input.chunks_unknown_station, 1);
        assert_eq!(lc.counters.input.chunks_after_close, 1);
        // Its End (and a Begin from history) change nothing.
        lc.on_event(&event(StationEventKind::End, 9, 6), t, &mut out);
        assert_eq!(out.reports.len(), 1);
    }

    /// An agent resuming its job closes what the agent before left open as interrupted; a
    /// reader of the recording does the same where the resumed agent said so.
    #[test]
    fn stations_left_open_are_interrupted_once() {
        let (mut lc, mut out, t) = setup();
        begin_with_pose(&mut lc, &mut out, t, 1, 3);
        lc.on_chunk(chunk(1, 0, 10), t, &mut out);
        assert_eq!(lc.interrupt_open(&mut out), vec![(1, 1)]);
        lc.interrupt(&event(StationEventKind::Begin, 1, 3), &mut out);
        assert_eq!(out.reports.len(), 1);
        assert_eq!(out.reports[0].status(), Some(StationStatus::Interrupted));
        // An attempt reported interrupted that was never open here is reported all the same.
        let mut begin = event(StationEventKind::Begin, 4, 0);
        begin.attempt = 2;
        begin.name = asbuilt_protocol::FixedText::truncated("L008-S4");
        lc.interrupt(&begin, &mut out);
        assert_eq!(out.reports.len(), 2);
        assert_eq!((out.reports[1].station, out.reports[1].attempt), (4, 2));
        assert_eq!(out.reports[1].name.as_str(), "L008-S4");
    }

    /// Outputs that keep reports, findings and the scan layer states.
    #[derive(Default)]
    struct WithStates {
        inner: Collect,
        findings: Vec<StationFindings>,
        states: Vec<asbuilt_core::scan_layer::ScanLayerState>,
    }
    impl Outputs for WithStates {
        fn deviations(
            &mut self,
            n: usize,
            fill: &mut dyn FnMut(&mut [PointDeviation]) -> DeviationHeader,
        ) {
            self.inner.deviations(n, fill)
        }
        fn report(&mut self, r: &StationReport) {
            self.inner.report(r)
        }
        fn findings(&mut self, f: &StationFindings) {
            self.findings.push(f.clone());
        }
        fn wants_scan_layer_state(&self) -> bool {
            true
        }
        fn scan_layer_state(
            &mut self,
            _: &StationReport,
            state: &asbuilt_core::scan_layer::ScanLayerState,
        ) {
            self.states.push(state.clone());
        }
    }

    fn with_findings() -> Lifecycle<Owned> {
        let (lc, _, _) = setup();
        let config = crate::config::FindingsConfig {
            enabled: true,
            ..Default::default()
        };
        lc.with_findings(FindingsStage::new(config, 0.005, 0.05, 100))
    }

    /// A station of 4 chunks of 100 points on the cube's top, 2 mm above it, shifted by `dx`.
    fn station_on_top(lc: &mut Lifecycle<Owned>, out: &mut WithStates, station: u32, dx: f32) {
        attempt_on_top(lc, out, (station, 1), dx, 4);
    }

    /// Attempt `key.1` of station `key.0` as [`station_on_top`] sends it, of which only the
    /// first `sent` chunks arrive; a station with chunks missing closes incomplete.
    fn attempt_on_top(
        lc: &mut Lifecycle<Owned>,
        out: &mut WithStates,
        (station, attempt): (u32, u8),
        dx: f32,
        sent: u64,
    ) {
        let t = Instant::now();
        let mut p = pose(station);
        p.translation = [0.0, 0.0, 2.0];
        p.attempt = attempt;
        let mut begin = event(StationEventKind::Begin, station, 4);
        begin.attempt = attempt;
        lc.on_event(&begin, t, out);
        lc.on_pose(&p, t, out);
        for seq in 0..sent {
            let pts = (0..100)
                .map(|i| {
                    let x = -0.45 + 0.009 * i as f32 + dx;
                    let y = -0.45 + 0.3 * seq as f32;
                    ScanPoint::new(x, y, -1.498)
                })
                .collect();
            let c = Owned(ChunkHeader::new(1, station, seq, 100), pts);
            lc.on_chunk(with_attempt(c, attempt.into()), t, out);
        }
        let mut end = event(StationEventKind::End, station, 4);
        end.attempt = attempt;
        lc.on_event(&end, t, out);
        lc.on_idle(t + END_GRACE, out);
    }

    /// A station whose first attempt got half its chunks through, reported incomplete and sent
    /// again, counts once in its scan layer: the findings after it and after the next station
    /// are those of a job whose station was complete the first time, bit for bit. An agent that
    /// takes the layer up from the state recorded after the incomplete attempt does the same.
    #[test]
    fn an_incomplete_attempt_sent_again_counts_once_in_the_findings() {
        let bytes = |f: &StationFindings| asbuilt_protocol::codec::encode(f);
        let mut clean = with_findings();
        let mut out_clean = WithStates::default();
        for (station, dx) in [(1, 0.0), (2, 0.004), (3, 0.002)] {
            station_on_top(&mut clean, &mut out_clean, station, dx);
        }
        let mut retried = with_findings();
        let mut out_retried = WithStates::default();
        station_on_top(&mut retried, &mut out_retried, 1, 0.0);
        attempt_on_top(&mut retried, &mut out_retried, (2, 1), 0.004, 2);
        let r = out_retried.inner.reports[1];
        assert_eq!(
            (r.status(), r.attempt),
            (Some(StationStatus::Incomplete), 1)
        );
        // The incomplete attempt's points are in the findings until the station comes again.
        assert_eq!(out_retried.findings[1].stations, 2);
        assert_ne!(
            bytes(&out_retried.findings[1]),
            bytes(&out_clean.findings[1])
        );
        attempt_on_top(&mut retried, &mut out_retried, (2, 2), 0.004, 4);
        station_on_top(&mut retried, &mut out_retried, 3, 0.002);
        assert_eq!(out_retried.findings.len(), 4);
        for (a, b) in [(2, 1), (3, 2)] {
            assert_eq!(
                bytes(&out_retried.findings[a]),
                bytes(&out_clean.findings[b])
            );
            assert_eq!(out_retried.states[a], out_clean.states[b]);
        }

        // Killed after the incomplete attempt: the next agent takes up the state recorded after
        // it, and the one before it, and goes on as the agent that never stopped.
        let mut resumed = with_findings();
        let mut out_resumed = WithStates::default();
        let (after, before) = (&out_retried.states[1], &out_retried.states[0]);
        resumed
            .restore_scan_layer(1, f64::NAN, after, Some((2, Some(before))))
            .unwrap();
        resumed.remember_reported((1, 2), 1, 0);
        attempt_on_top(&mut resumed, &mut out_resumed, (2, 2), 0.004, 4);
        station_on_top(&mut resumed, &mut out_resumed, 3, 0.002);
        assert_eq!(out_resumed.findings.len(), 2);
        assert_eq!(
            bytes(&out_resumed.findings[1]),
            bytes(&out_clean.findings[2])
        );

        // A station that was the scan layer's first goes back to the layer's start.
        let mut first = with_findings();
        let mut out_first = WithStates::default();
        attempt_on_top(&mut first, &mut out_first, (1, 1), 0.0, 1);
        attempt_on_top(&mut first, &mut out_first, (1, 2), 0.0, 4);
        assert_eq!(bytes(&out_first.findings[1]), bytes(&out_clean.findings[0]));
    }

    /// An agent that takes up a scan layer from the state recorded after its second station
    /// draws, after the third, the findings of the agent that never stopped, bit for bit.
    #[test]
    fn a_scan_layer_taken_up_from_its_state_goes_on_as_if_never_stopped() {
        let mut a = with_findings();
        let mut out_a = WithStates::default();
        for (station, dx) in [(1, 0.0), (2, 0.004)] {
            station_on_top(&mut a, &mut out_a, station, dx);
        }
        assert_eq!(out_a.states.len(), 2, "{:?}", out_a.inner.reports);
        let saved = out_a.states[1].clone();
        assert_eq!(saved.stations, 2);
        let encoded = postcard::to_allocvec(&saved).unwrap();
        let decoded: asbuilt_core::scan_layer::ScanLayerState =
            postcard::from_bytes(&encoded).unwrap();
        assert_eq!(decoded, saved);

        let mut b = with_findings();
        let mut out_b = WithStates::default();
        b.restore_scan_layer(1, f64::NAN, &decoded, None).unwrap();
        station_on_top(&mut a, &mut out_a, 3, 0.002);
        station_on_top(&mut b, &mut out_b, 3, 0.002);
        let bytes = |f: &StationFindings| asbuilt_protocol::codec::encode(f);
        assert_eq!(out_a.findings.len(), 3);
        assert_eq!(out_b.findings.len(), 1);
        assert_eq!(bytes(&out_a.findings[2]), bytes(&out_b.findings[0]));
        assert_eq!(out_a.states[2], out_b.states[0]);
        assert_eq!(out_b.findings[0].stations, 3);
        // A state of another design does not fit, and says so.
        let mut other = saved.clone();
        other.samples += 1;
        assert!(
            with_findings()
                .restore_scan_layer(1, f64::NAN, &other, None)
                .is_err()
        );
    }
}
