//! The flight recorder: everything the agent receives and sends, into one MCAP file per job
//! (layout in `asbuilt_protocol::recording`), written by a thread of its own.
//!
//! The event loop only hands a message to a bounded queue and moves on: a slow disk never
//! holds the robot back. A scan chunk is lent rather than copied while few are out (see
//! [`lent`]): the writer reads its points in shared memory. When the bytes waiting exceed
//! `recorder.queue_mb`, or the disk's free space falls below `recorder.min_free_mb`, scan and
//! deviation chunks are left out (counted and logged); station events, poses, reports and
//! status are always kept. What the cell or the printer acts on is committed once a station's
//! results are all queued ([`Recorder::commit`]): the writer ends the MCAP chunk and syncs the
//! file ([`storage`]), and the agent tells the cell only then, so neither a crash nor a power
//! cut loses what the cell was told.

use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering::Relaxed};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;

use asbuilt_protocol::foxglove::cloud_points;
use asbuilt_protocol::ipc::ChunkSample;
use asbuilt_protocol::recording::{JobMetadata, Recorded, RecordingWriter, ScanLayerStateRecord};
use asbuilt_protocol::{
    ChunkHeader, DeviationHeader, PointDeviation, ProfileHeader, ProfilePoint, ScanPoint,
    unix_time_ns,
};

use asbuilt_core::Design;
use asbuilt_core::colour::deviation_colour;

use crate::config::RecorderConfig;
use crate::{info, warn};

mod lent;
mod storage;
pub use lent::{LENT_CHUNKS, Lent};
use lent::{LentPoints, Returns, Shelf};
pub use storage::{Disk, Storage, StoredFile};

/// Messages waiting for the writer; a chunk counts once, however many points it holds.
const QUEUE: usize = 16_384;

/// How often a sync that failed is tried again.
const RETRY_SYNC: std::time::Duration = std::time::Duration::from_millis(200);

enum Item {
    Message(u64, Recorded),
    /// A scan chunk whose points the writer reads where they arrived.
    Lent(u64, ChunkHeader, LentPoints),
    /// The points of a deviation chunk that Foxglove's cloud shows, already selected (the
    /// asbuilt channel skips deviation chunks).
    FoxgloveCloud(u64, DeviationHeader, Vec<PointDeviation>),
    /// A scan layer's findings state, attached to the job's file.
    State(u64, Box<ScanLayerStateRecord>),
    Flush,
    /// The print a resume took up: its next file is the next part, not a new print's first.
    Continue(PrintFiles),
}

/// A print's files: a job's files from a first part to the parts that follow it. The recorder
/// starts a print's first file when a job begins, or when a Begin says that a new print began
/// under the same job number (`StationEvent::job_started_ns`), and goes on with parts (a full
/// file, an agent that resumed the print) otherwise; so a reader finds a print's files by
/// their names alone (see [`crate::resume::newest_print`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PrintFiles {
    /// The job number.
    pub job: u64,
    /// When the print started (0: not said).
    pub started: u64,
    /// The part of its newest file.
    pub part: u32,
}

/// What the recorder left out, for the status line and the log.
#[derive(Debug, Default)]
pub struct RecorderCounters {
    /// Scan chunks written.
    pub chunks_recorded: AtomicU64,
    /// Chunks left out because the queue was over its byte budget or the disk nearly full.
    pub chunks_dropped: AtomicU64,
    /// Chunks left out by `scan_every`.
    pub chunks_decimated: AtomicU64,
    /// Recording files opened (one more at every rotation).
    pub files: AtomicU64,
    /// Commits done by the writer: what was kept before the n-th is synced to disk.
    pub flushes: AtomicU64,
}

/// The MCAP recorder: messages queue under a byte budget to a writer thread, so recording
/// never blocks the event loop; only reports wait for room.
pub struct Recorder {
    tx: Option<SyncSender<Item>>,
    thread: Option<JoinHandle<()>>,
    queued: Arc<AtomicUsize>,
    budget: usize,
    scan_every: u64,
    seen_chunks: u64,
    deviations: bool,
    /// With Foxglove's channels: one point in this many of a chunk goes into its cloud, if it
    /// matched.
    foxglove: Option<usize>,
    /// Set by the writer when free disk space is below the guard.
    disk_low: Arc<std::sync::atomic::AtomicBool>,
    /// Flushes asked for so far.
    flushes_asked: AtomicU64,
    /// Whether a kept message was queued since the last commit.
    uncommitted: std::cell::Cell<bool>,
    /// Lent scan chunks' samples waiting for the writer.
    shelf: std::rc::Rc<std::cell::RefCell<Shelf<ChunkSample>>>,
    /// What was recorded and what was left out.
    pub counters: Arc<RecorderCounters>,
}

/// What Foxglove's channels are drawn with: the colour scale's tolerance (metres), where the
/// robot's base is in the design frame, and a line profiler's clock offset (the robot's clock
/// less the sensor's, ns), which puts its profiles on the robot's clock.
#[derive(Debug, Clone, Copy)]
pub struct ShownAs {
    /// Deviations are coloured saturating at ± this, metres.
    pub tolerance: f64,
    /// The robot's base in the design frame (`[calibration]`).
    pub t_design_base: nalgebra::Isometry3<f64>,
    /// `[profiler] clock_offset_ns`.
    pub clock_offset_ns: i64,
}

/// A tolerance alone: the base at the design's origin, clocks that agree.
impl From<f64> for ShownAs {
    fn from(tolerance: f64) -> Self {
        Self {
            tolerance,
            t_design_base: nalgebra::Isometry3::identity(),
            clock_offset_ns: 0,
        }
    }
}

impl Recorder {
    /// Starts the writer thread. `design` (the file's path and bytes, as the agent read them)
    /// is attached to every file with `meta`, whose design hash is filled from those bytes. With Foxglove's
    /// channels, `mesh` (the design as the agent read it) is shown, drawn as `shown` says.
    pub fn start(
        cfg: &RecorderConfig,
        meta: JobMetadata,
        design: (&Path, Vec<u8>),
        mesh: Arc<Design>,
        shown: impl Into<ShownAs>,
    ) -> std::io::Result<Self> {
        Self::start_on(Arc::new(Disk), cfg, meta, design, mesh, shown)
    }

    /// [`Recorder::start`] writing through `storage` instead of the disk.
    pub fn start_on(
        storage: Arc<dyn Storage>,
        cfg: &RecorderConfig,
        mut meta: JobMetadata,
        (design, design_bytes): (&Path, Vec<u8>),
        mesh: Arc<Design>,
        shown: impl Into<ShownAs>,
    ) -> std::io::Result<Self> {
        use sha2::{Digest, Sha256};
        let shown = shown.into();
        let dir = cfg.dir.clone().expect("started only when recording is on");
        std::fs::create_dir_all(&dir)?;
        meta.design_sha256 = format!("{:x}", Sha256::digest(&design_bytes));
        let design_name = design
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "design".into());
        let (tx, rx) = sync_channel(QUEUE);
        let queued = Arc::new(AtomicUsize::new(0));
        let counters = Arc::new(RecorderCounters::default());
        let disk_low = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let returns = Arc::new(Returns::default());
        let last_stamp = newest_stamp(&dir);
        let writer = Writer {
            storage,
            dir,
            max_bytes: (cfg.max_file_mb * 1e6) as u64,
            compression: cfg.compression,
            min_free: (cfg.min_free_mb * 1e6) as u64,
            meta,
            design_name,
            design: design_bytes,
            queued: queued.clone(),
            counters: counters.clone(),
            disk_low: disk_low.clone(),
            file: None,
            returns: returns.clone(),
            since_check: 0,
            last_stamp,
            owed: 0,
            unwritten: Vec::new(),
            sync_failing: false,
            continuing: None,
            foxglove: cfg.foxglove.then_some(Foxglove {
                shown,
                mesh,
                every: cfg.foxglove_every.max(1) as usize,
            }),
        };
        // Before the first chunk can be offered: a disk that is already full must keep it out.
        writer.check_disk();
        let thread = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || writer.run(rx))?;
        Ok(Self {
            tx: Some(tx),
            thread: Some(thread),
            queued,
            budget: (cfg.queue_mb * 1e6) as usize,
            scan_every: cfg.scan_every as u64,
            seen_chunks: 0,
            deviations: cfg.deviations,
            foxglove: cfg.foxglove.then_some(cfg.foxglove_every.max(1) as usize),
            disk_low,
            flushes_asked: AtomicU64::new(0),
            uncommitted: std::cell::Cell::new(false),
            shelf: Shelf::new(returns),
            counters,
        })
    }

    fn send(&self, item: Item, bytes: usize) -> bool {
        let Some(tx) = &self.tx else { return false };
        self.queued.fetch_add(bytes, Relaxed);
        match tx.try_send(item) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.queued.fetch_sub(bytes, Relaxed);
                false
            }
        }
    }

    fn small(&self, msg: Recorded) {
        if !self.send(Item::Message(unix_time_ns(), msg), 256) {
            warn!("recorder: queue full, a control message was not recorded");
        }
    }

    /// Records a message of the cell or of the agent (chunks have [`Recorder::chunk`] and
    /// [`Recorder::deviations`]). What the cell or the printer acts on (a report, findings, a
    /// surface judgement, advice: the table's per-station results) and a station's Begin are
    /// kept: they wait for queue room (only a stalled writer could make them wait) and are
    /// made durable by the next [`Recorder::commit`]. Other messages are left out, and said,
    /// when the queue is full.
    pub fn record(&self, m: Recorded) {
        if kept(&m) {
            self.keep(Item::Message(unix_time_ns(), m), 256);
        } else {
            self.small(m);
        }
    }

    /// Says which print a resume took up, before anything is recorded: its next file goes on
    /// from its newest part.
    pub fn continues(&self, print: PrintFiles) {
        self.keep(Item::Continue(print), 0);
    }

    /// Attaches a scan layer's findings state after a station, kept like a report: an agent
    /// resuming the job goes on from the latest instead of replaying the layer's points.
    pub fn scan_layer_state(&self, record: ScanLayerStateRecord) {
        let bytes = record.state.len();
        self.keep(Item::State(unix_time_ns(), Box::new(record)), bytes);
    }

    /// Queues an item that is never left out, weighed as the writer will unweigh it.
    fn keep(&self, item: Item, bytes: usize) {
        let Some(tx) = &self.tx else { return };
        self.queued.fetch_add(bytes, Relaxed);
        if tx.send(item).is_err() {
            self.queued.fetch_sub(bytes, Relaxed);
            return;
        }
        self.uncommitted.set(true);
    }

    /// Asks the writer to make everything kept so far durable (one sync for all of it: a
    /// station's report, findings, surface judgement, advice and state go together), and
    /// returns the ticket [`Recorder::is_on_disk`] takes. Without anything new since the last
    /// commit, that commit's ticket.
    pub fn commit(&self) -> u64 {
        let asked = self.flushes_asked.load(Relaxed);
        if !self.uncommitted.replace(false) {
            return asked;
        }
        match &self.tx {
            Some(tx) if tx.send(Item::Flush).is_ok() => {
                self.flushes_asked.fetch_add(1, Relaxed);
                asked + 1
            }
            // A writer that is gone holds nothing back (`is_on_disk` says so).
            _ => asked,
        }
    }

    /// Whether the commit of `ticket` is done: what was kept before it survives a crash of the
    /// agent and a power cut (the disk has it). True too once the writer is gone.
    pub fn is_on_disk(&self, ticket: u64) -> bool {
        // Asked while results wait for the disk, after a station's last chunk: the moment to
        // return the samples the writer is done with, which the next lend would otherwise do.
        self.shelf.borrow_mut().release();
        self.counters
            .flushes
            .load(std::sync::atomic::Ordering::Acquire)
            >= ticket
            || self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Whether a bulk chunk of `bytes` may go in now; counts it when it may not.
    fn admit(&mut self, bytes: usize) -> bool {
        self.seen_chunks += 1;
        if self.scan_every == 0 || !(self.seen_chunks - 1).is_multiple_of(self.scan_every) {
            self.counters.chunks_decimated.fetch_add(1, Relaxed);
            return false;
        }
        if self.disk_low.load(Relaxed)
            || self.queued.load(Relaxed).saturating_add(bytes) > self.budget
        {
            let n = self.counters.chunks_dropped.fetch_add(1, Relaxed);
            if n.is_power_of_two() {
                warn!(
                    "recorder: {} chunk(s) left out so far ({} MB waiting): {}",
                    n + 1,
                    self.queued.load(Relaxed) / 1_000_000,
                    if self.disk_low.load(Relaxed) {
                        "the disk is nearly full (recorder.min_free_mb)"
                    } else {
                        "the writer is behind (recorder.queue_mb)"
                    }
                );
            }
            return false;
        }
        true
    }

    /// Records a scan chunk, unless `scan_every` leaves it out or the budget is spent. The
    /// writer reads the points where they lie in shared memory when it can (see [`lent`]):
    /// then the chunk comes back lent, and its sample must be given back with
    /// [`Lent::give_back`] when its holder is done with it. Otherwise the points are copied.
    #[must_use = "a lent chunk's sample must be given back"]
    pub fn chunk(&mut self, h: &ChunkHeader, points: &[ScanPoint]) -> Option<Lent<ChunkSample>> {
        let bytes = std::mem::size_of_val(points);
        if !self.admit(bytes) {
            return None;
        }
        let t = unix_time_ns();
        let (sent, lent) = match Shelf::lend(&self.shelf, points) {
            Some((lent, points)) => {
                if self.send(Item::Lent(t, *h, points), bytes) {
                    (true, Some(lent))
                } else {
                    lent.cancel();
                    (false, None)
                }
            }
            None => {
                let copy = Recorded::Chunk(*h, points.to_vec());
                (self.send(Item::Message(t, copy), bytes), None)
            }
        };
        let counter = if sent {
            &self.counters.chunks_recorded
        } else {
            &self.counters.chunks_dropped
        };
        counter.fetch_add(1, Relaxed);
        lent
    }

    /// A line profiler's chunk, copied (the lifecycle copies each profile for its wait, so
    /// the sample is not kept lent): decimated and guarded as scan chunks are.
    pub fn profiles(&mut self, h: &ProfileHeader, points: &[ProfilePoint]) {
        let bytes = std::mem::size_of_val(points);
        if !self.admit(bytes) {
            return;
        }
        let m = Recorded::Profiles(Box::new(*h), points.to_vec());
        let counter = if self.send(Item::Message(unix_time_ns(), m), bytes) {
            &self.counters.chunks_recorded
        } else {
            &self.counters.chunks_dropped
        };
        counter.fetch_add(1, Relaxed);
    }

    /// Deviation chunks follow the scan chunks they come from: the same decimation and guard.
    pub fn deviations(&mut self, h: &DeviationHeader, points: &[PointDeviation]) {
        let bytes = std::mem::size_of_val(points);
        // Decimation counts scan chunks only; a deviation chunk is kept when its scan chunk was.
        if !(self.deviations || self.foxglove.is_some())
            || self.scan_every == 0
            || self.disk_low.load(Relaxed)
            || self.queued.load(Relaxed).saturating_add(bytes) > self.budget
        {
            return;
        }
        let t = unix_time_ns();
        if self.deviations {
            self.send(
                Item::Message(t, Recorded::Deviations(*h, points.to_vec())),
                bytes,
            );
        } else if let Some(every) = self.foxglove {
            // Only Foxglove's cloud wants them: the one point in `every` it shows is all that
            // is read and copied, not the whole chunk.
            let shown: Vec<PointDeviation> = cloud_points(points, every).copied().collect();
            let bytes = std::mem::size_of_val(shown.as_slice());
            self.send(Item::FoxgloveCloud(t, *h, shown), bytes);
        }
    }

    /// Writes what is queued and closes the file with its summary.
    pub fn finish(&mut self) {
        self.tx.take();
        if let Some(t) = self.thread.take()
            && t.join().is_err()
        {
            warn!("recorder: the writer thread failed; the last file may need `asbuilt recover`");
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.finish();
    }
}

/// Counts the bytes that reach the file, for rotation.
struct Counting<W> {
    inner: W,
    bytes: Arc<AtomicU64>,
}

impl<W: Write> Write for Counting<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.bytes.fetch_add(n as u64, Relaxed);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl<W: Seek> Seek for Counting<W> {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.inner.seek(pos)
    }
}

type FileWriter = RecordingWriter<Counting<Box<dyn StoredFile>>>;

struct OpenFile {
    writer: FileWriter,
    bytes: Arc<AtomicU64>,
    /// Bytes of the metadata and design attachment every file starts with.
    preamble: u64,
    path: PathBuf,
    job: u64,
    part: u32,
    /// When the print the file records started (0: not said yet).
    started: u64,
}

struct Writer {
    storage: Arc<dyn Storage>,
    dir: PathBuf,
    max_bytes: u64,
    compression: asbuilt_protocol::recording::ChunkCompression,
    min_free: u64,
    meta: JobMetadata,
    design_name: String,
    design: Vec<u8>,
    queued: Arc<AtomicUsize>,
    counters: Arc<RecorderCounters>,
    disk_low: Arc<std::sync::atomic::AtomicBool>,
    file: Option<OpenFile>,
    /// Where the writer says which lent chunks it is done with.
    returns: Arc<Returns>,
    /// Items written since the disk's free space was last checked.
    since_check: u32,
    foxglove: Option<Foxglove>,
    /// The newest stamp of the folder's job files: the next file's is later.
    last_stamp: u64,
    /// Commits asked for and not yet on disk (a sync failed).
    owed: u64,
    /// Kept messages whose write failed, written again before the next sync.
    unwritten: Vec<Item>,
    /// Whether the last sync failed (said once in the log).
    sync_failing: bool,
    /// The print a resume took up, until its next file opens.
    continuing: Option<PrintFiles>,
}

/// Tells the event loop the writer reads no more lent chunks, however its thread ends.
struct Gone(Arc<Returns>);

impl Drop for Gone {
    fn drop(&mut self) {
        self.0.gone();
    }
}

/// What the Foxglove channels need besides the messages: how they are drawn and the design.
struct Foxglove {
    shown: ShownAs,
    mesh: Arc<Design>,
    every: usize,
}

/// The newest stamp among the job files of `dir` (0 without any).
fn newest_stamp(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| crate::resume::JobFile::parse(&e.path()))
        .map(|f| f.stamp)
        .max()
        .unwrap_or(0)
}

/// Whether `m` is never left out and is retried until written: what the cell or the printer
/// acts on (the table's per-station results) and a station's Begin, which a resume needs.
fn kept(m: &Recorded) -> bool {
    m.channel().is_per_station()
        || matches!(m, Recorded::Event(e)
            if e.kind() == Some(asbuilt_protocol::StationEventKind::Begin))
}

/// The job of `m`, and when its print started when `m` is a Begin that says so.
fn print_of(m: &Recorded) -> (Option<u64>, Option<u64>) {
    match m {
        Recorded::Event(e)
            if e.kind() == Some(asbuilt_protocol::StationEventKind::Begin)
                && e.job_started_ns != 0 =>
        {
            (Some(e.job), Some(e.job_started_ns))
        }
        m => (job_of(m), None),
    }
}

fn job_of(m: &Recorded) -> Option<u64> {
    match m {
        Recorded::Pose(p) => Some(p.job),
        Recorded::Chunk(h, _) => Some(h.job),
        Recorded::MountPose(p) => Some(p.job),
        Recorded::Profiles(h, _) => Some(h.job),
        Recorded::Event(e) => Some(e.job),
        Recorded::Deviations(h, _) => Some(h.job),
        Recorded::Report(r) => Some(r.job),
        Recorded::Findings(f) => Some(f.job),
        Recorded::Correction(c) => Some(c.job),
        Recorded::Applied(a) => Some(a.job),
        Recorded::Surface(s) => Some(s.job),
        Recorded::Status(_) => None,
    }
}

impl Writer {
    fn run(mut self, rx: Receiver<Item>) {
        let _gone = Gone(self.returns.clone());
        self.check_disk();
        loop {
            // A commit that failed is tried again while nothing else comes: the results it
            // holds back wait for it, and the log has said why.
            let item = if self.owed > 0 {
                match rx.recv_timeout(RETRY_SYNC) {
                    Ok(item) => item,
                    Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                        self.settle();
                        continue;
                    }
                    Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
                }
            } else {
                match rx.recv() {
                    Ok(item) => item,
                    Err(_) => break,
                }
            };
            match item {
                Item::Message(t, m) => {
                    let bytes = match &m {
                        Recorded::Chunk(_, p) => std::mem::size_of_val(p.as_slice()),
                        Recorded::Profiles(_, p) => std::mem::size_of_val(p.as_slice()),
                        Recorded::Deviations(_, p) => std::mem::size_of_val(p.as_slice()),
                        _ => 256,
                    };
                    if !self.put(print_of(&m), bytes, |w| w.write(t, &m)) && kept(&m) {
                        self.unwritten.push(Item::Message(t, m));
                    }
                }
                Item::Lent(t, h, lent) => {
                    let bytes = std::mem::size_of_val(lent.points());
                    self.put((Some(h.job), None), bytes, |w| {
                        w.write_scan_chunk(t, &h, lent.points())
                    });
                    // From here the sample may go back to the scanner.
                    self.returns.done_with(lent.ticket());
                }
                Item::FoxgloveCloud(t, h, points) => {
                    let bytes = std::mem::size_of_val(points.as_slice());
                    self.put((Some(h.job), None), bytes, |w| {
                        w.write_foxglove_cloud(t, &h, &points)
                    });
                }
                Item::State(t, record) => {
                    self.queued.fetch_sub(record.state.len(), Relaxed);
                    if !self.attach_state(t, &record) {
                        self.unwritten.push(Item::State(t, record));
                    }
                }
                Item::Flush => {
                    self.owed += 1;
                    self.settle();
                    self.check_disk();
                }
                Item::Continue(print) => self.continuing = Some(print),
            }
        }
        self.close();
    }

    /// Ends the MCAP chunk and syncs the file; once the disk has it, the commits owed are
    /// done and the results they hold back may be told. A failure is said once and leaves them
    /// owed: no result goes out ahead of its record.
    fn settle(&mut self) {
        self.write_again();
        // Why the results must wait, if they must.
        let held = if !self.unwritten.is_empty() {
            Some(format!(
                "{} result(s) could not be written to {}",
                self.unwritten.len(),
                self.dir.display()
            ))
        } else {
            match &mut self.file {
                Some(f) => f.writer.flush().err().map(|e| {
                    format!(
                        "cannot sync {} to disk: {}",
                        f.path.display(),
                        asbuilt_io::error_message(&e)
                    )
                }),
                None => None,
            }
        };
        match held {
            None => {
                if self.sync_failing {
                    info!("recorder: the recording is synced to disk again");
                    self.sync_failing = false;
                }
                self.counters
                    .flushes
                    .fetch_add(self.owed, std::sync::atomic::Ordering::Release);
                self.owed = 0;
            }
            Some(why) => {
                if !self.sync_failing {
                    warn!(
                        "recorder: {why}; results are held back from the cell until they are \
                         on disk (trying again every {} ms)",
                        RETRY_SYNC.as_millis()
                    );
                    self.sync_failing = true;
                }
            }
        }
    }

    /// Writes the kept messages that could not be written before (in the order they came).
    fn write_again(&mut self) {
        for item in std::mem::take(&mut self.unwritten) {
            let written = match &item {
                // Their weight came off the queue at the first try.
                Item::Message(t, m) => self.put(print_of(m), 0, |w| w.write(*t, m)),
                Item::State(t, record) => self.attach_state(*t, record),
                _ => true,
            };
            if !written {
                self.unwritten.push(item);
            }
        }
    }

    /// Attaches a scan layer's state to the job's file; whether it is there. A state of a job
    /// whose file is not open (the next job began) is of no use to a resume: done.
    fn attach_state(&mut self, t: u64, record: &ScanLayerStateRecord) -> bool {
        let Some(f) = &mut self.file else {
            return false;
        };
        if f.job != record.job {
            return true;
        }
        match f.writer.attach_scan_layer_state(record, t) {
            Ok(()) => true,
            Err(e) => {
                warn!(
                    "recorder: cannot attach the scan layer state to {}: {e}; trying again",
                    f.path.display()
                );
                false
            }
        }
    }

    fn check_disk(&self) {
        let Some(free) = free_bytes(&self.dir) else {
            return;
        };
        let low = free < self.min_free;
        if low != self.disk_low.swap(low, Relaxed) {
            if low {
                warn!(
                    "recorder: {} has {} MB free, below recorder.min_free_mb: scan and deviation \
                     chunks are no longer recorded (events, poses, reports and status still are)",
                    self.dir.display(),
                    free / 1_000_000
                );
            } else {
                info!(
                    "recorder: disk space is back above recorder.min_free_mb; recording scans again"
                );
            }
        }
    }

    /// Writes one queued item with `write` into the file of `print` (its job, and its print's
    /// start when it is a Begin that says so), says so when that fails,
    /// and takes its `bytes` off the queue's weight; whether it was written. Every 64 items the
    /// disk's free space is checked again, so a filling disk stops the scan chunks before it
    /// is full.
    fn put(
        &mut self,
        print: (Option<u64>, Option<u64>),
        bytes: usize,
        write: impl FnOnce(&mut FileWriter) -> Result<(), mcap::McapError>,
    ) -> bool {
        let written = self.file_for(print).and_then(|f| match f {
            Some(f) => write(&mut f.writer).map_err(WriteError::Message),
            None => Ok(()),
        });
        if let Err(e) = &written {
            warn!("recorder: cannot write: {e}; a result is tried again, anything else is lost");
        }
        self.queued.fetch_sub(bytes, Relaxed);
        self.since_check += 1;
        if self.since_check >= 64 {
            self.since_check = 0;
            self.check_disk();
        }
        written.is_ok()
    }

    /// The file a message of `job` goes to: the open one, or a new one when the job changes, a
    /// Begin says a later print `started` under its number, or the file is full. None for a
    /// message without a job before the first job (nothing to attach it to).
    fn file_for(
        &mut self,
        (job, started): (Option<u64>, Option<u64>),
    ) -> Result<Option<&mut OpenFile>, WriteError> {
        let Some(job) = job else {
            return Ok(self.file.as_mut());
        };
        let new_print =
            |f: &OpenFile| f.job != job || started.is_some_and(|s| f.started != 0 && s > f.started);
        let next = match &self.file {
            None => match self.continuing.take() {
                // The print a resume took up goes on in its next part, unless a later print
                // begins.
                Some(c)
                    if c.job == job && started.is_none_or(|s| c.started == 0 || s <= c.started) =>
                {
                    Some((c.part + 1, c.started))
                }
                _ => Some((1, 0)),
            },
            Some(f) if new_print(f) => Some((1, 0)),
            Some(f) if f.writer_bytes() - f.preamble > self.max_bytes => {
                Some((f.part + 1, f.started))
            }
            Some(_) => None,
        };
        if let Some((part, print_started)) = next {
            self.close();
            self.open(job, part, print_started)?;
        }
        let f = self.file.as_mut().expect("opened above");
        if let Some(s) = started
            && f.started == 0
        {
            f.started = s;
        }
        Ok(Some(f))
    }

    fn open(&mut self, job: u64, part: u32, started: u64) -> Result<(), WriteError> {
        // Names sort in writing order, whatever the clock says: a file is stamped with the
        // second it opens at, or one past the newest of the folder (a device that booted with
        // an old clock, two files within a second), and never overwrites one.
        let mut stamp = (unix_time_ns() / 1_000_000_000).max(self.last_stamp + 1);
        let (path, file) = loop {
            let name = if part == 1 {
                format!("job-{job}-{stamp}.mcap")
            } else {
                format!("job-{job}-{stamp}-part{part}.mcap")
            };
            let path = self.dir.join(name);
            match self.storage.create_new(&path) {
                Ok(f) => {
                    self.last_stamp = stamp;
                    break (path, f);
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => stamp += 1,
                Err(source) => return Err(WriteError::Create { path, source }),
            }
        };
        let bytes = Arc::new(AtomicU64::new(0));
        let begun = |source| WriteError::Begin {
            path: path.clone(),
            source,
        };
        let mut writer = RecordingWriter::with_compression(
            Counting {
                inner: file,
                bytes: bytes.clone(),
            },
            self.compression,
        )
        .map_err(begun)?;
        if let Some(f) = &self.foxglove {
            let tolerance = f.shown.tolerance;
            writer = writer
                .with_foxglove(Box::new(move |d| deviation_colour(d, tolerance)))
                .map_err(begun)?
                .foxglove_every(f.every)
                .foxglove_clock_offset(f.shown.clock_offset_ns);
        }
        writer.metadata(&self.meta).map_err(begun)?;
        let now = unix_time_ns();
        writer
            .attach_design(&self.design_name, &self.design, now)
            .map_err(begun)?;
        if let Some(f) = &self.foxglove {
            let vertices = f.mesh.vertices.iter().map(|v| [v.x, v.y, v.z]);
            writer
                .foxglove_design(now, vertices, &f.mesh.triangles)
                .map_err(begun)?;
            let base = &f.shown.t_design_base;
            let q = base.rotation.coords;
            writer
                .foxglove_base(now, base.translation.vector.into(), [q.x, q.y, q.z, q.w])
                .map_err(begun)?;
        }
        writer.flush().map_err(begun)?;
        info!("recorder: job {job} → {}", path.display());
        self.counters.files.fetch_add(1, Relaxed);
        let preamble = bytes.load(Relaxed);
        self.file = Some(OpenFile {
            writer,
            preamble,
            bytes,
            path,
            job,
            part,
            started,
        });
        Ok(())
    }

    fn close(&mut self) {
        if let Some(f) = self.file.take() {
            let path = f.path.clone();
            match f.writer.finish() {
                Ok(mut w) => {
                    let _ = w.flush();
                    info!(
                        "recorder: closed {} ({} MB)",
                        path.display(),
                        f.bytes.load(Relaxed) / 1_000_000
                    );
                }
                Err(e) => warn!(
                    "recorder: cannot finish {}: {e}; `asbuilt recover` saves its messages",
                    path.display()
                ),
            }
        }
    }
}

impl OpenFile {
    fn writer_bytes(&self) -> u64 {
        self.bytes.load(Relaxed)
    }
}

/// Why the recorder could not write a message (it says so, and the message is lost; the
/// agent goes on).
#[derive(Debug, thiserror::Error)]
enum WriteError {
    /// A new file could not be created.
    #[error("cannot create {}: {source}", path.display())]
    Create {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A new file's opening records (header, metadata, design, schemas) could not be written.
    #[error("cannot begin {}: {source}", path.display())]
    Begin {
        path: PathBuf,
        source: mcap::McapError,
    },
    /// The message itself could not be written.
    #[error("{0}")]
    Message(mcap::McapError),
}

/// Free bytes on the file system holding `dir` (for an unprivileged writer); `None` when it
/// cannot be asked, as for a folder that does not exist.
pub fn free_bytes(dir: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: statvfs is plain old data (integers and an array of them): all zeros is a value.
    let mut s: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c` is a valid NUL-terminated path and `s` a writable statvfs.
    if unsafe { libc::statvfs(c.as_ptr(), &mut s) } != 0 {
        return None;
    }
    Some(s.f_bavail as u64 * s.f_frsize as u64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::resume::JobFile;

    /// A folder holding a file stamped by a clock far ahead (or a device that booted with an
    /// old clock since): the next file still sorts after it, so a resume takes up the job
    /// written last.
    #[test]
    fn files_sort_in_writing_order_whatever_the_clock() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("job-9-99999999999.mcap"), b"").unwrap();
        let mut r = recorder(dir.path());
        for job in [1, 2] {
            let begin = asbuilt_protocol::StationEvent::new(
                asbuilt_protocol::StationEventKind::Begin,
                job,
                0,
            );
            r.record(Recorded::Event(begin));
        }
        r.finish();
        let mut files: Vec<JobFile> = std::fs::read_dir(dir.path())
            .unwrap()
            .filter_map(|e| JobFile::parse(&e.unwrap().path()))
            .collect();
        files.sort();
        let jobs: Vec<u64> = files.iter().map(|f| f.job).collect();
        assert_eq!(jobs, vec![9, 1, 2], "{files:?}");
    }

    fn recorder(dir: &Path) -> Recorder {
        let config = RecorderConfig {
            dir: Some(dir.to_path_buf()),
            ..Default::default()
        };
        let cube = asbuilt_core::design::shapes::cuboid(
            nalgebra::Point3::origin(),
            nalgebra::Point3::new(1.0, 1.0, 1.0),
        );
        Recorder::start(
            &config,
            JobMetadata::default(),
            (Path::new("design.stl"), Vec::new()),
            Arc::new(cube),
            0.005,
        )
        .unwrap()
    }

    /// A recorder of an agent that resumed job 1's print started at 200, its newest part `part`.
    fn resumed(dir: &Path, part: u32) -> Recorder {
        let r = recorder(dir);
        r.continues(PrintFiles {
            job: 1,
            started: 200,
            part,
        });
        r
    }

    fn begin(station: u32, started: u64) -> Recorded {
        let mut b = asbuilt_protocol::StationEvent::new(
            asbuilt_protocol::StationEventKind::Begin,
            1,
            station,
        );
        b.job_started_ns = started;
        Recorded::Event(b)
    }

    /// A new print under job 1 starts a first part; a resumed print and an earlier print's
    /// Begin (a service's history) go on in the print's files; and the folder's newest print is
    /// found from the names alone.
    #[test]
    fn a_print_goes_on_in_parts_and_a_new_print_under_its_number_starts_afresh() {
        let dir = tempfile::tempdir().unwrap();
        let files = || {
            let mut f: Vec<JobFile> = std::fs::read_dir(dir.path())
                .unwrap()
                .filter_map(|e| JobFile::parse(&e.unwrap().path()))
                .collect();
            f.sort();
            f
        };
        let mut r = recorder(dir.path());
        r.record(begin(0, 100));
        r.record(begin(1, 100));
        r.record(begin(0, 200));
        r.record(begin(1, 100));
        r.finish();
        let parts: Vec<u32> = files().iter().map(|f| f.part).collect();
        assert_eq!(parts, vec![1, 1]);
        // An agent that resumed the print of 200 goes on with its next part.
        let mut r = resumed(dir.path(), 1);
        r.record(begin(2, 200));
        r.finish();
        let parts: Vec<u32> = files().iter().map(|f| f.part).collect();
        assert_eq!(parts, vec![1, 1, 2]);
        let all = files();
        let newest = crate::resume::newest_print(&all, 1);
        assert_eq!(newest, vec![&all[1], &all[2]]);
        // Resumed, but the cell began a later print: a first part.
        let mut r = resumed(dir.path(), 2);
        r.record(begin(0, 300));
        r.finish();
        let all = files();
        assert_eq!(all.last().unwrap().part, 1);
        assert_eq!(crate::resume::newest_print(&all, 1), vec![&all[3]]);
    }
}
