//! Stations from begin to report: which chunks belong where, when a station may close, and what
//! is counted when something is wrong. No I/O: chunks come in through [`ChunkSource`] and
//! results go out through [`Outputs`], so the daemon feeds this from shared memory and the tests
//! feed it from plain vectors. Synchronous, but for one thing: a printed height's design is
//! prepared on a worker thread (`heights.rs`), so that a new height never stalls the loop.
//!
//! In parts: what each message means (`inputs.rs`), the open stations and the chunks that wait
//! for them (`slots.rs`), printed heights (`heights.rs`), closing a station with its report,
//! findings, advice and survey (`close.rs`), and taking a job up again after a restart
//! (`restore.rs`).
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
    AgentStatus, ChunkHeader, DeviationHeader, InputRejects, LayerApplied, LayerCorrection,
    Message, PointDeviation, PoseSnapshot, RejectCounts, ScanPoint, StationEvent, StationEventKind,
    StationFindings, StationReport, StationStatus,
};

use crate::attempts::{ClosedStations, StationKey, attempt_of};
use crate::findings::FindingsStage;

use crate::sequence::{ChunkVerdict, SequenceTracker};
use crate::{info, warn};

mod close;
mod heights;
mod inputs;
mod prints;
mod profiles;
mod restore;
mod slots;
#[cfg(test)]
mod tests;

use close::attempt_text;
use heights::Preparation;
pub use inputs::Input;
use slots::{CLOSED_MEMORY, OpenStation, Pending};

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
    /// Where a line profiler's sensor was (design frame) at the last profile of a batch of pass
    /// `key` (of layer `layer`) just compared: the view follows it.
    fn pass_sensor(&mut self, _key: StationKey, _layer: u32, _sensor: &nalgebra::Isometry3<f64>) {}
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

impl From<&crate::config::Limits> for LifecycleLimits {
    /// What the station lifecycle needs of the agent's `[limits]`.
    fn from(l: &crate::config::Limits) -> Self {
        Self {
            max_points_per_chunk: l.max_points_per_chunk,
            pending_chunks: l.pending_chunks,
            open_stations: l.open_stations,
            station_timeout: l.station_timeout(),
        }
    }
}

/// How long a station that said it is done, with chunks missing, stays open while the queues are
/// empty. Its End travels on another service than its chunks, possibly from another process (the
/// robot controller while the scanner driver still sends): chunks sent just before it must not
/// arrive to a closed station and be lost. The event loop wakes at least every 250 ms, so an
/// incomplete station is reported within about half a second of its End.
pub const END_GRACE: Duration = Duration::from_millis(200);

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

/// Every station of every job from Begin to report: poses, chunks in order, timeouts, the
/// printed design of each height, the findings after each report. Synchronous (only a printed
/// height is prepared on a worker thread): the daemon feeds it messages and the time, a
/// recording's reader does the same.
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
    /// The print each recent job number names.
    prints: prints::Prints,
    /// A line profiler's poses and the profiles waiting for them.
    profiler: profiles::Profiler,
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
            prints: prints::Prints::default(),
            profiler: profiles::Profiler::new(Default::default()),
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
}
