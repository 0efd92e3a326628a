//! The event loop: wait on the inbox with a WaitSet (no polling, no sleeps), drain the input
//! queues into the station lifecycle, and on a fixed tick close silent stations, clean up after
//! dead publishers and publish the agent's status.

use std::sync::Arc;
use std::time::{Duration, Instant};

use asbuilt_core::Design;
use asbuilt_core::printed::PrintedDesigns;
use asbuilt_core::station::InspectParams;
use asbuilt_protocol::{
    AgentState, AgentStatus, ChunkHeader, OutputDrops, PoseSnapshot, ScanPoint, StationEvent,
    StationEventKind, unix_time_ns,
};
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use iceoryx2_bb_posix::signal::SignalHandler;

use crate::config::AgentConfig;
pub use crate::error::AgentError;
use crate::fanout::Fanout;
use crate::findings::FindingsStage;
use crate::lifecycle::{ChunkSource, Input, Lifecycle, LifecycleLimits, Outputs};
use crate::recorder::{Lent, Recorder};
use crate::resume::Resumed;
use crate::{error, info, warn};
use asbuilt_protocol::ipc::{AgentPorts, ChunkSample, Ipc, IpcError, QueueSizes, ServiceNames};
use asbuilt_viewer::{View, Viewer, ViewerParams};

/// Station timeouts are checked this often at least.
const MAX_TICK: Duration = Duration::from_millis(250);
/// How often the loop looks for a printed height prepared on a worker thread.
const PREPARING_POLL: Duration = Duration::from_millis(2);

/// What a run did, for the exit message.
#[derive(Debug, Clone, Copy)]
pub struct RunSummary {
    /// Stations reported over the run.
    pub stations_reported: u64,
    /// Points of accepted chunks processed over the run.
    pub points_processed: u64,
}

/// A chunk the agent takes: live, still in shared memory, or read back from its recording
/// when it resumes a job.
pub enum AgentChunk {
    /// Received from the scanner's service.
    Live(LiveChunk),
    /// Read back from the recording.
    Recorded(ChunkHeader, Vec<ScanPoint>),
}

impl From<(ChunkHeader, Vec<ScanPoint>)> for AgentChunk {
    fn from((h, p): (ChunkHeader, Vec<ScanPoint>)) -> Self {
        Self::Recorded(h, p)
    }
}

impl ChunkSource for AgentChunk {
    fn header(&self) -> &ChunkHeader {
        match self {
            Self::Live(s) => s.sample().user_header(),
            Self::Recorded(h, _) => h,
        }
    }
    fn points(&self) -> &[ScanPoint] {
        match self {
            Self::Live(s) => s.sample().payload(),
            Self::Recorded(_, p) => p,
        }
    }
}

/// A scan chunk in shared memory; when the recorder's writer reads it there too, the sample
/// goes back to the recorder instead of the scanner once the lifecycle lets it go.
pub struct LiveChunk {
    /// Always there until the chunk is dropped.
    sample: Option<ChunkSample>,
    lent: Option<Lent<ChunkSample>>,
}

impl LiveChunk {
    fn new(sample: ChunkSample, lent: Option<Lent<ChunkSample>>) -> Self {
        Self {
            sample: Some(sample),
            lent,
        }
    }

    fn sample(&self) -> &ChunkSample {
        self.sample
            .as_ref()
            .expect("a live chunk keeps its sample until it is dropped")
    }
}

impl Drop for LiveChunk {
    fn drop(&mut self) {
        if let (Some(sample), Some(lent)) = (self.sample.take(), self.lent.take()) {
            lent.give_back(sample);
        }
    }
}

/// Runs the agent until SIGINT or SIGTERM. Returns after every open station got its report.
pub fn run(config: &AgentConfig) -> Result<RunSummary, AgentError> {
    // Install the termination handler before the long design load, so a stop request during
    // start-up is seen instead of killing the process.
    let _ = SignalHandler::termination_requested();
    set_log_level_from_env_or(LogLevel::Error);
    let started = Instant::now();

    let loaded = crate::design::load(config, started)?;
    let (node, ports, dead_nodes) = open_ports(config)?;
    let limits = &config.limits;
    let design = loaded.designs.whole_design().clone();
    let mut lifecycle = make_lifecycle(config, loaded.designs);
    let mut resumed = resume(config, &mut lifecycle);
    let mut out = Fanout::new(
        &ports,
        (
            start_recorder(
                config,
                design,
                loaded.file,
                resumed.as_ref().and_then(|r| r.print),
            )?,
            start_viewer(config, loaded.view)?,
        ),
        &config.frames,
        limits.max_points_per_chunk,
        config.recorder.resume && config.findings.enabled,
    );
    let recovering = resumed
        .as_mut()
        .and_then(|r| finish_resume(r, &mut lifecycle, &mut out));

    let tick = config.status.period().min(MAX_TICK);
    let waitset = WaitSetBuilder::new()
        .create::<Ipc>()
        .map_err(|e| IpcError::iceoryx("cannot create the wait set", e))?;
    let _inbox_guard = waitset
        .attach_notification(&ports.inbox)
        .map_err(|e| IpcError::iceoryx("cannot wait on the inbox", e))?;
    let _tick_guard = waitset
        .attach_interval(tick)
        .map_err(|e| IpcError::iceoryx("cannot attach the tick", e))?;

    info!(
        "serving {}/… (chunks up to {} points, {} queued, {} held for a pose; station timeout \
         {:.0} s), {:.2} s after start",
        config.services.prefix,
        limits.max_points_per_chunk,
        limits.chunk_queue,
        limits.pending_chunks,
        limits.station_timeout_s,
        started.elapsed().as_secs_f64()
    );
    let mut status = StatusReporter {
        started,
        period: config.status.period(),
        next: Instant::now() + config.status.period(),
        last_points: 0,
        last_at: Instant::now(),
        dead_nodes,
    };
    // At once, not after a period: a cell learns that this agent (a new process id) serves.
    status.publish(&ports, &lifecycle, &out, AgentState::Serving);
    let held = serve(&waitset, &node, &mut lifecycle, &mut out, &mut status);

    let summary = shut_down(lifecycle, out, held, &mut status, started);
    join(
        recovering,
        "resume: recovering unfinished files failed; the next start tries again",
    );
    join(
        loaded.caching,
        "design: caching the index failed; the next start indexes again",
    );
    Ok(summary)
}

/// The loop: waits on the inbox and the tick, drains the inputs into the lifecycle, closes
/// silent stations, publishes reports once on disk and the status on its period, until a stop
/// is requested. Returns what it still holds, for the shutdown.
fn serve(
    waitset: &WaitSet<Ipc>,
    node: &Node<Ipc>,
    lifecycle: &mut AgentLifecycle,
    out: &mut Fanout<'_>,
    status: &mut StatusReporter,
) -> HeldControl {
    let ports = out.ports;
    let mut terminated = false;
    let mut held = HeldControl::default();
    let mut more = false;
    while !terminated {
        // While a printed height is prepared off the loop, or a report waits for the recorder to
        // have it on disk, wake often to take it up at once;
        // with chunks still queued after a slice of reading, do not wait at all.
        let result = if more {
            Ok(WaitSetRunResult::AllEventsHandled)
        } else if lifecycle.is_preparing() || !out.unpublished.is_empty() {
            waitset.wait_and_process_once_with_timeout(
                |_| CallbackProgression::Continue,
                PREPARING_POLL,
            )
        } else {
            waitset.wait_and_process_once(|_| CallbackProgression::Continue)
        };
        match result {
            Ok(WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) => break,
            Ok(_) => {}
            Err(e) => {
                error!("wait set failed: {e:?}; stopping");
                break;
            }
        }
        // Clear the wake-ups before reading, so data that arrives while we read wakes us again.
        if let Err(e) = ports.inbox.try_wait(|_| {}) {
            warn!("inbox: {e:?}");
        }
        lifecycle.poll_designs(Instant::now(), out);
        let drained = held.drain(lifecycle, out);
        terminated = drained == Drained::Stop;
        more = drained == Drained::More;
        let now = Instant::now();
        lifecycle.on_tick(now, out);
        out.publish_durable(false);
        if now >= status.next {
            status.dead_nodes += cleanup_dead_nodes(node);
            let state = if out.held_by_disk() {
                AgentState::HeldByDisk
            } else {
                AgentState::Serving
            };
            status.publish(ports, lifecycle, out, state);
        }
    }
    held
}

/// Waits for a helper thread (its work is done or safely cut short); says `failed` if it
/// panicked.
fn join(thread: Option<std::thread::JoinHandle<()>>, failed: &str) {
    if let Some(t) = thread
        && t.join().is_err()
    {
        warn!("{failed}");
    }
}

/// The node and the agent's services; also how many dead nodes of an earlier run were cleaned.
fn open_ports(config: &AgentConfig) -> Result<(Node<Ipc>, AgentPorts, u64), AgentError> {
    let node = NodeBuilder::new()
        .name(&"asbuilt-agent".try_into().expect("valid node name"))
        .create::<Ipc>()
        .map_err(|e| IpcError::iceoryx("cannot create the iceoryx2 node", e))?;
    let dead_nodes = node.try_cleanup_dead_nodes().cleanups;
    if dead_nodes > 0 {
        info!("removed the resources of {dead_nodes} dead iceoryx2 node(s) from an earlier run");
    }
    let names = ServiceNames::new(&config.services.prefix);
    let limits = &config.limits;
    let ports = AgentPorts::create(
        &node,
        &names,
        QueueSizes {
            max_points_per_chunk: limits.max_points_per_chunk,
            chunk_queue: limits.chunk_queue,
            pending_chunks: limits.pending_chunks,
            // Whether or not this run records: the services' settings stay the same.
            lent_chunks: crate::recorder::LENT_CHUNKS,
        },
    )?;
    Ok((node, ports, dead_nodes))
}

/// The lifecycle of stations over chunks still in shared memory (or read back on resuming).
type AgentLifecycle = Lifecycle<AgentChunk>;

/// Takes up the newest recorded job (`[recorder] resume`): see [`crate::resume`].
fn resume(config: &AgentConfig, lifecycle: &mut AgentLifecycle) -> Option<Resumed> {
    let dir = config
        .recorder
        .dir
        .as_ref()
        .filter(|_| config.recorder.resume)?;
    let started = Instant::now();
    let folder = crate::resume::scan_folder(dir);
    let mut resumed = crate::resume::replay_job(&folder.files, lifecycle)?;
    resumed.unfinished = folder.unfinished;
    for u in &resumed.unreadable {
        warn!("resume: {u}");
    }
    if config.recorder.scan_every != 1 {
        warn!(
            "resume: recorder.scan_every = {}: the recording holds part of the scan chunks, so \
             the current scan layer's findings go on from part of its points",
            config.recorder.scan_every
        );
    }
    let layer = match resumed.state_bytes {
        Some(bytes) => format!(
            "the current scan layer taken up from its recorded state ({:.1} MB)",
            bytes as f64 / 1e6
        ),
        None if resumed.stations_replayed == 0 => {
            "no station of the current scan layer to take up".to_string()
        }
        None => format!(
            "{} station(s) of the current scan layer replayed ({} points)",
            resumed.stations_replayed, resumed.points_replayed
        ),
    };
    info!(
        "resume: job {} from {} file(s): {} report(s) recorded; {layer}; in {:.2} s",
        resumed.job,
        resumed.files,
        resumed.recorded.len(),
        started.elapsed().as_secs_f64()
    );
    // The replay's counts are not this run's work.
    lifecycle.counters = Default::default();
    Some(resumed)
}

/// Reports, with the real outputs, what the agent before left undone: the reports it never had
/// on disk, the stations it had open (interrupted: the cell sends them again), and every
/// recorded report once more, since the cell may not have had them. Then starts rewriting the
/// files whose writer died (every channel kept) on a thread of their own, while the agent
/// serves: the resume read them as they are.
fn finish_resume(
    r: &mut Resumed,
    lifecycle: &mut AgentLifecycle,
    out: &mut Fanout<'_>,
) -> Option<std::thread::JoinHandle<()>> {
    out.redraw(r);
    for report in &r.unrecorded {
        info!(
            "resume: job {} station {} attempt {} was closed but its report never recorded; \
             reporting it now",
            report.job, report.station, report.attempt
        );
        out.report(report);
    }
    if let Some(report) = &r.findings_due {
        info!(
            "resume: job {} station {}: its findings (or the advice after them) never made it \
             to disk; drawn again from the scan layer's state",
            report.job, report.station
        );
        lifecycle.findings_after(report, out);
    }
    let mut open = lifecycle.interrupt_open(out);
    for begin in &r.open {
        lifecycle.interrupt(begin, out);
        let key = (begin.job, begin.station);
        if !open.contains(&key) {
            open.push(key);
        }
    }
    for (job, station) in open {
        warn!(
            "resume: job {job} station {station} was open when the agent before stopped; \
             reported interrupted, for the cell to send it again"
        );
    }
    // The reports' service keeps a short history; the latest are the ones a cell may lack.
    let skip = r.recorded.len().saturating_sub(REPUBLISHED);
    for report in &r.recorded[skip..] {
        out.publish(&crate::fanout::Outgoing::Report(Box::new(*report)));
    }
    let unfinished = std::mem::take(&mut r.unfinished);
    if unfinished.is_empty() {
        return None;
    }
    std::thread::Builder::new()
        .name("recover".into())
        .spawn(move || crate::resume::recover_files(&unfinished))
        .map_err(|e| warn!("resume: cannot start recovering the unfinished files: {e}"))
        .ok()
}

/// How many of the latest recorded reports are published again on resuming.
const REPUBLISHED: usize = 32;

fn make_lifecycle(config: &AgentConfig, designs: PrintedDesigns) -> AgentLifecycle {
    let limits = &config.limits;
    let mut inspect = InspectParams::with_tolerance(config.inspect.tolerance);
    inspect.max_range = config.inspect.max_range;
    let designs_full = designs.full().clone();
    if config.findings.enabled {
        // Findings keep M3C2 cylinders off sharp edges: find the whole design's at start-up,
        // not on the event loop (a printed height's are found where it is prepared).
        designs.full().sharp_edges();
    }
    let mut lifecycle: AgentLifecycle = Lifecycle::new(
        designs,
        config.frames.clone(),
        inspect,
        LifecycleLimits::from(limits),
    )
    .with_profiler(config.profiler.clone());
    if config.findings.enabled {
        let f = &config.findings;
        info!(
            "findings: on, design samples every {:.1} mm, M3C2 cylinders {:.1} mm wide, {}",
            f.spacing * 1e3,
            f.projection_diameter() * 1e3,
            f.layer_height
                .map_or("no layer height (no per-layer rows)".to_string(), |h| {
                    format!("layers of {:.1} mm", h * 1e3)
                })
        );
        let crew = config.verdict_limits();
        lifecycle = lifecycle.with_findings(
            FindingsStage::new(
                f.clone(),
                config.inspect.tolerance,
                config.inspect.max_distance(),
                limits.max_points_per_chunk,
            )
            .judged_by(crew),
        );
    }
    // Checked at start: a standard that does not parse was refused there.
    let flatness = config.tolerances.flatness().ok().flatten();
    let dimensions = config.tolerances.dimensions().ok().flatten();
    let rule = config.tolerances.decision_rule().unwrap_or_default();
    lifecycle = lifecycle.with_survey(crate::survey::Survey::new(
        designs_full.design(),
        flatness,
        dimensions,
        rule,
    ));
    if config.corrections.enabled {
        let c = &config.corrections;
        info!(
            "corrections: on, at most {:.1} mm a layer, flow {:.2}..{:.2}, path {:.0} mm, deadband \
             {:.1} mm, {}",
            c.max_z_per_layer * 1e3,
            c.flow_min,
            c.flow_max,
            c.max_path_offset * 1e3,
            c.deadband * 1e3,
            c.bead_width
                .map_or("no bead width (no flow advice)".to_string(), |b| {
                    format!("bead {:.1} mm", b * 1e3)
                })
        );
        lifecycle = lifecycle.with_corrections(c.limits());
    }
    lifecycle
}

/// Starts the recorder (when `[recorder]` names a folder), going on with the files of the print
/// a resume took up.
fn start_recorder(
    config: &AgentConfig,
    design: Arc<Design>,
    file: Vec<u8>,
    resumed: Option<crate::recorder::PrintFiles>,
) -> Result<Option<Recorder>, AgentError> {
    Ok(match &config.recorder.dir {
        Some(dir) => {
            let r = Recorder::start(
                &config.recorder,
                job_metadata(config),
                (&config.design.path, file),
                design,
                crate::recorder::ShownAs {
                    tolerance: config.inspect.tolerance,
                    t_design_base: config.frames.t_design_base,
                    clock_offset_ns: config.profiler.clock_offset_ns,
                },
            )
            .map_err(|source| AgentError::Recorder {
                dir: dir.clone(),
                source,
            })?;
            if let Some(print) = resumed {
                r.continues(print);
            }
            info!(
                "recording every job to {} (files up to {} MB, every {} scan chunk(s))",
                dir.display(),
                config.recorder.max_file_mb,
                config.recorder.scan_every
            );
            Some(r)
        }
        None => None,
    })
}

fn start_viewer(
    config: &AgentConfig,
    design_view: Option<crate::design::DesignView>,
) -> Result<Option<Viewer>, AgentError> {
    Ok(
        if config.viewer.rrd.is_some() || config.viewer.url.is_some() {
            let v = Viewer::start(ViewerParams {
                rrd: config.viewer.rrd.clone(),
                // The agent runs for as long as the cell prints: see the field.
                footer: false,
                url: config.viewer.url.clone(),
                max_points_per_station: config.viewer.max_points_per_station,
                queue: config.viewer.queue,
                tolerance: config.inspect.tolerance,
                warn: |args| crate::log::line(crate::log::Level::Warn, args),
                job: asbuilt_viewer::Job::Printing {
                    corrections: config.corrections.enabled,
                },
                limits: Some(config.verdict_limits()),
            })?;
            if let Some((vertices, triangles)) = design_view {
                v.show(View::Design {
                    vertices,
                    triangles,
                });
            }
            info!(
                "viewer: {}{}{} (up to {} points per station)",
                config
                    .viewer
                    .rrd
                    .as_ref()
                    .map(|p| p.display().to_string())
                    .unwrap_or_default(),
                if config.viewer.rrd.is_some() && config.viewer.url.is_some() {
                    " and "
                } else {
                    ""
                },
                config.viewer.url.clone().unwrap_or_default(),
                config.viewer.max_points_per_station
            );
            Some(v)
        } else {
            None
        },
    )
}

/// Closes every open station with a partial report, says so, and closes the view and the
/// recorder, publishing the reports that waited for the disk.
fn shut_down(
    mut lifecycle: AgentLifecycle,
    mut out: Fanout<'_>,
    mut held: HeldControl,
    status: &mut StatusReporter,
    started: Instant,
) -> RunSummary {
    let ports = out.ports;
    info!("stop requested: closing open stations with partial reports");
    if let Some(c) = held.chunk.take() {
        let chunk = AgentChunk::Live(LiveChunk::new(c, None));
        lifecycle.take(Input::Chunk(chunk), Instant::now(), &mut out);
    }
    lifecycle.shutdown(&mut out);
    status.publish(ports, &lifecycle, &out, AgentState::ShuttingDown);
    if let Some(mut v) = out.viewer.take() {
        v.finish();
        let dropped = v.dropped.load(std::sync::atomic::Ordering::Relaxed);
        info!("viewer: closed ({dropped} item(s) dropped while the viewer was behind)");
    }
    if let Some(mut r) = out.recorder.take() {
        r.finish();
        // Everything is on disk now.
        out.recorder = None;
        out.publish_durable(true);
        use std::sync::atomic::Ordering::Relaxed;
        info!(
            "recorder: {} file(s), {} scan chunks recorded, {} left out (queue or disk), {} \
             skipped by scan_every",
            r.counters.files.load(Relaxed),
            r.counters.chunks_recorded.load(Relaxed),
            r.counters.chunks_dropped.load(Relaxed),
            r.counters.chunks_decimated.load(Relaxed)
        );
    }
    let c = lifecycle.counters;
    info!(
        "stopped after {:.1} s: {} stations reported, {} points processed",
        started.elapsed().as_secs_f64(),
        c.stations_reported,
        c.points_processed
    );
    RunSummary {
        stations_reported: c.stations_reported,
        points_processed: c.points_processed,
    }
}

/// A Begin or pose for a new station that arrived while every station slot was taken. It waits
/// here, and its queue is not read further, until a slot frees (a station completes or times
/// out): a publisher running ahead of the agent is held back by its full queue instead of
/// forcing open stations closed before their chunks, still queued, are read.
///
/// A chunk of such a station waits here too, and the chunk queue is not read further: the
/// publisher is held back by its full queue instead of its chunks being pushed out of the
/// bounded buffer of chunks waiting for a pose.
#[derive(Default)]
struct HeldControl {
    event: Option<StationEvent>,
    pose: Option<PoseSnapshot>,
    chunk: Option<ChunkSample>,
    /// A profile chunk whose pass waits for its printed design.
    profiles: Option<asbuilt_protocol::ipc::ProfileSample>,
}

/// How a pass over the input queues ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Drained {
    /// Every queue is empty (or what is left waits for its station).
    Empty,
    /// A slice of reading is over with chunks still queued: the loop does its periodic work
    /// (timeouts, prepared heights, the status) and comes straight back.
    More,
    /// A stop was requested.
    Stop,
}

/// How long one pass reads before the loop's periodic work gets a turn, so health lines keep
/// their period while a cell streams without a pause.
const DRAIN_SLICE: Duration = Duration::from_millis(100);

impl HeldControl {
    fn waits_for_a_slot(&self) -> bool {
        self.event.is_some() || self.pose.is_some()
    }

    /// Reads every queue until all are empty, or for at most [`DRAIN_SLICE`]. Station events
    /// and poses go first, and again before any chunk whose station is not ready, because the
    /// cell sends a station's Begin and pose before its chunks but on other services. What
    /// cannot be taken yet is held here.
    fn drain(&mut self, lifecycle: &mut AgentLifecycle, out: &mut Fanout<'_>) -> Drained {
        let ports = out.ports;
        let deadline = Instant::now() + DRAIN_SLICE;
        loop {
            let mut any = self.drain_control(lifecycle, out);
            loop {
                let sample = match self.chunk.take() {
                    Some(s) => s,
                    None => match ports.chunks.receive() {
                        Ok(Some(s)) => s,
                        Ok(None) => break,
                        Err(e) => {
                            warn!("scan chunks: {e:?}");
                            break;
                        }
                    },
                };
                if !lifecycle.is_ready_for(sample.user_header()) {
                    any |= self.drain_control(lifecycle, out);
                    // A station waiting for a slot or for its printed design: leave the queue
                    // unread, so the cell is held back instead of its chunks pushed out.
                    let waits =
                        self.waits_for_a_slot() || lifecycle.awaits_design(sample.user_header());
                    if waits && !lifecycle.is_ready_for(sample.user_header()) {
                        self.chunk = Some(sample);
                        break;
                    }
                }
                any = true;
                let lent = out.took_chunk(&sample);
                let now = Instant::now();
                let chunk = AgentChunk::Live(LiveChunk::new(sample, lent));
                lifecycle.take(Input::Chunk(chunk), now, out);
                if SignalHandler::termination_requested() {
                    return Drained::Stop;
                }
                if now >= deadline {
                    return Drained::More;
                }
            }
            match self.drain_profiles(lifecycle, out, deadline) {
                Drained::Empty => {}
                stop_or_more => return stop_or_more,
            }
            if !any {
                break;
            }
        }
        lifecycle.on_idle(Instant::now(), out);
        Drained::Empty
    }

    /// Reads a line profiler's chunks, with the robot's mount poses before each (a profile
    /// waits for the pose after it), until the queue is empty ([`Drained::Empty`]) or the
    /// slice is over.
    fn drain_profiles(
        &mut self,
        lifecycle: &mut AgentLifecycle,
        out: &mut Fanout<'_>,
        deadline: Instant,
    ) -> Drained {
        let ports = out.ports;
        loop {
            self.drain_mount_poses(lifecycle, out);
            let sample = match self.profiles.take() {
                Some(s) => s,
                None => match ports.profiles.receive() {
                    Ok(Some(s)) => s,
                    Ok(None) => return Drained::Empty,
                    Err(e) => {
                        warn!("profile chunks: {e:?}");
                        return Drained::Empty;
                    }
                },
            };
            let (h, points) = (sample.user_header(), sample.payload());
            // A pass's Begin, sent before its profiles on another service.
            if !lifecycle.pass_is_ready(h.job, h.pass) {
                self.drain_control(lifecycle, out);
            }
            // A pass waiting for its printed design: the queue is left unread, so the cell is
            // held back instead of the pass's points piling up.
            if lifecycle.pass_awaits_design(h.job, h.pass) {
                self.profiles = Some(sample);
                return Drained::Empty;
            }
            out.took_profiles(h, points);
            let now = Instant::now();
            lifecycle.on_profiles(h, points, now, out);
            drop(sample);
            if SignalHandler::termination_requested() {
                return Drained::Stop;
            }
            if now >= deadline {
                return Drained::More;
            }
        }
    }

    /// Reads the robot's mount poses until their queue is empty.
    fn drain_mount_poses(&mut self, lifecycle: &mut AgentLifecycle, out: &mut Fanout<'_>) {
        while let Some(m) = next(&out.ports.mount_poses, "mount poses") {
            out.took_mount_pose(&m);
            lifecycle.on_mount_pose(&m, Instant::now(), out);
        }
    }

    /// Reads the printer's answers, station events, then poses, until their queues are empty or
    /// a new station finds no slot; whether anything was read.
    fn drain_control(&mut self, lifecycle: &mut AgentLifecycle, out: &mut Fanout<'_>) -> bool {
        let ports = out.ports;
        let mut any = false;
        // The printer's answers first: the advice after the next station builds on them.
        while let Some(a) = next(&ports.applied, "applied layers") {
            any = true;
            out.took_applied(&a);
            lifecycle.take(Input::Applied(a), Instant::now(), out);
        }
        any |= self.drain_events(lifecycle, out);
        self.drain_mount_poses(lifecycle, out);
        let mut poses = false;
        while let Some(p) = self.pose.take().or_else(|| next(&ports.poses, "poses")) {
            if !lifecycle.has_room_for(p.job, p.station) {
                self.pose = Some(p);
                break;
            }
            poses = true;
            out.took_pose(&p, lifecycle.layer_of(p.job, p.station));
            lifecycle.take(Input::Pose(p), Instant::now(), out);
        }
        // A Begin sent just before its pose may have reached its queue after the events were
        // read: it is there now that the pose was. Read before the station's chunks, so that
        // none is compared before its Begin said the station's name and printed height.
        if poses {
            self.drain_events(lifecycle, out);
        }
        any | poses
    }

    /// Reads station events until their queue is empty or a Begin finds no slot; whether
    /// anything was read.
    fn drain_events(&mut self, lifecycle: &mut AgentLifecycle, out: &mut Fanout<'_>) -> bool {
        let mut any = false;
        while let Some(ev) = self
            .event
            .take()
            .or_else(|| next(&out.ports.stations, "station events"))
        {
            let begins = ev.kind() == Some(StationEventKind::Begin);
            if begins && !lifecycle.has_room_for(ev.job, ev.station) {
                self.event = Some(ev);
                break;
            }
            any = true;
            out.took_event(&ev);
            lifecycle.take(Input::Event(ev), Instant::now(), out);
        }
        any
    }
}

/// The next message of a queue, copied out of shared memory.
fn next<T: Copy + std::fmt::Debug + iceoryx2::prelude::ZeroCopySend>(
    queue: &iceoryx2::port::subscriber::Subscriber<Ipc, T, ()>,
    what: &str,
) -> Option<T> {
    match queue.receive() {
        Ok(Some(m)) => Some(*m.payload()),
        Ok(None) => None,
        Err(e) => {
            warn!("{what}: {e:?}");
            None
        }
    }
}

fn cleanup_dead_nodes(node: &Node<Ipc>) -> u64 {
    let c = node.try_cleanup_dead_nodes();
    if c.cleanups > 0 {
        info!(
            "removed the resources of {} dead iceoryx2 node(s) (a publisher that died)",
            c.cleanups
        );
    }
    if c.failed_cleanups > 0 {
        warn!(
            "{} dead iceoryx2 node(s) could not be cleaned up",
            c.failed_cleanups
        );
    }
    c.cleanups
}

/// The periodic status message and health line, and what they are computed from.
struct StatusReporter {
    started: Instant,
    period: Duration,
    next: Instant,
    last_points: u64,
    last_at: Instant,
    /// Dead iceoryx2 nodes removed since start.
    dead_nodes: u64,
}

impl StatusReporter {
    fn publish(
        &mut self,
        ports: &AgentPorts,
        lifecycle: &AgentLifecycle,
        out: &Fanout<'_>,
        state: AgentState,
    ) {
        use std::sync::atomic::Ordering::Relaxed;
        let now = Instant::now();
        let mut s = AgentStatus::new(std::process::id());
        s.state = state as u8;
        s.timestamp_ns = unix_time_ns();
        s.uptime_ns = self.started.elapsed().as_nanos() as u64;
        lifecycle.fill_status(&mut s);
        let dt = now.duration_since(self.last_at).as_secs_f64();
        if dt > 0.0 {
            s.points_per_second = (s.points_processed - self.last_points) as f64 / dt;
        }
        s.dead_nodes_cleaned = self.dead_nodes;
        s.output = OutputDrops {
            deviation_chunks: ports.deviation_drops.load(Relaxed),
            reports: ports.report_drops.load(Relaxed),
            deviation_chunks_unloaned: out.unloaned,
        };
        self.last_points = s.points_processed;
        self.last_at = now;
        self.next = now + self.period;
        out.status(&s);
        log_health(&s);
    }
}

fn log_health(s: &AgentStatus) {
    let reasons: Vec<String> = s
        .input
        .by_reason()
        .iter()
        .map(|(reason, n)| format!("{reason} {n}"))
        .collect();
    info!(
        "health: {:.2} M points/s, {} points, {} chunks, {} stations open, {} chunks waiting for \
         a pose, {} reported; rejected points {}; rejected inputs {} ({}); outputs missed by slow \
         subscribers {} deviation chunks, {} reports",
        s.points_per_second / 1e6,
        s.points_processed,
        s.chunks_processed,
        s.stations_open,
        s.chunks_waiting,
        s.stations_reported,
        s.rejected_points.total(),
        s.input.total(),
        reasons.join(", "),
        s.output.deviation_chunks + s.output.deviation_chunks_unloaned,
        s.output.reports
    );
    if s.state() == Some(AgentState::HeldByDisk) {
        warn!(
            "health: results wait for the recording's disk; the cell is held back until they \
             are synced"
        );
    }
}

/// What every recording of this agent says about how it was made. The recorder adds the
/// design's hash from the bytes it attaches.
fn job_metadata(config: &AgentConfig) -> asbuilt_protocol::recording::JobMetadata {
    let calibrations = config
        .text
        .parse::<toml::Table>()
        .ok()
        .and_then(|t| t.get("calibration").map(|c| c.to_string()))
        .unwrap_or_else(|| "none: identity transforms".into());
    asbuilt_protocol::recording::JobMetadata {
        writer: "asbuilt-agent".into(),
        asbuilt_version: env!("CARGO_PKG_VERSION").into(),
        design_path: config.design.path.display().to_string(),
        design_units: config.design.units.clone(),
        design_sha256: String::new(),
        config: config.text.clone(),
        calibrations,
    }
}

#[cfg(test)]
mod power_cut;
#[cfg(test)]
mod tests;
