//! What goes out and what is recorded of what comes in: the agent's results to the cell's
//! ports, the recorder and the view, in one place. A result the cell or the printer acts on (a
//! report, findings, a surface judgement, advice) reaches it only once the recorder has it
//! synced to disk.

use std::time::{Duration, Instant};

use asbuilt_protocol::ipc::{AgentPorts, ChunkSample, Ipc};
use asbuilt_protocol::recording::Recorded;
use asbuilt_protocol::{
    AgentStatus, DeviationHeader, FindingsHeader, LayerCorrection, MountPose, PointDeviation,
    PoseSnapshot, ProfileHeader, ProfilePoint, StationEvent, StationFindings, StationReport,
};
use asbuilt_viewer::{self as viewer, View, Viewer};

use crate::lifecycle::Outputs;
use crate::recorder::{Lent, Recorder};
use crate::warn;

/// Where the agent's results go: the cell's ports, the recorder and the view. What comes in
/// from the cell is recorded and shown here too ([`Fanout::took_event`], [`Fanout::took_pose`],
/// [`Fanout::took_chunk`]).
pub(crate) struct Fanout<'p> {
    pub(crate) ports: &'p AgentPorts,
    /// Everything received and sent goes here too, when `[recorder]` is on.
    pub(crate) recorder: Option<Recorder>,
    /// The rerun view, when `[viewer]` is on, and points shown so far per open station.
    pub(crate) viewer: Option<Viewer>,
    /// What the view was given of each open station, and what its size is expected to be.
    pub(crate) shown: std::collections::BTreeMap<(u64, u32), ViewShare>,
    pub(crate) frames: &'p asbuilt_core::frames::FrameChain,
    /// Where deviations go when no shared-memory sample can be loaned, so the station's
    /// statistics stay whole. Sized once for the largest accepted chunk.
    pub(crate) scratch: Vec<PointDeviation>,
    pub(crate) unloaned: u64,
    /// Results waiting for the recorder to have them on disk, in the order they were made,
    /// with their commit's ticket (none until committed) and since when: the cell learns of a
    /// result only once neither a crash nor a power cut can lose it.
    pub(crate) unpublished: std::collections::VecDeque<Held>,
    /// The ticket whose wait for the disk the log has said.
    pub(crate) slow_disk_said: Option<u64>,
    /// Record each scan layer's findings state after every station (`[recorder] resume`).
    pub(crate) record_states: bool,
}

impl<'p> Fanout<'p> {
    /// The agent's outputs on `ports`, with the recorder and view when they are on; deviations
    /// that find no shared-memory sample go to a scratch buffer of `max_points_per_chunk`.
    pub(crate) fn new(
        ports: &'p AgentPorts,
        (recorder, viewer): (Option<Recorder>, Option<Viewer>),
        frames: &'p asbuilt_core::frames::FrameChain,
        max_points_per_chunk: usize,
        record_states: bool,
    ) -> Self {
        Self {
            ports,
            recorder,
            viewer,
            shown: Default::default(),
            frames,
            scratch: vec![PointDeviation::default(); max_points_per_chunk],
            unloaned: 0,
            unpublished: std::collections::VecDeque::new(),
            slow_disk_said: None,
            record_states,
        }
    }

    /// A station event taken from the cell: recorded; a Begin's chunk count sizes the
    /// station's share of the view.
    pub(crate) fn took_event(&mut self, ev: &StationEvent) {
        if self.viewer.is_some() && ev.kind() == Some(asbuilt_protocol::StationEventKind::Begin) {
            self.share((ev.job, ev.station)).expected_chunks = ev.expected_chunks.into();
        }
        if let Some(r) = &self.recorder {
            r.record(Recorded::Event(*ev));
            // A Begin is made durable at once: an agent resuming after a power cut knows
            // the attempt began, and calls it interrupted.
            if ev.kind() == Some(asbuilt_protocol::StationEventKind::Begin) {
                r.commit();
            }
        }
    }

    /// What the printer applied to a layer, taken from the cell: recorded.
    pub(crate) fn took_applied(&self, a: &asbuilt_protocol::LayerApplied) {
        if let Some(r) = &self.recorder {
            r.record(Recorded::Applied(*a));
        }
    }

    /// What the agents before recorded of the job being resumed, drawn again in the view (its
    /// .rrd starts empty): each report's statistics, each scan layer's latest findings (their
    /// markers, table and history) and the advice. The points are not drawn again.
    pub(crate) fn redraw(&self, r: &crate::resume::Resumed) {
        let Some(v) = &self.viewer else { return };
        let reports = r.recorded.iter().map(|report| View::Report {
            index: report.station,
            name: view_name(report.job, report.station),
            report: Box::new(*report),
        });
        let findings = r.findings.iter().map(|f| View::Findings {
            index: f.station,
            findings: Box::new(f.clone()),
        });
        let advice = r.corrections.iter().map(|c| View::Correction(Box::new(*c)));
        v.show_all(reports.chain(findings).chain(advice));
    }

    /// A pose taken from the cell, of a station of scan layer `layer`: recorded and shown.
    pub(crate) fn took_pose(&self, p: &PoseSnapshot, layer: u32) {
        if let Some(r) = &self.recorder {
            r.record(Recorded::Pose(*p));
        }
        if let (Some(v), Ok(t)) = (&self.viewer, self.frames.t_design_scanner(p)) {
            v.show(View::Station {
                index: p.station,
                name: view_name(p.job, p.station),
                layer,
                pose: t,
                time_ns: p.timestamp_ns,
            });
        }
    }

    /// A scan chunk taken from the cell: recorded, where the recorder's writer may read it in
    /// shared memory (then it comes back lent, to be given back when the lifecycle is done).
    pub(crate) fn took_chunk(&mut self, sample: &ChunkSample) -> Option<Lent<ChunkSample>> {
        let h = sample.user_header();
        self.sized_by((h.job, h.station), h.point_count);
        self.recorder
            .as_mut()
            .and_then(|r| r.chunk(h, sample.payload()))
    }

    /// A line profiler's chunk, taken from the cell: recorded.
    pub(crate) fn took_profiles(&mut self, h: &ProfileHeader, points: &[ProfilePoint]) {
        self.sized_by((h.job, h.pass), h.point_count);
        if let Some(r) = self.recorder.as_mut() {
            r.profiles(h, points);
        }
    }

    /// A robot pose of the profiler's mount, taken from the cell: recorded.
    pub(crate) fn took_mount_pose(&self, m: &MountPose) {
        if let Some(r) = &self.recorder {
            r.record(Recorded::MountPose(*m));
        }
    }

    /// The agent's status: recorded and published (its health line is the caller's).
    pub(crate) fn status(&self, s: &AgentStatus) {
        if let Some(r) = &self.recorder {
            r.record(Recorded::Status(Box::new(*s)));
        }
        if let Err(e) = self.ports.status.send_copy(*s) {
            warn!("status not published: {e:?}");
        }
    }
}

/// How long a result waits for the recorder's disk before the log and the status say the disk
/// holds the cell back. It is never published ahead of its record: a report the cell has and
/// the recording lacks makes a restarted agent call that attempt interrupted, while the cell
/// kept the first report it got and never scans the station again.
const ON_DISK_WAIT: Duration = Duration::from_secs(1);

/// A result for the cell or the printer.
pub(crate) enum Outgoing {
    Report(Box<StationReport>),
    Findings(Box<StationFindings>),
    Surface(Box<asbuilt_protocol::SurfaceFindings>),
    Correction(LayerCorrection),
}

impl Outgoing {
    /// The station the result is of.
    fn station(&self) -> (u64, u32) {
        match self {
            Outgoing::Report(r) => (r.job, r.station),
            Outgoing::Findings(f) => (f.job, f.station),
            Outgoing::Surface(s) => (s.job, s.station),
            Outgoing::Correction(c) => (c.job, c.station),
        }
    }
}

/// What the view is given of one station: its points spread evenly over the whole station,
/// at most the per-station budget. The stride follows from the points the station is expected
/// to bring (its Begin's chunks times its first chunk's points: a pass's deviations come in
/// batches of other sizes, but its points are the same); without a chunk count, each chunk
/// gives a sixteenth of the budget, and a station of more chunks shows its first sixteen only.
#[derive(Debug, Default, Clone, Copy)]
pub(crate) struct ViewShare {
    points: usize,
    parts: u32,
    expected_chunks: u64,
    chunk_points: u64,
}

impl ViewShare {
    fn stride(&self, n: usize, max: usize) -> usize {
        let expected = self.expected_chunks.saturating_mul(self.chunk_points);
        if expected > 0 {
            usize::try_from(expected)
                .unwrap_or(usize::MAX)
                .div_ceil(max.max(1))
                .max(1)
        } else {
            viewer::stride(n, (max / 16).max(1).min(max - self.points))
        }
    }
}

impl Fanout<'_> {
    /// The view's share of a station; a cell that begins stations it never ends cannot grow
    /// the table past the stations a lifecycle keeps open, and a few.
    fn share(&mut self, key: (u64, u32)) -> &mut ViewShare {
        const KEPT: usize = 64;
        if self.shown.len() >= KEPT && !self.shown.contains_key(&key) {
            self.shown.pop_first();
        }
        self.shown.entry(key).or_default()
    }

    /// A station's first chunk of input says how many points a chunk brings.
    fn sized_by(&mut self, key: (u64, u32), points: u32) {
        if self.viewer.is_some() {
            let share = self.share(key);
            if share.chunk_points == 0 {
                share.chunk_points = points.into();
            }
        }
    }
}

/// A result waiting for its record to be durable.
pub(crate) struct Held {
    /// The recorder's commit that makes it durable; none before it is asked for.
    ticket: Option<u64>,
    since: Instant,
    result: Outgoing,
}

/// One name per station in the view, the same for its pose, points and report.
fn view_name(job: u64, station: u32) -> String {
    format!("job{job}/station{station}")
}

impl Fanout<'_> {
    /// A decimated share of a deviation chunk for the view: at most 1/16 of the per-station
    /// budget per chunk, and nothing once the budget is spent.
    fn view_points(&mut self, h: &DeviationHeader, devs: &[PointDeviation]) {
        let Some(max) = self.viewer.as_ref().map(Viewer::max_points_per_station) else {
            return;
        };
        let share = self.share((h.job, h.station));
        if share.points >= max || devs.is_empty() {
            return;
        }
        let (positions, distances) = viewer::decimate(devs, share.stride(devs.len(), max));
        share.points += positions.len();
        share.parts += 1;
        let part = share.parts - 1;
        let Some(v) = &self.viewer else { return };
        v.show(View::Points {
            index: h.station,
            name: view_name(h.job, h.station),
            part,
            positions,
            distances,
        });
    }

    /// Publishes an encoded message (`what`) of a station `(job, station, layer)` behind a
    /// findings header; a failure is logged, never waited for.
    fn publish_encoded(
        &self,
        publisher: &iceoryx2::port::publisher::Publisher<Ipc, [u8], FindingsHeader>,
        (job, station, layer): (u64, u32, u32),
        bytes: &[u8],
        what: &str,
    ) {
        match publisher.loan_slice_uninit(bytes.len()) {
            Ok(mut sample) => {
                let header = sample.user_header_mut();
                header.job = job;
                header.station = station;
                header.layer = layer;
                header.bytes = bytes.len() as u32;
                let sample = sample.write_from_slice(bytes);
                if let Err(e) = sample.send() {
                    warn!("{what} of station {station} not published: {e:?}");
                }
                self.notify();
            }
            Err(e) => warn!(
                "{what} of station {station} ({} bytes) not published: {e:?}",
                bytes.len()
            ),
        }
    }

    fn notify(&self) {
        if let Err(e) = self.ports.outbox.notify() {
            warn!("cannot notify output subscribers: {e:?}");
        }
    }
}

impl Outputs for Fanout<'_> {
    fn pass_sensor(
        &mut self,
        key: crate::attempts::StationKey,
        layer: u32,
        sensor: &nalgebra::Isometry3<f64>,
    ) {
        if let Some(v) = &self.viewer {
            v.show(View::Sensor {
                index: key.1,
                layer,
                pose: *sensor,
            });
        }
    }

    fn wants_scan_layer_state(&self) -> bool {
        self.record_states && self.recorder.is_some()
    }

    fn scan_layer_state(
        &mut self,
        report: &StationReport,
        state: &asbuilt_core::scan_layer::ScanLayerState,
    ) {
        if let Some(r) = &self.recorder {
            r.scan_layer_state(asbuilt_protocol::recording::ScanLayerStateRecord {
                version: asbuilt_protocol::recording::ScanLayerStateRecord::VERSION,
                job: report.job,
                station: report.station,
                attempt: report.attempt,
                printed_height: report.printed_height,
                state: postcard::to_allocvec(state).expect("a state of numbers always encodes"),
            });
        }
    }

    fn findings(&mut self, f: &StationFindings) {
        if let Some(v) = &self.viewer {
            v.show(View::Findings {
                index: f.station,
                findings: Box::new(f.clone()),
            });
        }
        self.durable_then_said(
            Recorded::Findings(Box::new(f.clone())),
            Outgoing::Findings(Box::new(f.clone())),
        );
    }

    fn surface(&mut self, s: &asbuilt_protocol::SurfaceFindings) {
        self.durable_then_said(
            Recorded::Surface(Box::new(s.clone())),
            Outgoing::Surface(Box::new(s.clone())),
        );
    }

    fn correction(&mut self, c: &LayerCorrection) {
        if let Some(v) = &self.viewer {
            v.show(View::Correction(Box::new(*c)));
        }
        self.durable_then_said(Recorded::Correction(Box::new(*c)), Outgoing::Correction(*c));
    }

    fn deviations(
        &mut self,
        n: usize,
        fill: &mut dyn FnMut(&mut [PointDeviation]) -> DeviationHeader,
    ) {
        match self.ports.deviations.loan_slice(n) {
            Ok(mut sample) => {
                let header = fill(sample.payload_mut());
                *sample.user_header_mut() = header;
                if let Some(r) = &mut self.recorder {
                    r.deviations(&header, sample.payload());
                }
                self.view_points(&header, sample.payload());
                if let Err(e) = sample.send() {
                    warn!("deviation chunk {} not published: {e:?}", header.sequence);
                }
                self.notify();
            }
            Err(e) => {
                self.unloaned += 1;
                let header = fill(&mut self.scratch[..n]);
                if let Some(r) = &mut self.recorder {
                    r.deviations(&header, &self.scratch[..n]);
                }
                warn!(
                    "deviation chunk {} computed but not published, no output sample free \
                     ({e:?}): subscribers are holding too many",
                    header.sequence
                );
            }
        }
    }

    fn report(&mut self, report: &StationReport) {
        self.durable_then_said(
            Recorded::Report(Box::new(*report)),
            Outgoing::Report(Box::new(*report)),
        );
        if let Some(v) = &self.viewer {
            self.shown.remove(&(report.job, report.station));
            v.show(View::Report {
                index: report.station,
                name: view_name(report.job, report.station),
                report: Box::new(*report),
            });
        }
    }
}

impl Fanout<'_> {
    /// Records `record` and holds `result` until the recorder has it on disk; without a
    /// recorder, says it at once.
    fn durable_then_said(&mut self, record: Recorded, result: Outgoing) {
        match &self.recorder {
            Some(r) => {
                r.record(record);
                self.unpublished.push_back(Held {
                    ticket: None,
                    since: Instant::now(),
                    result,
                });
            }
            None => self.publish(&result),
        }
    }

    /// Tells the cell (or the printer) `result`, now.
    pub(crate) fn publish(&self, result: &Outgoing) {
        match result {
            Outgoing::Report(r) => {
                if let Err(e) = self.ports.reports.send_copy(**r) {
                    warn!("report of station {} not published: {e:?}", r.station);
                }
                self.notify();
            }
            Outgoing::Findings(f) => self.publish_encoded(
                &self.ports.findings,
                (f.job, f.station, f.layer),
                &asbuilt_protocol::codec::encode(f.as_ref()),
                "findings",
            ),
            Outgoing::Surface(s) => self.publish_encoded(
                &self.ports.surface,
                (s.job, s.station, s.layer),
                &asbuilt_protocol::codec::encode(s.as_ref()),
                "surface judgement",
            ),
            Outgoing::Correction(c) => match self.ports.corrections.send_copy(*c) {
                Ok(_) => self.notify(),
                Err(e) => warn!("advice after station {} not published: {e:?}", c.station),
            },
        }
    }

    /// Whether a result has waited for the disk longer than [`ON_DISK_WAIT`]: the disk holds
    /// the cell back, as the status says.
    pub(crate) fn held_by_disk(&self) -> bool {
        self.unpublished
            .front()
            .is_some_and(|h| h.since.elapsed() >= ON_DISK_WAIT)
    }

    /// Commits the results made since the last call (one sync for all of a station's) and
    /// publishes those the recorder has on disk, in order; all of them when `all` (the
    /// recorder is finished). One that has waited [`ON_DISK_WAIT`] is said once in the log,
    /// and waits on.
    pub(crate) fn publish_durable(&mut self, all: bool) {
        if let Some(r) = &self.recorder
            && self.unpublished.iter().any(|h| h.ticket.is_none())
        {
            let ticket = r.commit();
            for h in self.unpublished.iter_mut().filter(|h| h.ticket.is_none()) {
                h.ticket = Some(ticket);
            }
        }
        while let Some(held) = self.unpublished.front() {
            let ticket = held.ticket.unwrap_or(0);
            let on_disk = self.recorder.as_ref().is_none_or(|r| r.is_on_disk(ticket));
            if !(on_disk || all) {
                let waited = held.since.elapsed();
                if waited >= ON_DISK_WAIT && self.slow_disk_said != Some(ticket) {
                    self.slow_disk_said = Some(ticket);
                    let (job, station) = held.result.station();
                    warn!(
                        "job {job} station {station}: its results wait for the recorder to \
                         have them on disk ({:.1} s so far); the cell is told once they are. \
                         Check the recording folder's disk",
                        waited.as_secs_f64()
                    );
                }
                break;
            }
            let held = self.unpublished.pop_front().expect("checked above");
            self.publish(&held.result);
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use asbuilt_core::Design;
    use asbuilt_core::frames::FrameChain;
    use asbuilt_protocol::ipc::{CellPorts, QueueSizes, ServiceNames};
    use asbuilt_protocol::recording::{self, JobMetadata};
    use iceoryx2::prelude::*;

    use super::*;
    use crate::config::RecorderConfig;

    /// A station of 248 chunks of 6,000 points with a budget of 20,000: every chunk gives some
    /// points, and all of them together stay within the budget. Without a chunk count, the
    /// budget is spent in the first eighteen chunks.
    #[test]
    fn a_station_view_spreads_its_budget_over_every_chunk() {
        let show = |expected_chunks: u64| {
            let mut share = ViewShare {
                expected_chunks,
                chunk_points: 6_000,
                ..ViewShare::default()
            };
            let mut parts = Vec::new();
            for _ in 0..248 {
                if share.points >= 20_000 {
                    break;
                }
                let shown = 6_000usize.div_ceil(share.stride(6_000, 20_000));
                share.points += shown;
                parts.push(shown);
            }
            (share.points, parts)
        };
        let (points, parts) = show(248);
        assert_eq!(parts.len(), 248);
        assert!(parts.iter().all(|&n| n == 80), "{parts:?}");
        assert!(points <= 20_000 && points > 19_000, "{points}");
        // A sixteenth of the budget a chunk, the last ones what is left of it.
        let (points, parts) = show(0);
        assert_eq!((parts.len(), points), (18, 20_000));
    }

    fn cube() -> Arc<Design> {
        let (lo, hi) = (
            nalgebra::Point3::origin(),
            nalgebra::Point3::new(1.0, 1.0, 1.0),
        );
        Arc::new(asbuilt_core::design::shapes::cuboid(lo, hi))
    }

    /// The reports in the recording folder's files as they are on disk now.
    fn recorded_reports(dir: &std::path::Path) -> Vec<StationReport> {
        let mut out = Vec::new();
        for f in std::fs::read_dir(dir).unwrap() {
            let bytes = std::fs::read(f.unwrap().path()).unwrap();
            let Ok(messages) = recording::messages(&bytes) else {
                continue;
            };
            // A file still being written ends in the middle: what is before is read.
            for m in messages.map_while(Result::ok) {
                if let (_, Recorded::Report(r)) = m {
                    out.push(*r);
                }
            }
        }
        out
    }

    /// Both sides' ports on services of their own, and a folder for the recording.
    struct Rig {
        _node: Node<Ipc>,
        ports: AgentPorts,
        cell: CellPorts,
        frames: FrameChain,
        dir: tempfile::TempDir,
    }

    impl Rig {
        fn new(name: &str) -> Self {
            let names = ServiceNames::new(&format!("asbuilt-fanout-{name}/{}", std::process::id()));
            let node = NodeBuilder::new().create::<Ipc>().unwrap();
            let queues = QueueSizes {
                max_points_per_chunk: 16,
                chunk_queue: 2,
                pending_chunks: 1,
                lent_chunks: 0,
            };
            let ports = AgentPorts::create(&node, &names, queues).unwrap();
            let cell = CellPorts::try_open(&node, &names, 16).unwrap();
            Self {
                _node: node,
                ports,
                cell,
                frames: FrameChain::default(),
                dir: tempfile::tempdir().unwrap(),
            }
        }

        /// A recorder into the rig's folder, on `storage` (the disk without one).
        fn recorder(&self, storage: Option<Arc<dyn crate::recorder::Storage>>) -> Recorder {
            let config = RecorderConfig {
                dir: Some(self.dir.path().to_path_buf()),
                ..Default::default()
            };
            let storage = storage.unwrap_or_else(|| Arc::new(crate::recorder::Disk));
            let design = (std::path::Path::new("design.stl"), Vec::new());
            Recorder::start_on(
                storage,
                &config,
                JobMetadata::default(),
                design,
                cube(),
                0.005,
            )
            .unwrap()
        }
    }

    /// Durable, then said: with the recorder on, the cell gets a station's report only once
    /// the recording's file holds it; without one, at once.
    #[test]
    fn a_report_reaches_the_cell_only_once_its_record_is_on_disk() {
        let rig = Rig::new("report");
        let (ports, cell, frames) = (&rig.ports, &rig.cell, &rig.frames);
        let recorder = rig.recorder(None);
        let mut out = Fanout::new(ports, (Some(recorder), None), frames, 16, false);

        let mut sent = StationReport::new(7, 3);
        sent.points_received = 1234;
        sent.printed_height = 0.5;
        out.report(&sent);
        let start = Instant::now();
        let got = loop {
            out.publish_durable(false);
            if let Some(r) = cell.reports.receive().unwrap() {
                break *r.payload();
            }
            assert!(start.elapsed() < Duration::from_secs(10), "never published");
            std::thread::sleep(Duration::from_millis(1));
        };
        assert_eq!(got, sent);
        assert_eq!(recorded_reports(rig.dir.path()), vec![sent]);

        // Without a recorder nothing waits.
        let mut out = Fanout::new(ports, (None, None), frames, 16, false);
        out.report(&sent);
        assert_eq!(
            cell.reports.receive().unwrap().map(|r| *r.payload()),
            Some(sent)
        );
    }

    /// A storage whose syncs fail until the gate opens: a disk that stalls.
    struct Gated(Arc<std::sync::atomic::AtomicBool>);

    struct GatedFile(std::io::Cursor<Vec<u8>>, Arc<std::sync::atomic::AtomicBool>);

    impl crate::recorder::Storage for Gated {
        fn create_new(
            &self,
            _: &std::path::Path,
        ) -> std::io::Result<Box<dyn crate::recorder::StoredFile>> {
            Ok(Box::new(GatedFile(Default::default(), self.0.clone())))
        }
    }

    impl std::io::Write for GatedFile {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.write(buf)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            if self.1.load(std::sync::atomic::Ordering::SeqCst) {
                Ok(())
            } else {
                Err(std::io::Error::other("the disk is stalled"))
            }
        }
    }

    impl std::io::Seek for GatedFile {
        fn seek(&mut self, pos: std::io::SeekFrom) -> std::io::Result<u64> {
            self.0.seek(pos)
        }
    }

    /// Every result the cell or the printer acts on waits for the disk, in order: a report,
    /// findings, a surface judgement and advice made while the disk fails to sync reach the
    /// cell only once it syncs again, and the status says the disk holds the cell back.
    #[test]
    fn results_wait_for_a_stalled_disk_and_go_out_in_order_once_it_syncs() {
        let rig = Rig::new("stall");
        let (ports, cell, frames) = (&rig.ports, &rig.cell, &rig.frames);
        let gate = Arc::new(std::sync::atomic::AtomicBool::new(true));
        let recorder = rig.recorder(Some(Arc::new(Gated(gate.clone()))));
        let mut out = Fanout::new(ports, (Some(recorder), None), frames, 16, false);
        // The job's file opens while the disk works; then it stalls.
        let mut begin = StationEvent::new(asbuilt_protocol::StationEventKind::Begin, 7, 3);
        begin.expected_chunks = 1;
        out.took_event(&begin);
        let wait_for = |done: &dyn Fn() -> bool| {
            let start = Instant::now();
            while !done() {
                assert!(start.elapsed() < Duration::from_secs(10), "timed out");
                std::thread::sleep(Duration::from_millis(2));
            }
        };
        let recorder = out.recorder.as_ref().unwrap();
        let begun = recorder.commit();
        wait_for(&|| recorder.is_on_disk(begun));
        gate.store(false, std::sync::atomic::Ordering::SeqCst);

        let mut report = StationReport::new(7, 3);
        report.points_received = 99;
        report.printed_height = 0.5;
        let mut findings = StationFindings::new(7, 3);
        findings.layer = 2;
        let advice = LayerCorrection::neutral(7, 3, 1, 2);
        out.report(&report);
        out.findings(&findings);
        out.correction(&advice);
        std::thread::sleep(ON_DISK_WAIT + Duration::from_millis(100));
        out.publish_durable(false);
        assert!(
            out.held_by_disk(),
            "the status says the disk holds the cell back"
        );
        assert!(
            cell.reports.receive().unwrap().is_none(),
            "no report ahead of its record"
        );
        assert!(cell.findings.receive().unwrap().is_none());
        assert!(cell.corrections.receive().unwrap().is_none());

        gate.store(true, std::sync::atomic::Ordering::SeqCst);
        let start = Instant::now();
        while !out.unpublished.is_empty() {
            assert!(start.elapsed() < Duration::from_secs(10), "never published");
            std::thread::sleep(Duration::from_millis(2));
            out.publish_durable(false);
        }
        assert!(!out.held_by_disk());
        assert_eq!(
            cell.reports.receive().unwrap().map(|r| *r.payload()),
            Some(report)
        );
        let got = cell
            .findings
            .receive()
            .unwrap()
            .expect("findings published");
        assert_eq!(got.user_header().station, 3);
        let advised = cell.corrections.receive().unwrap().map(|c| *c.payload());
        // Compared as bytes: the neutral advice's evidence is NaN.
        let bytes = |c: &LayerCorrection| asbuilt_protocol::codec::encode(c);
        assert_eq!(advised.as_ref().map(bytes), Some(bytes(&advice)));
    }
}
