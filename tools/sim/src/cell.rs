//! The simulated print cell on the wire: a job planned from a part, its defects and its scan
//! layers, scanned by the simulated scanner and sent to a running agent over its iceoryx2
//! services exactly as a robot controller, a scanner driver and job control would (Begin, pose,
//! chunks in scan-line order at the scanner's rate, End), with the agent's reports and findings
//! collected as they come back.

use std::time::{Duration, Instant};

use crate::{
    AsBuilt, Defect, Part, Scan, ScannerModel, Truth, as_built, perturb, scan, stations_around,
};
use anyhow::{Context, Result, bail};
use asbuilt_protocol::ipc::CellPorts;
use asbuilt_protocol::{
    ChunkHeader, FixedText, PoseMode, PoseSnapshot, ScanPoint, StationEvent, StationEventKind,
    StationFindings, StationReport, StationSender, StationSink, codec, unix_time_ns,
};
use nalgebra::{Isometry3, Point3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

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
    /// Points per scan chunk sent.
    pub chunk_points: usize,
    /// Points per second, or `None` for as fast as the agent takes them.
    pub rate: Option<f64>,
    /// Wait for a station's report before the next station begins, as a scanner carried from
    /// station to station does. Off, the cell runs ahead of the agent as far as its queues let it.
    pub one_station_at_a_time: bool,
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
            chunk_points: 16_384,
            rate: Some(1.0e6),
            one_station_at_a_time: true,
        }
    }

    /// Every station of the job, in the order the robot visits them.
    pub fn plan(&self) -> Vec<PlannedStation> {
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
    /// The job and the truth of each scan layer, as `truth.json` holds it for a reviewer.
    pub fn truth_json(&self) -> serde_json::Value {
        let t = |t: &Truth| {
            serde_json::json!({
                "kind": t.kind,
                "magnitude_m": t.magnitude,
                "position_m": [t.position.x, t.position.y, t.position.z],
                "layers": [t.layers.0, t.layers.1],
                "direction": t.direction,
            })
        };
        serde_json::json!({
            "part": self.part.name,
            "layer_height_m": self.part.layer_height,
            "scan_after_layers": self.scan_after,
            "defects": self.defects.iter().map(|d| format!("{d:?}")).collect::<Vec<_>>(),
            "truth": self.truth().iter().map(|(k, tr)| {
                let mut v = t(tr);
                v["after_layers"] = serde_json::json!(k);
                v
            }).collect::<Vec<_>>(),
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

    /// The as-built part after `printed` layers.
    pub fn as_built(&self, printed: u32) -> Result<AsBuilt> {
        Ok(as_built(&self.part, &self.defects, printed)?)
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
    /// The agent reported a station.
    Report(&'a StationReport),
    /// The agent sent a station's findings.
    Findings(&'a StationFindings),
}

/// What a job sent and got back.
#[derive(Debug, Default)]
pub struct SimOutcome {
    /// Points sent over every station.
    pub points_sent: u64,
    /// Seconds the whole job took, up to its last report (or the end of the wait for it).
    pub seconds: f64,
    /// The reports, as they came.
    pub reports: Vec<StationReport>,
    /// The findings, as they came.
    pub findings: Vec<StationFindings>,
}

impl SimOutcome {
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
/// findings, when `expect_findings`).
pub fn run(
    job: &SimJob,
    ports: &CellPorts,
    expect_findings: bool,
    wait: Duration,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<SimOutcome> {
    if job.chunk_points == 0 {
        bail!("chunks need at least one point");
    }
    let plan = job.plan();
    let mut out = SimOutcome::default();
    let started = Instant::now();
    let mut current: Option<(u32, AsBuilt)> = None;
    for st in &plan {
        if current.as_ref().map(|c| c.0) != Some(st.printed) {
            current = Some((st.printed, job.as_built(st.printed)?));
        }
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
        let previous = st
            .index
            .checked_sub(1)
            .filter(|_| job.one_station_at_a_time);
        let deadline = Instant::now() + wait;
        while let Some(p) = previous
            && !out.reports.iter().any(|r| r.station == p)
            && Instant::now() < deadline
        {
            ports.wait_for_output(Duration::from_millis(50))?;
            collect(job.job, ports, &mut out, on)?;
        }
        let t = Instant::now();
        send_station(job, st, &s, ports, &mut out, on)?;
        on(SimEvent::Sent {
            station: st,
            points: s.points.len() as u64,
            seconds: t.elapsed().as_secs_f64(),
        });
    }
    let deadline = Instant::now() + wait;
    let done = |o: &SimOutcome| {
        o.reports.len() >= plan.len() && (!expect_findings || o.findings.len() >= plan.len())
    };
    while !done(&out) && Instant::now() < deadline {
        ports.wait_for_output(Duration::from_millis(100))?;
        collect(job.job, ports, &mut out, on)?;
    }
    out.seconds = started.elapsed().as_secs_f64();
    Ok(out)
}

fn send_station(
    job: &SimJob,
    st: &PlannedStation,
    s: &Scan,
    ports: &CellPorts,
    out: &mut SimOutcome,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<()> {
    let n = s.points.len();
    let mut begin = StationEvent::new(StationEventKind::Begin, job.job, st.index);
    begin.name = FixedText::truncated(&st.name);
    begin.layer = st.printed - 1;
    begin.printed_height = st.printed_height;
    begin.expected_chunks = n.div_ceil(job.chunk_points) as u32;
    begin.expected_points = n as u64;
    let mut pose = PoseSnapshot::new(job.job, st.index, job.pose_mode);
    pose.translation = st.nominal.translation.vector.into();
    let q = st.nominal.rotation.coords;
    pose.rotation_xyzw = [q.x, q.y, q.z, q.w];
    pose.position_sigma = job.position_sigma;
    let mut sink = CellSink {
        ports,
        job: job.job,
        chunk_points: job.chunk_points,
        rate: job.rate,
        started: Instant::now(),
        out,
        on,
    };
    let mut sender = StationSender::start(begin, pose, &mut sink)?;
    for chunk in s.points.chunks(job.chunk_points) {
        sender.chunk(chunk, &mut sink)?;
    }
    sender.finish(&mut sink)?;
    collect(job.job, ports, sink.out, sink.on)
}

/// The cell's ports at the scanner's rate, taking the agent's answers after every chunk.
struct CellSink<'a> {
    ports: &'a CellPorts,
    job: u64,
    chunk_points: usize,
    rate: Option<f64>,
    started: Instant,
    out: &'a mut SimOutcome,
    on: &'a mut dyn FnMut(SimEvent<'_>),
}

impl StationSink for CellSink<'_> {
    type Error = anyhow::Error;
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
        if let Some(rate) = self.rate {
            let sent = (header.sequence + 1) as f64 * self.chunk_points as f64;
            let due = Duration::from_secs_f64(sent / rate);
            if let Some(ahead) = due.checked_sub(self.started.elapsed()) {
                std::thread::sleep(ahead);
            }
        }
        collect(self.job, self.ports, self.out, self.on)
    }
}

/// Takes whatever the agent sent back; deviations are for other subscribers.
fn collect(
    job: u64,
    ports: &CellPorts,
    out: &mut SimOutcome,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<()> {
    let bad = |e: &dyn std::fmt::Debug| anyhow::anyhow!("cannot read the agent's outputs: {e:?}");
    while let Some(r) = ports.reports.receive().map_err(|e| bad(&e))? {
        let r = *r.payload();
        if r.job == job && !out.reports.iter().any(|x| x.station == r.station) {
            on(SimEvent::Report(&r));
            out.reports.push(r);
        }
    }
    while let Some(sample) = ports.findings.receive().map_err(|e| bad(&e))? {
        match codec::decode::<StationFindings>(sample.payload()) {
            Ok(f) if f.job == job && !out.findings.iter().any(|x| x.station == f.station) => {
                on(SimEvent::Findings(&f));
                out.findings.push(f);
            }
            Ok(_) => {}
            Err(e) => eprintln!("warning: findings from the agent cannot be read: {e}"),
        }
    }
    while let Ok(Some(_)) = ports.deviations.receive() {}
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
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("cannot write {}", path.display()))?,
    );
    stl_io::write_stl(&mut f, d.triangles.iter().map(tri))
        .with_context(|| format!("cannot write {}", path.display()))
}
