//! Resuming the newest job of the recorder's folder when the agent starts, so that an unplanned
//! stop (killed, power lost, updated) loses nothing: the agent before this one recorded every
//! input it took, and this one takes them again.
//!
//! At start, before serving:
//! 1. Files whose writer died (no MCAP footer) are recovered in place, every channel kept. A file
//!    that cannot be read at all is renamed `*.damaged` and left out, with a warning.
//! 2. The newest job's files are read in order. Every recorded report tells which station
//!    attempts are over; the inputs of the current scan layer's stations are fed through the
//!    lifecycle again, so the findings state of that scan layer is the one the agent before had.
//! 3. What the agent before left undone is done: a station it closed but whose report never made
//!    it to disk is reported now; a station still open is reported `Interrupted`, so the cell
//!    scans it again. Recorded reports are published again (the cell may never have had them).
//!
//! Replaying the inputs costs the current scan layer's points once; a snapshot of the state was
//! the alternative, but it would add design-sized records to every station of the recording.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::time::Instant;

use std::collections::BTreeMap;

use asbuilt_core::scan_layer::ScanLayerState;
use asbuilt_protocol::recording::{self, Channel, ReadError, Recorded, ScanLayerStateRecord};
use asbuilt_protocol::{
    ChunkHeader, DeviationHeader, PointDeviation, ScanPoint, StationEventKind, StationReport,
    StationStatus,
};

use crate::attempts::StationKey;
use crate::lifecycle::{ChunkSource, Lifecycle, Outputs};
use crate::{info, warn};

/// One recording file of the agent's folder: `job-{job}-{stamp}[-part{n}].mcap`.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct JobFile {
    /// The Unix second the file was opened at, or one past the newest file of the folder when
    /// the clock says earlier (a device booted with an old clock): files sort in the order
    /// they were written, whatever the clock.
    pub stamp: u64,
    /// 1 for a print's first file, then one more for each file that goes on with it (a full
    /// file, an agent that resumed the print); see [`crate::recorder::PrintFiles`].
    pub part: u32,
    /// The job it records.
    pub job: u64,
    /// Where it is.
    pub path: PathBuf,
}

impl JobFile {
    /// The file's job, stamp and part from its name; `None` for a name the recorder does not
    /// write.
    pub fn parse(path: &Path) -> Option<Self> {
        let name = path.file_name()?.to_str()?.strip_suffix(".mcap")?;
        let rest = name.strip_prefix("job-")?;
        let mut fields = rest.splitn(3, '-');
        let job = fields.next()?.parse().ok()?;
        let stamp = fields.next()?.parse().ok()?;
        let part = match fields.next() {
            None => 1,
            Some(p) => p.strip_prefix("part")?.parse().ok()?,
        };
        Some(Self {
            stamp,
            part,
            job,
            path: path.to_path_buf(),
        })
    }
}

/// The files of the newest print of `job` among `files` (oldest first): from its last first
/// part on. Recordings of releases before prints were told apart started a first part at every
/// start of the agent too; naming such a job's files reads them together.
pub fn newest_print(files: &[JobFile], job: u64) -> Vec<&JobFile> {
    let of_job: Vec<&JobFile> = files.iter().filter(|f| f.job == job).collect();
    let from = of_job.iter().rposition(|f| f.part == 1).unwrap_or(0);
    of_job[from..].to_vec()
}

/// The recorder's folder at start: its job files, oldest first, and those of them whose
/// writer died (no footer), to recover with [`recover_files`] (while the agent serves: the
/// resume reads them as they are, up to where they stop). A file that is not MCAP at all is
/// set aside as `*.damaged`. Never fails on a file: what cannot be used is said.
pub struct Folder {
    /// Every job file, oldest first.
    pub files: Vec<JobFile>,
    /// The files among them that their writer never closed.
    pub unfinished: Vec<PathBuf>,
}

/// Lists the recorder's folder (see [`Folder`]).
pub fn scan_folder(dir: &Path) -> Folder {
    let mut folder = Folder {
        files: Vec::new(),
        unfinished: Vec::new(),
    };
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return folder,
        Err(e) => {
            warn!(
                "resume: cannot list {}: {e}; starting without the jobs recorded there",
                dir.display()
            );
            return folder;
        }
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == "recovering") {
            // A recovery cut short by another stop: its source is still there and is
            // recovered again.
            let _ = std::fs::remove_file(&path);
            continue;
        }
        let Some(file) = JobFile::parse(&path) else {
            continue;
        };
        match map(&path) {
            Ok(m) if m.starts_with(mcap::MAGIC) => {
                if !is_finished(&m) {
                    folder.unfinished.push(path);
                }
                folder.files.push(file);
            }
            Ok(_) => set_aside(&path, "it is not an MCAP file"),
            Err(e) => set_aside(&path, &e.to_string()),
        }
    }
    folder.files.sort();
    folder
}

/// Recovers each file in place (every channel kept); one that cannot be recovered is set
/// aside as `*.damaged`.
pub fn recover_files(paths: &[PathBuf]) {
    for path in paths {
        if let Err(e) = recover_if_unfinished(path) {
            set_aside(path, &e.to_string());
        }
    }
}

/// Renames a file the resume cannot use to `*.damaged`, so that nothing reads it as a job file
/// again and nothing of it is lost.
fn set_aside(path: &Path, why: &str) {
    let aside = path.with_extension("mcap.damaged");
    let moved = std::fs::rename(path, &aside).is_ok();
    warn!(
        "resume: {} cannot be read ({why}); {}",
        path.display(),
        if moved {
            format!("kept as {} and left out", aside.display())
        } else {
            "left out".to_string()
        }
    );
}

/// Whether a recording was closed by its writer: a finished MCAP file ends with the magic.
fn is_finished(bytes: &[u8]) -> bool {
    bytes.len() >= 2 * mcap::MAGIC.len() && bytes.ends_with(mcap::MAGIC)
}

/// Why a file whose writer died could not be recovered (it is set aside).
#[derive(Debug, thiserror::Error)]
enum RecoverError {
    /// It could not be read.
    #[error("{0}")]
    Read(std::io::Error),
    /// The recovered copy could not be written or put in its place.
    #[error("cannot write {}: {source}", path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    /// What it holds could not be recovered.
    #[error("{0}")]
    Recover(mcap::McapError),
}

/// Rewrites a file whose writer died into a valid recording, next to it first and then over it,
/// so that a stop during the recovery leaves the original as it was.
fn recover_if_unfinished(path: &Path) -> Result<(), RecoverError> {
    let map = map(path).map_err(RecoverError::Read)?;
    if is_finished(&map) {
        return Ok(());
    }
    let started = Instant::now();
    let tmp = path.with_extension("mcap.recovering");
    let written = |source| RecoverError::Write {
        path: tmp.clone(),
        source,
    };
    let out = File::create(&tmp).map_err(written)?;
    let result = recording::recover(&map, std::io::BufWriter::new(out));
    let (w, counts) = match result {
        Ok(r) => r,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(RecoverError::Recover(e));
        }
    };
    let file = w.into_inner().map_err(|e| written(e.into_error()))?;
    file.sync_all().map_err(written)?;
    drop(map);
    std::fs::rename(&tmp, path).map_err(written)?;
    info!(
        "resume: recovered {} (its writer stopped without closing it): {} messages, {} \
         attachment(s) kept{}, in {:.2} s",
        path.display(),
        counts.messages,
        counts.attachments,
        if counts.truncated {
            ", the unwritten end cut off"
        } else {
            ""
        },
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

fn map(path: &Path) -> std::io::Result<memmap2::Mmap> {
    let file = File::open(path)?;
    // SAFETY: only read; this agent is the folder's only writer and has not started writing.
    unsafe { memmap2::Mmap::map(&file) }
}

/// What resuming found and did.
#[derive(Debug, Default)]
pub struct Resumed {
    /// The job resumed.
    pub job: u64,
    /// Its print and newest file: the recorder goes on with the next part.
    pub print: Option<crate::recorder::PrintFiles>,
    /// Its files, oldest first.
    pub files: usize,
    /// Every report the agents before recorded, in the order they were recorded.
    pub recorded: Vec<StationReport>,
    /// Stations of the current scan layer fed through the lifecycle again, and their points.
    pub stations_replayed: usize,
    /// Points of those stations.
    pub points_replayed: u64,
    /// Reports the replay gave for station attempts whose report was never recorded: the agent
    /// before closed them, or would have, but stopped before the report was on disk.
    pub unrecorded: Vec<StationReport>,
    /// Messages of the files that could not be read (a damaged record ends a file's reading).
    pub unreadable: Vec<String>,
    /// Bytes of the scan layer state taken up, when the current scan layer went on from its
    /// recorded state rather than a replay.
    pub state_bytes: Option<usize>,
    /// The Begins of station attempts never reported: open when the agent before stopped.
    pub open: Vec<asbuilt_protocol::StationEvent>,
    /// A line profiler's passes open when the agent before stopped, taken up again.
    pub passes_taken_up: Vec<StationKey>,
    /// Files of the folder whose writer died, to recover while serving.
    pub unfinished: Vec<PathBuf>,
    /// The current scan layer's last station, whose findings never made it to disk: they are
    /// drawn again from the layer's state and published.
    pub findings_due: Option<StationReport>,
    /// Each scan layer's latest recorded findings, by scan layer: the view draws them again.
    /// As many as the job's scan layers.
    pub findings: Vec<asbuilt_protocol::StationFindings>,
    /// The advice recorded, in the order recorded: the view draws it again.
    pub corrections: Vec<asbuilt_protocol::LayerCorrection>,
}

/// Reads the newest job of `files` back into `lifecycle`: the attempts it reported are over,
/// and the current scan layer's findings state is taken up: from the state recorded after its
/// last station when there is one (its size is the design's), else by feeding the layer's
/// recorded inputs through the lifecycle again. Station attempts begun and never reported are
/// in [`Resumed::open`]: the caller reports them interrupted with its real outputs.
pub fn replay_job<C>(files: &[JobFile], lifecycle: &mut Lifecycle<C>) -> Option<Resumed>
where
    C: ChunkSource + From<(ChunkHeader, Vec<ScanPoint>)>,
{
    let job = files.last()?.job;
    let files = newest_print(files, job);
    let mut resumed = Resumed {
        job,
        files: files.len(),
        ..Default::default()
    };
    let seen = survey(&files, job, &mut resumed);
    resumed.print = files.last().map(|f| crate::recorder::PrintFiles {
        job,
        started: seen.started,
        part: f.part,
    });
    lifecycle.resumes_print(job, seen.started);
    for c in seen.advice.history() {
        lifecycle.restore_correction(c);
    }
    for a in &seen.applied {
        lifecycle.on_applied(a);
    }
    // The current scan layer's last station that did not end interrupted: the state after it
    // is the layer's.
    let in_layer = |key: StationKey| {
        seen.current.is_some() && seen.layer_of.get(&key) == seen.current.as_ref()
    };
    let last_report = resumed
        .recorded
        .iter()
        .rev()
        .find(|r| in_layer((r.job, r.station)) && r.status() != Some(StationStatus::Interrupted))
        .copied();
    let last_done = last_report.map(|r| (r.station, r.attempt));
    if let (Some(height), Some(done)) = (seen.current, last_done)
        && lifecycle.has_findings()
    {
        let at = seen
            .states
            .iter()
            .rposition(|r| r.printed_height.to_bits() == height && (r.station, r.attempt) == done);
        // The state from before the last station closed: the one recorded before its first
        // attempt (the scan layer's start when there is none), for that station sent again.
        let before = at.and_then(|at| {
            seen.states[..at]
                .iter()
                .rev()
                .find(|r| r.printed_height.to_bits() == height && r.station != done.0)
        });
        let profiled = !seen.passes.is_empty();
        let restored = at.map(|at| restore(lifecycle, &seen.states[at], before, profiled));
        match restored {
            Some(Ok(bytes)) => resumed.state_bytes = Some(bytes),
            Some(Err(e)) => {
                warn!("resume: the recorded scan layer state cannot be used ({e}); replaying");
                replay_layer(&files, lifecycle, &in_layer, &mut resumed);
            }
            None => replay_layer(&files, lifecycle, &in_layer, &mut resumed),
        }
    }
    // Findings, or the advice that follows them, that never made it to disk for the scan
    // layer's last closed attempt are drawn again. That attempt is the last one the replay
    // reported when its report was never recorded either (a kill loses a file's tail), else
    // the last recorded; what was recorded is matched per attempt, not per station: a
    // station sent again has the findings of its earlier attempt on disk, not of this one.
    let last_closed = resumed
        .unrecorded
        .iter()
        .rev()
        .find(|r| in_layer((r.job, r.station)) && r.status() != Some(StationStatus::Interrupted))
        .copied()
        .or(last_report);
    resumed.findings_due = last_closed.filter(|r| {
        let key = (r.job, r.station, r.attempt.max(1));
        lifecycle.has_findings()
            && (!seen.with_findings.contains(&key)
                || (lifecycle.has_corrections() && !seen.with_advice.contains(&key)))
    });
    // After a replay, which must take the current scan layer's stations as new: every attempt
    // reported before is over, and its repeats change nothing.
    for r in &resumed.recorded {
        if r.status() != Some(StationStatus::Interrupted) {
            let key = (r.job, r.station);
            let begun = seen.begun_at.get(&key).copied().unwrap_or(0);
            lifecycle.remember_reported(key, r.attempt.into(), begun);
        }
    }
    resumed.open = seen
        .begun
        .into_values()
        .filter(|b| {
            !resumed.recorded.iter().any(|r| {
                (r.job, r.station) == (b.job, b.station) && r.attempt.max(1) >= b.attempt.max(1)
            })
        })
        .collect();
    take_up_passes(&files, lifecycle, !seen.passes.is_empty(), &mut resumed);
    Some(resumed)
}

/// A line profiler's pass cannot be sent again (its layer is printed over): each pass open
/// when the agent before stopped (`profiled`: the job's mount poses say it is printed with a
/// profiler; the open pass's own may not have reached the disk) is fed through the lifecycle
/// again from what was recorded of it, and goes on with what the cell sends.
fn take_up_passes<C>(
    files: &[&JobFile],
    lifecycle: &mut Lifecycle<C>,
    profiled: bool,
    resumed: &mut Resumed,
) where
    C: ChunkSource + From<(ChunkHeader, Vec<ScanPoint>)>,
{
    if !profiled {
        return;
    }
    for b in std::mem::take(&mut resumed.open) {
        let key = (b.job, b.station);
        let before = resumed.points_replayed;
        replay_layer(files, lifecycle, &|k| k == key, resumed);
        if !lifecycle.take_up_pass(key.0, key.1) {
            resumed.open.push(b);
            continue;
        }
        info!(
            "resume: job {} pass {}: taken up from its {} recorded points; it goes on with \
             what the cell sends",
            key.0,
            key.1,
            resumed.points_replayed - before
        );
        resumed.passes_taken_up.push(key);
    }
}

/// A station's attempt: job, station, attempt (from 1).
type AttemptKey = (u64, u32, u8);

/// What a first pass over a job's files finds, without decoding a scan chunk.
struct Survey {
    /// When the print started, as its Begins say (0: they do not).
    started: u64,
    /// The scan layer (printed height's bits) of each station's Begin.
    layer_of: BTreeMap<StationKey, u64>,
    /// The latest Begin's scan layer.
    current: Option<u64>,
    /// The Begin of the latest attempt of each station.
    begun: BTreeMap<StationKey, asbuilt_protocol::StationEvent>,
    /// When each station's latest Begin was sent.
    begun_at: BTreeMap<StationKey, u64>,
    /// Station attempts whose findings were recorded (findings follow their attempt's report
    /// in the file: they take the attempt of the station's latest report).
    with_findings: std::collections::BTreeSet<AttemptKey>,
    /// Station attempts whose advice was recorded.
    with_advice: std::collections::BTreeSet<AttemptKey>,
    /// The attempt of each station's latest recorded report.
    reported: BTreeMap<StationKey, u8>,
    /// The advice recorded, as far as the next advice builds on it.
    advice: asbuilt_core::corrections::Corrector,
    /// What the printer said it applied, in the order recorded.
    applied: Vec<asbuilt_protocol::LayerApplied>,
    /// A line profiler's passes, as the job's mount poses name them.
    passes: std::collections::BTreeSet<StationKey>,
    /// The scan layer states recorded for the latest scan layer that has one, by station
    /// attempt (a scan layer's stations are recorded one after the other, so this holds one
    /// scan layer's at most).
    states: Vec<ScanLayerStateRecord>,
}

/// Reads the reports (into `resumed`), the Begins and the scan layer states of `job`'s files.
fn survey(files: &[&JobFile], job: u64, resumed: &mut Resumed) -> Survey {
    let mut seen = Survey {
        started: 0,
        layer_of: BTreeMap::new(),
        current: None,
        begun: BTreeMap::new(),
        begun_at: BTreeMap::new(),
        with_findings: Default::default(),
        with_advice: Default::default(),
        reported: BTreeMap::new(),
        advice: asbuilt_core::corrections::Corrector::new(Default::default()),
        applied: Vec::new(),
        passes: Default::default(),
        states: Vec::new(),
    };
    for f in files {
        let map = match map(&f.path) {
            Ok(m) => m,
            Err(e) => {
                resumed
                    .unreadable
                    .push(format!("{}: {e}", f.path.display()));
                continue;
            }
        };
        let wanted = [
            Channel::StationEvents,
            Channel::Reports,
            Channel::Findings,
            Channel::Corrections,
            Channel::Applied,
            Channel::MountPoses,
        ];
        let messages = recording::messages_on(&map, &wanted);
        for m in messages.into_iter().flatten() {
            // A damaged record ends the file's reading; the second pass says so.
            let Ok((_, m)) = m else { break };
            match m {
                Recorded::Report(r) => {
                    seen.reported.insert((r.job, r.station), r.attempt.max(1));
                    resumed.recorded.push(*r);
                }
                Recorded::Findings(f) => {
                    let attempt = seen.reported.get(&(f.job, f.station)).copied();
                    seen.with_findings
                        .insert((f.job, f.station, attempt.unwrap_or(1)));
                    if f.job == job {
                        let layers = &mut resumed.findings;
                        match layers.binary_search_by_key(&f.layer, |l| l.layer) {
                            Ok(i) => layers[i] = *f,
                            Err(i) => layers.insert(i, *f),
                        }
                    }
                }
                Recorded::Applied(a) if a.job == job => seen.applied.push(a),
                Recorded::MountPose(m) if m.job == job => {
                    seen.passes.insert((m.job, m.pass));
                }
                Recorded::Correction(c) if c.job == job => {
                    seen.with_advice
                        .insert((c.job, c.station, c.attempt.max(1)));
                    seen.advice.restore(&c);
                    resumed.corrections.push(*c);
                }
                Recorded::Event(e) if e.kind() == Some(StationEventKind::Begin) => {
                    if e.job_started_ns != 0 && e.job_started_ns < seen.started {
                        // An earlier print's, from a service's history: the agent ignored it.
                        continue;
                    }
                    seen.started = seen.started.max(e.job_started_ns);
                    let height = e.printed_height.to_bits();
                    let key = (e.job, e.station);
                    seen.layer_of.insert(key, height);
                    seen.current = Some(height);
                    let attempt = |b: &asbuilt_protocol::StationEvent| {
                        crate::attempts::attempt_of(b.attempt.into())
                    };
                    let latest = seen.begun.entry(key).or_insert(e);
                    if attempt(&e) >= attempt(latest) {
                        *latest = e;
                    }
                    seen.begun_at.insert(key, e.timestamp_ns);
                }
                _ => {}
            }
        }
        let _ = recording::scan_layer_states(&map, |r| {
            if r.job != job {
                return;
            }
            let height = r.printed_height.to_bits();
            seen.states.retain(|s| {
                s.printed_height.to_bits() == height
                    && (s.station, s.attempt) != (r.station, r.attempt)
            });
            seen.states.push(r);
        });
    }
    seen
}

/// Why a recorded scan layer state is not taken up.
#[derive(Debug, thiserror::Error)]
enum StateError {
    /// Its bytes do not decode.
    #[error("it does not decode: {0}")]
    Decode(#[from] postcard::Error),
    /// It decodes but cannot be taken up.
    #[error(transparent)]
    Restore(#[from] crate::lifecycle::RestoreError),
}

/// Takes up the scan layer from a recorded state, `r`, and `before`, the one recorded before
/// `r`'s station first closed (`None`: the scan layer's first station); the states' bytes.
fn restore<C: ChunkSource>(
    lifecycle: &mut Lifecycle<C>,
    r: &ScanLayerStateRecord,
    before: Option<&ScanLayerStateRecord>,
    profiled: bool,
) -> Result<usize, StateError> {
    let decode = |r: &ScanLayerStateRecord| postcard::from_bytes::<ScanLayerState>(&r.state);
    let state = decode(r)?;
    let before_state = before.map(decode).transpose()?;
    lifecycle.restore_scan_layer(
        r.job,
        r.printed_height,
        &state,
        Some((r.station, before_state.as_ref())),
        profiled,
    )?;
    Ok(r.state.len() + before.map_or(0, |b| b.state.len()))
}

/// Feeds the current scan layer's recorded inputs through the lifecycle again, in the order
/// the agent took them.
fn replay_layer<C>(
    files: &[&JobFile],
    lifecycle: &mut Lifecycle<C>,
    in_layer: &dyn Fn(StationKey) -> bool,
    resumed: &mut Resumed,
) where
    C: ChunkSource + From<(ChunkHeader, Vec<ScanPoint>)>,
{
    let mut out = Replayed::default();
    let mut stations = std::collections::BTreeSet::new();
    for f in files {
        read_file(f, &mut resumed.unreadable, |m| {
            let key = match &m {
                Recorded::Event(e) => (e.job, e.station),
                Recorded::Pose(p) => (p.job, p.station),
                Recorded::Chunk(h, _) => (h.job, h.station),
                Recorded::MountPose(m) => (m.job, m.pass),
                Recorded::Profiles(h, _) => (h.job, h.pass),
                Recorded::Report(r) => (r.job, r.station),
                _ => return,
            };
            if !in_layer(key) {
                return;
            }
            let points = match &m {
                Recorded::Chunk(_, p) => Some(p.len()),
                Recorded::Profiles(_, p) => Some(p.len()),
                _ => None,
            };
            if let Some(n) = points {
                resumed.points_replayed += n as u64;
                stations.insert(key);
            }
            crate::replay::feed(lifecycle, m, Instant::now(), &mut out);
        });
    }
    lifecycle.wait_designs(Instant::now(), &mut out);
    resumed.stations_replayed = stations.len();
    let unrecorded: Vec<StationReport> = out
        .reports
        .into_iter()
        .filter(|r| {
            !resumed
                .recorded
                .iter()
                .any(|x| (x.job, x.station, x.attempt) == (r.job, r.station, r.attempt))
        })
        .collect();
    resumed.unrecorded.extend(unrecorded);
}

/// Calls `take` with every message of a file in the order the agent took them; a file that
/// stops reading is noted in `unreadable`.
fn read_file(f: &JobFile, unreadable: &mut Vec<String>, mut take: impl FnMut(Recorded)) {
    let map = match map(&f.path) {
        Ok(m) => m,
        Err(e) => {
            unreadable.push(format!("{}: {e}", f.path.display()));
            return;
        }
    };
    let messages = match recording::messages_in_agent_order(&map) {
        Ok(m) => m,
        Err(e) => {
            unreadable.push(format!("{}: {e}", f.path.display()));
            return;
        }
    };
    for m in messages {
        match m {
            Ok((_, m)) => take(m),
            Err(e) => {
                unreadable.push(format!("{}: {}", f.path.display(), describe(&e)));
                return;
            }
        }
    }
}

fn describe(e: &ReadError) -> String {
    format!("{e}; the messages after it are left out")
}

/// The replay's outputs: the reports it gives are kept, to find those never recorded; the
/// deviations are computed into a scratch buffer and forgotten.
#[derive(Default)]
struct Replayed {
    reports: Vec<StationReport>,
    scratch: Vec<PointDeviation>,
}

impl Outputs for Replayed {
    fn deviations(
        &mut self,
        n: usize,
        fill: &mut dyn FnMut(&mut [PointDeviation]) -> DeviationHeader,
    ) {
        if self.scratch.len() < n {
            self.scratch.resize(n, PointDeviation::default());
        }
        fill(&mut self.scratch[..n]);
    }

    fn report(&mut self, report: &StationReport) {
        self.reports.push(*report);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_give_job_stamp_and_part_and_sort_in_writing_order() {
        let a = JobFile::parse(Path::new("/r/job-7-1700000000.mcap")).unwrap();
        let b = JobFile::parse(Path::new("/r/job-7-1700000000-part2.mcap")).unwrap();
        let c = JobFile::parse(Path::new("/r/job-7-1700000005.mcap")).unwrap();
        assert_eq!((a.job, a.stamp, a.part), (7, 1_700_000_000, 1));
        assert_eq!(b.part, 2);
        let mut v = vec![c.clone(), b.clone(), a.clone()];
        v.sort();
        assert_eq!(v, [a, b, c]);
        for bad in [
            "job-7.mcap",
            "x-7-1.mcap",
            "job-7-1-p2.mcap",
            "job-7-1.mcap.damaged",
        ] {
            assert!(JobFile::parse(Path::new(bad)).is_none(), "{bad}");
        }
    }
}
