//! The simulated print cell on the wire: a job planned from a part, its defects and its scan
//! layers, scanned by the simulated scanner and sent to a running agent over its iceoryx2
//! services exactly as a robot controller, a scanner driver and job control would (Begin, pose,
//! chunks in scan-line order at the scanner's rate, End), with the agent's reports and findings
//! collected as they come back.

use std::time::{Duration, Instant};

use crate::{
    AsBuilt, Defect, LayerSettings, Part, Scan, ScannerModel, Truth, as_built_with, built_layers,
    perturb, scan, stations_around,
};
use asbuilt_protocol::ipc::CellPorts;
use asbuilt_protocol::{
    ChunkHeader, FixedText, LayerApplied, LayerCorrection, Paced, PoseMode, PoseSnapshot,
    ScanPoint, StationEvent, StationEventKind, StationFindings, StationReport, StationSender,
    StationSink, StationStatus, codec, unix_time_ns,
};
use nalgebra::{Isometry3, Point3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Why a simulated job could not go on.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The job asks for chunks without points.
    #[error("chunks need at least one point")]
    NoChunkPoints,
    /// The job allows no attempt at a station.
    #[error("a station needs at least one attempt")]
    NoAttempts,
    /// The part cannot be built as its defects say.
    #[error(transparent)]
    Part(#[from] crate::PartError),
    /// The agent's services failed (it is gone, stuck, or was never there).
    #[error(transparent)]
    Ipc(#[from] asbuilt_protocol::ipc::IpcError),
    /// The agent's outputs cannot be read.
    #[error("cannot read the agent's outputs: {0}")]
    Outputs(String),
    /// Sending an attempt stopped: the agent reported it interrupted. The cell sends the
    /// station again.
    #[error("{0}")]
    Cut(String),
    /// A file cannot be written.
    #[error("cannot write {}", path.display())]
    Write {
        /// The file.
        path: std::path::PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
}

pub(crate) type Result<T, E = SimError> = std::result::Result<T, E>;

/// A print job to simulate.
#[derive(Debug, Clone)]
pub struct SimJob {
    /// The part to print.
    pub part: Part,
    /// Defects of the print.
    pub defects: Vec<Defect>,
    /// Layer counts after which the robot scans, ascending.
    pub scan_after: Vec<u32>,
    /// Stations around the part at each scan layer.
    pub stations_per_scan: u32,
    /// Stations stand this far out from the part's footprint and this far above its top, m.
    pub standoff: f64,
    /// Metres the stations stand above the printed top.
    pub lift: f64,
    /// `FixedOrientation` (the Z+F mounting) or `SixDof`.
    pub pose_mode: PoseMode,
    /// Pose error of the robot-mounted scanner, metres and radians (six-DoF only).
    pub position_sigma: f64,
    /// One-sigma rotation error of the robot pose, radians.
    pub rotation_sigma: f64,
    /// The scanner's model: angular step, ranges, noise, dropout, mixed pixels.
    pub scanner: ScannerModel,
    /// Seed of every random draw, so a job gives the same points each time.
    pub seed: u64,
    /// The job number the messages carry.
    pub job: u64,
    /// When the cell started the job, ns since the Unix epoch (`StationEvent::job_started_ns`):
    /// the time [`SimJob::new`] ran; a cell that sends a job again after a restart sets the
    /// first run's, so that the agent takes it as the same print.
    pub job_started_ns: u64,
    /// Points per scan chunk sent.
    pub chunk_points: usize,
    /// Points per second, or `None` for as fast as the agent takes them.
    pub rate: Option<f64>,
    /// Wait for a station's report before the next station begins, as a scanner carried from
    /// station to station does. Off, the cell runs ahead of the agent as far as its queues let it.
    pub one_station_at_a_time: bool,
    /// Tries at a station before the cell gives up on it: a station that is reported
    /// interrupted or unfinished, or whose sending fails (the agent stopped), is scanned and sent
    /// again as its next attempt.
    pub max_attempts: u8,
    /// The printer applies the agent's latest advice (`PREFIX/agent/corrections`) from the
    /// next layer it prints, as a controller would; it waits for the advice after each scan
    /// layer's last station before printing on.
    pub closed_loop: bool,
    /// The share of each advice the closed-loop printer applies (0 to 1; 1 by default): the
    /// cell decides. Whatever it applies, it tells the agent layer by layer
    /// (`PREFIX/printer/applied`).
    pub apply: f64,
    /// Scan while printing with this line profiler, every layer a pass
    /// ([`crate::run_printing`]), instead of the scanner's stations.
    pub profiler: Option<crate::profiler::ProfilerModel>,
    /// Profiles a profiler's chunk carries.
    pub profiles_per_chunk: usize,
    /// With a profiler: the layers printed, each a pass (`None`: the whole part).
    pub print_layers: Option<u32>,
}

impl SimJob {
    /// A job on `part` without defects: one scan of the finished part from four stations, a Z+F
    /// at its native rate. Callers set the scan layers and defects they want.
    pub fn new(part: Part) -> Self {
        Self {
            scan_after: vec![part.layers()],
            part,
            defects: Vec::new(),
            stations_per_scan: 4,
            standoff: 1.2,
            lift: 0.5,
            pose_mode: PoseMode::FixedOrientation,
            position_sigma: 0.001,
            rotation_sigma: 0.0002,
            scanner: ScannerModel::default(),
            seed: 1,
            job: 1,
            job_started_ns: unix_time_ns(),
            chunk_points: 16_384,
            rate: Some(1.0e6),
            one_station_at_a_time: true,
            max_attempts: 5,
            closed_loop: false,
            apply: 1.0,
            profiler: None,
            profiles_per_chunk: asbuilt_protocol::MAX_PROFILES_PER_CHUNK,
            print_layers: None,
        }
    }

    /// With a profiler, the points its passes return, roughly: each layer's outlines at the
    /// print speed, three rays in four returning.
    pub fn profiler_points(&self) -> Option<f64> {
        let m = self.profiler?;
        let length = |z: f64| -> f64 {
            let rings = self.part.section(z).unwrap_or_default();
            rings
                .iter()
                .flat_map(|r| (0..r.len()).map(move |k| (r[k], r[(k + 1) % r.len()])))
                .map(|(a, b)| (b[0] - a[0]).hypot(b[1] - a[1]))
                .sum()
        };
        let profiles: f64 = self
            .plan()
            .iter()
            .map(|p| length(p.printed_height - 0.5 * self.part.layer_height) / m.speed * m.rate_hz)
            .sum();
        Some(profiles * m.points as f64 * 0.75)
    }

    /// The most points a chunk of the job carries: a scan chunk's, or a profiler's.
    pub fn chunk_capacity(&self) -> usize {
        let profiles = self
            .profiler
            .map_or(0, |m| m.points * self.profiles_per_chunk);
        self.chunk_points.max(profiles)
    }

    /// Every station of the job, in the order the robot visits them (a profiler's passes, one
    /// a layer).
    pub fn plan(&self) -> Vec<PlannedStation> {
        if self.profiler.is_some() {
            // Scanning while printing: every layer is a pass, numbered as the layer.
            let layers = self.print_layers.unwrap_or(u32::MAX);
            return (0..layers.min(self.part.layers()))
                .map(|layer| PlannedStation {
                    index: layer,
                    name: format!("L{:03}-pass", layer + 1),
                    printed: layer + 1,
                    printed_height: self.part.layer_span(layer).1,
                    nominal: Isometry3::identity(),
                    truth: Isometry3::identity(),
                })
                .collect();
        }
        let (lo, hi) = self.part.design.bounds();
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let mut out = Vec::new();
        for &printed in &self.scan_after {
            let printed = printed.clamp(1, self.part.layers());
            let height = self.part.layer_span(printed - 1).1;
            let poses = stations_around(
                lo,
                hi,
                height,
                self.stations_per_scan,
                self.standoff,
                self.lift,
            );
            for (k, nominal) in poses.into_iter().enumerate() {
                let rot = match self.pose_mode {
                    PoseMode::SixDof => self.rotation_sigma,
                    _ => 0.0,
                };
                let truth = perturb(&nominal, self.position_sigma, rot, &mut rng);
                out.push(PlannedStation {
                    index: out.len() as u32,
                    name: format!("L{printed:03}-S{}", k + 1),
                    printed,
                    printed_height: height,
                    nominal,
                    truth,
                });
            }
        }
        out
    }
    /// The job and the truth of each scan layer, as `truth.json` holds it for a reviewer: the
    /// defects, what each did by each scan layer, and the print as built with `settings` (what
    /// the printer applied per layer; empty for a print as designed): each layer's top, width
    /// and shift error, and the top's error at each scan layer.
    pub fn truth_json(&self, settings: &[LayerSettings]) -> serde_json::Value {
        let t = |t: &Truth| {
            serde_json::json!({
                "kind": t.kind.as_str(),
                "magnitude_m": t.magnitude,
                "position_m": [t.position.x, t.position.y, t.position.z],
                "layers": [t.layers.0, t.layers.1],
                "direction": t.direction,
            })
        };
        let last = self.scan_after.last().copied().unwrap_or(0);
        let built = built_layers(&self.part, &self.defects, last, settings).unwrap_or_default();
        let scans: Vec<serde_json::Value> = self
            .scan_after
            .iter()
            .filter_map(|&k| {
                let layers = built_layers(&self.part, &self.defects, k, settings).ok()?;
                let top = layers.last()?;
                Some(serde_json::json!({
                    "after_layers": k,
                    "top_error_m": top.top_error_m,
                    "width_error_m": top.width_error_m,
                    "shift_m": top.shift_m,
                }))
            })
            .collect();
        let applied: Vec<serde_json::Value> = settings
            .iter()
            .enumerate()
            .filter(|(_, s)| **s != LayerSettings::NOMINAL)
            .map(|(j, s)| {
                serde_json::json!({
                    "layer": j,
                    "z_offset_m": s.z_offset,
                    "flow": s.flow,
                    "path_offset_m": s.path_offset,
                })
            })
            .collect();
        serde_json::json!({
            "part": self.part.name,
            "layer_height_m": self.part.layer_height,
            "bead_width_m": self.part.bead_width().ok(),
            "scan_after_layers": self.scan_after,
            "closed_loop": self.closed_loop,
            "defects": self.defects.iter().map(|d| format!("{d:?}")).collect::<Vec<_>>(),
            "truth": self.truth().iter().map(|(k, tr)| {
                let mut v = t(tr);
                v["after_layers"] = serde_json::json!(k);
                v
            }).collect::<Vec<_>>(),
            "as_built_at_scans": scans,
            "as_built_layers": built,
            "corrections_applied": applied,
        })
    }

    /// What each defect did by each scan layer.
    pub fn truth(&self) -> Vec<(u32, Truth)> {
        self.scan_after
            .iter()
            .flat_map(|&k| {
                self.defects
                    .iter()
                    .filter_map(move |d| d.truth(&self.part, k).map(|t| (k, t)))
            })
            .collect()
    }

    /// The as-built part after `printed` layers, printed as designed.
    pub fn as_built(&self, printed: u32) -> Result<AsBuilt> {
        self.as_built_with(printed, &[])
    }

    /// The as-built part after `printed` layers, each printed with its `settings`.
    pub fn as_built_with(&self, printed: u32, settings: &[LayerSettings]) -> Result<AsBuilt> {
        Ok(as_built_with(&self.part, &self.defects, printed, settings)?)
    }

    /// The scan of one station, repeatable from the job's seed.
    pub fn scan(&self, st: &PlannedStation, part: &AsBuilt) -> Scan {
        scan(
            part,
            &st.truth,
            &self.scanner,
            self.seed
                .wrapping_mul(1_000_003)
                .wrapping_add(st.index as u64),
        )
    }
}

/// A station the job will scan from.
#[derive(Debug, Clone)]
pub struct PlannedStation {
    /// The station's number within the job.
    pub index: u32,
    /// The station's name: its scan layer and place around the part.
    pub name: String,
    /// Layers printed when it scans.
    pub printed: u32,
    /// Nominal height of the print then, metres.
    pub printed_height: f64,
    /// The pose the robot reports.
    pub nominal: Isometry3<f64>,
    /// Where the scanner really was.
    pub truth: Isometry3<f64>,
}

impl PlannedStation {
    /// The scanner's origin as the robot reports it.
    pub fn origin(&self) -> Point3<f64> {
        Point3::from(self.nominal.translation.vector)
    }
}

/// What happened, as it happened.
pub enum SimEvent<'a> {
    /// A station's scan was simulated.
    Scanned {
        /// The station.
        station: &'a PlannedStation,
        /// Its scan.
        scan: &'a Scan,
        /// Seconds the simulation took.
        seconds: f64,
    },
    /// A station's messages were sent to the agent.
    Sent {
        /// The station.
        station: &'a PlannedStation,
        /// Points sent.
        points: u64,
        /// Seconds the sending took.
        seconds: f64,
    },
    /// The agent reported a station attempt.
    Report(&'a StationReport),
    /// A station attempt did not end complete: the cell tries the station again (when
    /// `attempt` is below the job's `max_attempts`).
    Retry {
        /// The station.
        station: &'a PlannedStation,
        /// The attempt that did not end complete.
        attempt: u8,
        /// What happened to it.
        why: &'a str,
    },
    /// The agent sent a station's findings.
    Findings(&'a StationFindings),
    /// The agent sent advice for the layers still to print.
    Correction(&'a LayerCorrection),
    /// The printer prints `layers` (inclusive) with `advice` (closed loop).
    Printing {
        /// First and last layer.
        layers: (u32, u32),
        /// The advice applied; `None`: none came, the layers are printed as designed.
        advice: Option<&'a LayerCorrection>,
    },
}

/// What a job sent and got back.
#[derive(Debug, Default)]
pub struct SimOutcome {
    /// Points sent over every station.
    pub points_sent: u64,
    /// Seconds the whole job took, up to its last report (or the end of the wait for it).
    pub seconds: f64,
    /// Each station's report of its latest attempt, in the order stations were first reported.
    pub reports: Vec<StationReport>,
    /// Every attempt's report, as they came (a report published again comes once).
    pub attempts: Vec<StationReport>,
    /// The station attempts that did not end complete: station, attempt, what happened.
    pub retries: Vec<(u32, u8, String)>,
    /// The serving agent's process id, from its status, and since when it serves: a new one
    /// means the agent was started again.
    pub agent: Option<(u32, Instant)>,
    /// The findings, as they came.
    pub findings: Vec<StationFindings>,
    /// The latest advice after each station, as it came.
    pub corrections: Vec<LayerCorrection>,
    /// What the printer applied to each layer (closed loop; empty when open).
    pub settings: Vec<LayerSettings>,
    /// The latest surface judgement after each station (when the agent's `[tolerances]` names
    /// a standard).
    pub surface: Vec<asbuilt_protocol::SurfaceFindings>,
}

impl SimOutcome {
    /// What did not end well: stations without a report, or never reported complete in the
    /// job's attempts; `None` when every station ended complete.
    pub fn unfinished(&self, job: &SimJob) -> Option<String> {
        let expected = job.plan().len();
        if self.reports.len() < expected {
            let missing = expected - self.reports.len();
            return Some(format!("{missing} of {expected} station(s) got no report"));
        }
        let unfinished: Vec<String> = self
            .reports
            .iter()
            .filter(|r| r.status() != Some(StationStatus::Complete))
            .map(|r| format!("{} ({:?})", r.name.as_str(), r.status()))
            .collect();
        (!unfinished.is_empty()).then(|| match job.profiler {
            // A layer laid is printed over: its pass is never sent again.
            Some(_) => format!(
                "{} pass(es) did not end complete: {}",
                unfinished.len(),
                unfinished.join(", ")
            ),
            None => format!(
                "{} station(s) never ended complete in {} attempt(s): {}",
                unfinished.len(),
                job.max_attempts,
                unfinished.join(", ")
            ),
        })
    }

    /// The latest findings of each scan layer (they cover its stations so far).
    pub fn findings_by_layer(&self) -> Vec<&StationFindings> {
        let mut out: Vec<&StationFindings> = Vec::new();
        for f in &self.findings {
            match out.iter_mut().find(|g| g.layer == f.layer) {
                Some(g) if g.stations <= f.stations => *g = f,
                Some(_) => {}
                None => out.push(f),
            }
        }
        out.sort_by_key(|f| f.layer);
        out
    }
}

/// Sends the job to the agent behind `ports`; waits up to `wait` for the last report (and for
/// findings, when `expect_findings`). A station attempt that is not reported complete is tried
/// again, up to the job's `max_attempts`.
pub fn run(
    job: &SimJob,
    ports: &CellPorts,
    expect_findings: bool,
    wait: Duration,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<SimOutcome> {
    if let Some(model) = &job.profiler {
        let n = job.profiles_per_chunk;
        return crate::run_printing(job, model, n, ports, expect_findings, wait, on);
    }
    if job.chunk_points == 0 {
        return Err(SimError::NoChunkPoints);
    }
    if job.max_attempts == 0 {
        return Err(SimError::NoAttempts);
    }
    let plan = job.plan();
    let mut out = SimOutcome::default();
    let started = Instant::now();
    let mut current: Option<(u32, AsBuilt)> = None;
    // Attempts sent whose report is still to come, oldest first.
    let mut in_flight: std::collections::VecDeque<Attempt<'_>> = Default::default();
    // The serving agent's status (kept in the service's history), before the first station.
    collect(job.job, ports, &mut out, on)?;
    let mut settings: Vec<LayerSettings> = Vec::new();
    let mut previous: Option<&PlannedStation> = None;
    for st in &plan {
        if current.as_ref().map(|c| c.0) != Some(st.printed) {
            if job.closed_loop {
                // The printer goes on only with the last scan layer's advice in hand.
                while let Some(a) = in_flight.pop_front() {
                    settle(job, a, ports, wait, &settings, &mut out, on)?;
                }
                let advice = match previous {
                    Some(p) => wait_for_advice(job, p.index, ports, &mut out, on)?,
                    None => None,
                };
                let from = settings.len() as u32;
                settings.extend((from..st.printed).map(|j| {
                    advice.map_or(LayerSettings::NOMINAL, |c| {
                        LayerSettings::advised(&c, j).scaled(job.apply)
                    })
                }));
                let followed = advice.map_or(u32::MAX, |c| c.layer);
                tell_applied(job, ports, &settings, from..st.printed, followed)?;
                if from < st.printed {
                    on(SimEvent::Printing {
                        layers: (from, st.printed - 1),
                        advice: advice.as_ref(),
                    });
                }
            }
            current = Some((st.printed, job.as_built_with(st.printed, &settings)?));
        }
        previous = Some(st);
        let part = &current.as_ref().expect("set above").1;
        let t = Instant::now();
        let s = job.scan(st, part);
        on(SimEvent::Scanned {
            station: st,
            scan: &s,
            seconds: t.elapsed().as_secs_f64(),
        });
        // The robot moves on once the scanner is done; the agent may still be busy with the
        // last station's points. Waiting for its report keeps one station in flight, as a
        // scanner that is carried from station to station sends them.
        if job.one_station_at_a_time {
            while let Some(a) = in_flight.pop_front() {
                settle(job, a, ports, wait, &settings, &mut out, on)?;
            }
        }
        let mut a = Attempt {
            station: st,
            attempt: 1,
            scan: job.one_station_at_a_time.then_some(s),
            cut: None,
            agent: None,
        };
        send_attempt(job, &mut a, ports, &settings, &mut out, on)?;
        in_flight.push_back(a);
    }
    while let Some(a) = in_flight.pop_front() {
        settle(job, a, ports, wait, &settings, &mut out, on)?;
    }
    out.settings = settings;
    finish(job, ports, (expect_findings, wait), started, out, on)
}

/// Waits up to `wait` for what is still to come of the job's stations (every report; the
/// findings when expected; closed loop, the advice after each, the last too).
pub(crate) fn finish(
    job: &SimJob,
    ports: &CellPorts,
    (expect_findings, wait): (bool, Duration),
    started: Instant,
    mut out: SimOutcome,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<SimOutcome> {
    let n = job.plan().len();
    let deadline = Instant::now() + wait;
    let done = |o: &SimOutcome| {
        o.reports.len() >= n
            && (!expect_findings || o.findings.len() >= n)
            && (!job.closed_loop || o.corrections.len() >= n)
    };
    while !done(&out) && Instant::now() < deadline {
        ports.wait_for_output(Duration::from_millis(100))?;
        collect(job.job, ports, &mut out, on)?;
    }
    out.seconds = started.elapsed().as_secs_f64();
    Ok(out)
}

/// Tells the agent what the printer applied to `layers`, as the settings it printed them with
/// (`followed`: the layer of the advice they follow, `u32::MAX` for none).
pub(crate) fn tell_applied(
    job: &SimJob,
    ports: &CellPorts,
    settings: &[LayerSettings],
    layers: std::ops::Range<u32>,
    followed: u32,
) -> Result<()> {
    for j in layers {
        let s = settings
            .get(j as usize)
            .copied()
            .unwrap_or(LayerSettings::NOMINAL);
        let mut a = LayerApplied::nominal(job.job, j);
        a.advice_layer = followed;
        a.z_offset = s.z_offset;
        a.flow = s.flow;
        a.path_offset = s.path_offset;
        a.timestamp_ns = unix_time_ns();
        ports.send_applied(&a)?;
    }
    Ok(())
}

/// How long the printer waits for the advice after a scan layer's last station was reported.
const ADVICE_WAIT: Duration = Duration::from_secs(5);

/// The advice after `station` (the last of its scan layer); when none comes within
/// [`ADVICE_WAIT`] (the agent's `[corrections]` are off, or it was lost), the latest advice
/// the agent gave, if any.
pub(crate) fn wait_for_advice(
    job: &SimJob,
    station: u32,
    ports: &CellPorts,
    out: &mut SimOutcome,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<Option<LayerCorrection>> {
    let deadline = Instant::now() + ADVICE_WAIT;
    loop {
        collect(job.job, ports, out, on)?;
        if let Some(c) = out.corrections.iter().find(|c| c.station == station) {
            return Ok(Some(*c));
        }
        if Instant::now() >= deadline {
            return Ok(out
                .corrections
                .iter()
                .max_by_key(|c| (c.layer, c.station))
                .copied());
        }
        ports.wait_for_output(Duration::from_millis(50))?;
    }
}

/// One try at a station: what was sent, and why it was cut short if it was.
struct Attempt<'a> {
    station: &'a PlannedStation,
    attempt: u8,
    /// The station's scan, kept while one station is in flight at a time; scanned again (the
    /// same points: the noise is drawn from the seed and the station) when it is not.
    scan: Option<Scan>,
    /// Why sending stopped early: the agent reported the attempt interrupted, or a send failed.
    cut: Option<String>,
    /// The agent (process id) serving when the attempt was sent.
    agent: Option<u32>,
}

/// Sends an attempt; a failed send or an interrupted report cuts it short, which is noted in
/// the attempt rather than returned as an error, so that the station can be tried again.
fn send_attempt(
    job: &SimJob,
    a: &mut Attempt<'_>,
    ports: &CellPorts,
    settings: &[LayerSettings],
    out: &mut SimOutcome,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<()> {
    let rescanned;
    let s = match &a.scan {
        Some(s) => s,
        None => {
            rescanned = job.scan(a.station, &job.as_built_with(a.station.printed, settings)?);
            &rescanned
        }
    };
    let t = Instant::now();
    a.agent = out.agent.map(|(pid, _)| pid);
    a.cut = match send_station(job, a.station, a.attempt, s, ports, out, on) {
        Ok(()) => None,
        Err(SimError::Cut(why)) => Some(why),
        // The agent is gone or stuck: the next attempt goes to the one that replaces it.
        Err(SimError::Ipc(e)) => Some(format!("sending failed: {}", asbuilt_io::error_message(&e))),
        Err(e) => return Err(e),
    };
    on(SimEvent::Sent {
        station: a.station,
        points: s.points.len() as u64,
        seconds: t.elapsed().as_secs_f64(),
    });
    Ok(())
}

/// Waits for an attempt's report and tries the station again until an attempt is reported
/// complete or the attempts run out.
fn settle(
    job: &SimJob,
    mut a: Attempt<'_>,
    ports: &CellPorts,
    wait: Duration,
    settings: &[LayerSettings],
    out: &mut SimOutcome,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<()> {
    loop {
        let why = match a.cut.take() {
            Some(why) => why,
            None => match wait_for_report(job.job, &a, ports, wait, out, on)? {
                Waited::Reported(StationStatus::Complete) => return Ok(()),
                Waited::Reported(status) => format!("reported {status:?}"),
                Waited::Replaced(pid) => format!(
                    "lost: the agent was started again (process {pid}) and does not know it"
                ),
                Waited::Nothing => format!("no report within {:.0} s", wait.as_secs_f64()),
            },
        };
        on(SimEvent::Retry {
            station: a.station,
            attempt: a.attempt,
            why: &why,
        });
        out.retries.push((a.station.index, a.attempt, why));
        if a.attempt >= job.max_attempts {
            return Ok(());
        }
        a.attempt += 1;
        send_attempt(job, &mut a, ports, settings, out, on)?;
    }
}

/// How long a new agent has to report an attempt sent to the one it replaced: it resumes the
/// job from its recording at start, and reports what it knows of at once.
const REPLACED_GRACE: Duration = Duration::from_secs(2);

/// What waiting for an attempt's report came to.
enum Waited {
    /// Its report came, with this status.
    Reported(StationStatus),
    /// The agent it was sent to was replaced (by this process) and the new one has not
    /// reported it within [`REPLACED_GRACE`]: the attempt's messages were lost with the old.
    Replaced(u32),
    /// Nothing within the wait.
    Nothing,
}

/// Waits for the report of an attempt.
fn wait_for_report(
    job: u64,
    a: &Attempt<'_>,
    ports: &CellPorts,
    wait: Duration,
    out: &mut SimOutcome,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<Waited> {
    let deadline = Instant::now() + wait;
    loop {
        collect(job, ports, out, on)?;
        if let Some(r) = out.report_of(a.station.index, a.attempt) {
            return Ok(Waited::Reported(
                r.status().unwrap_or(StationStatus::Incomplete),
            ));
        }
        if let Some((pid, since)) = out.agent
            && a.agent.is_some_and(|sent_to| sent_to != pid)
            && since.elapsed() >= REPLACED_GRACE
        {
            return Ok(Waited::Replaced(pid));
        }
        if Instant::now() >= deadline {
            return Ok(Waited::Nothing);
        }
        ports.wait_for_output(Duration::from_millis(50))?;
    }
}

impl SimOutcome {
    /// The report of `attempt` of `station`, once it came.
    pub fn report_of(&self, station: u32, attempt: u8) -> Option<&StationReport> {
        self.attempts
            .iter()
            .find(|r| r.station == station && r.attempt.max(1) == attempt)
    }
}

fn send_station(
    job: &SimJob,
    st: &PlannedStation,
    attempt: u8,
    s: &Scan,
    ports: &CellPorts,
    out: &mut SimOutcome,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<()> {
    let n = s.points.len();
    let mut begin = StationEvent::new(StationEventKind::Begin, job.job, st.index);
    begin.job_started_ns = job.job_started_ns;
    begin.name = FixedText::truncated(&st.name);
    begin.layer = st.printed - 1;
    begin.printed_height = st.printed_height;
    begin.expected_chunks = n.div_ceil(job.chunk_points) as u32;
    begin.expected_points = n as u64;
    begin.attempt = attempt;
    let mut pose = PoseSnapshot::new(job.job, st.index, job.pose_mode);
    pose.translation = st.nominal.translation.vector.into();
    let q = st.nominal.rotation.coords;
    pose.rotation_xyzw = [q.x, q.y, q.z, q.w];
    pose.position_sigma = job.position_sigma;
    let sink = CellSink {
        ports,
        job: job.job,
        station: st.index,
        attempt,
        out,
        on,
    };
    let mut sink = Paced::new(sink, job.rate, Instant::now(), 0);
    let mut sender = StationSender::start(begin, pose, &mut sink)?;
    for chunk in s.points.chunks(job.chunk_points) {
        sender.chunk(chunk, &mut sink)?;
    }
    sender.finish(&mut sink)?;
    collect(job.job, ports, sink.inner.out, sink.inner.on)
}

/// The cell's ports, taking the agent's answers after every chunk (paced to the scanner's
/// rate by [`Paced`]).
struct CellSink<'a> {
    ports: &'a CellPorts,
    job: u64,
    station: u32,
    attempt: u8,
    out: &'a mut SimOutcome,
    on: &'a mut dyn FnMut(SimEvent<'_>),
}

impl StationSink for CellSink<'_> {
    type Error = SimError;
    fn now_ns(&mut self, _points_sent: u64) -> u64 {
        unix_time_ns()
    }
    fn event(&mut self, event: &StationEvent) -> Result<()> {
        Ok(self.ports.send_event(event)?)
    }
    fn pose(&mut self, pose: &PoseSnapshot) -> Result<()> {
        Ok(self.ports.send_pose(pose)?)
    }
    fn chunk(&mut self, header: &ChunkHeader, points: &[ScanPoint]) -> Result<()> {
        self.ports.send_chunk(header, points)?;
        self.out.points_sent += points.len() as u64;
        collect(self.job, self.ports, self.out, self.on)?;
        // An agent started again reports the attempt it could not finish at once: the rest of
        // it would be dropped, so the cell stops and sends the station again.
        match self.out.report_of(self.station, self.attempt) {
            Some(r) if r.status() == Some(StationStatus::Interrupted) => {
                Err(SimError::Cut("reported Interrupted while sending".into()))
            }
            _ => Ok(()),
        }
    }
}

/// Takes whatever the agent sent back; deviations are for other subscribers.
pub(crate) fn collect(
    job: u64,
    ports: &CellPorts,
    out: &mut SimOutcome,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<()> {
    let bad = |e: &dyn std::fmt::Debug| SimError::Outputs(format!("{e:?}"));
    while let Some(r) = ports.reports.receive().map_err(|e| bad(&e))? {
        let r = *r.payload();
        // Reports are delivered at least once (an agent that resumes a job publishes its
        // recorded reports again): each attempt counts once.
        if r.job != job || out.report_of(r.station, r.attempt.max(1)).is_some() {
            continue;
        }
        on(SimEvent::Report(&r));
        out.attempts.push(r);
        match out.reports.iter_mut().find(|x| x.station == r.station) {
            Some(x) if x.attempt <= r.attempt => *x = r,
            Some(_) => {}
            None => out.reports.push(r),
        }
    }
    while let Some(sample) = ports.findings.receive().map_err(|e| bad(&e))? {
        match codec::decode::<StationFindings>(sample.payload()) {
            Ok(f) if f.job == job => {
                // A station tried again gives its findings again: the latest stand. The same
                // findings published twice (an agent resuming) come once.
                match out.findings.iter_mut().find(|x| x.station == f.station) {
                    Some(x) if *x == f => continue,
                    Some(x) => *x = f.clone(),
                    None => out.findings.push(f.clone()),
                }
                on(SimEvent::Findings(&f));
            }
            Ok(_) => {}
            Err(e) => eprintln!("warning: findings from the agent cannot be read: {e}"),
        }
    }
    while let Some(sample) = ports.corrections.receive().map_err(|e| bad(&e))? {
        let c = *sample.payload();
        if c.job != job {
            continue;
        }
        // The latest advice after each station stands; the same advice again comes once.
        match out.corrections.iter_mut().find(|x| x.station == c.station) {
            Some(x) if codec::encode(x) == codec::encode(&c) => continue,
            Some(x) => *x = c,
            None => out.corrections.push(c),
        }
        on(SimEvent::Correction(&c));
    }
    while let Some(sample) = ports.surface.receive().map_err(|e| bad(&e))? {
        match codec::decode::<asbuilt_protocol::SurfaceFindings>(sample.payload()) {
            Ok(s) if s.job == job => {
                match out.surface.iter_mut().find(|x| x.station == s.station) {
                    Some(x) => *x = s,
                    None => out.surface.push(s),
                }
            }
            Ok(_) => {}
            Err(e) => eprintln!("warning: a surface judgement from the agent cannot be read: {e}"),
        }
    }
    while let Ok(Some(_)) = ports.deviations.receive() {}
    while let Ok(Some(s)) = ports.status.receive() {
        let pid = s.payload().process_id;
        if out.agent.is_none_or(|(known, _)| known != pid) {
            out.agent = Some((pid, Instant::now()));
        }
    }
    Ok(())
}

/// Writes a design as a binary STL in metres, for an agent to load.
pub fn write_stl(path: &std::path::Path, d: &asbuilt_core::Design) -> Result<()> {
    let tri = |t: &[u32; 3]| {
        let [a, b, c] = t.map(|i| d.vertices[i as usize]);
        let n = (b - a).cross(&(c - a)).normalize();
        let v =
            |p: nalgebra::Point3<f64>| stl_io::Vertex::new([p.x as f32, p.y as f32, p.z as f32]);
        stl_io::Triangle {
            normal: stl_io::Normal::new([n.x as f32, n.y as f32, n.z as f32]),
            vertices: [v(a), v(b), v(c)],
        }
    };
    let failed = |source| SimError::Write {
        path: path.to_path_buf(),
        source,
    };
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).map_err(failed)?);
    stl_io::write_stl(&mut f, d.triangles.iter().map(tri)).map_err(failed)
}
