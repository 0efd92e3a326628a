//! The cell's side in Python: `asbuilt.Cell` sends stations to a running agent over its
//! iceoryx2 services and takes its reports and findings back, with the same ports and the same
//! station sender as `asbuilt publish` and the simulator (one definition of every message: the
//! protocol crate's). `asbuilt.SimulatedJob` gives a simulated print cell's stations and scans.

use std::sync::Mutex;
use std::time::{Duration, Instant};

use asbuilt_protocol::ipc::{CellPorts, Ipc, IpcError, ServiceNames};
use asbuilt_protocol::{
    FixedText, LayerApplied, LayerCorrection, MountPose, PoseMode, PoseSnapshot, ProfileHeader,
    ProfilePoint, ScanPoint, ScanPointFlags, StationEvent, StationEventKind, StationFindings,
    StationReport, StationSender, codec,
};
use asbuilt_sim::{AsBuilt, JobSpec, LayerSettings, PartSpec, SimJob};
use iceoryx2::prelude::*;
use numpy::{IntoPyArray, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::convert::{self, anyhow_err, runtime};

/// The ports of a running agent (its `services.prefix`), opened as a robot cell opens them.
///
/// `send_station` sends Begin, the pose, the chunks (the last flagged) and End; `receive`
/// returns the agent's reports and findings as they come. Not shared between threads.
#[pyclass(unsendable, module = "asbuilt")]
pub struct Cell {
    ports: CellPorts,
    /// Dropped after the ports: the node owns their shared memory.
    _node: Node<Ipc>,
    max_points_per_chunk: usize,
    /// When this cell was opened (ns since the Unix epoch): the jobs' start unless told.
    opened_ns: u64,
}

fn pose_mode(text: &str) -> PyResult<PoseMode> {
    match text {
        "design_scanner" => Ok(PoseMode::DesignScanner),
        "fixed" => Ok(PoseMode::FixedOrientation),
        "6dof" => Ok(PoseMode::SixDof),
        other => Err(PyValueError::new_err(format!(
            "pose_mode {other:?}: give design_scanner (the pose is T_design_scanner), fixed \
             (flange translation, calibrated orientation) or 6dof (flange pose in the robot base)"
        ))),
    }
}

/// Scan points from arrays: (N, 3) float32 scanner-frame xyz, optional intensity and flags.
fn scan_points(
    points: &PyReadonlyArray2<'_, f32>,
    intensity: Option<&PyReadonlyArray1<'_, f32>>,
    flags: Option<&PyReadonlyArray1<'_, u16>>,
) -> PyResult<Vec<ScanPoint>> {
    let p = points.as_array();
    if p.ncols() != 3 {
        return Err(PyValueError::new_err(format!(
            "points must be an (N, 3) float32 array in the scanner frame, metres; got shape {:?}",
            p.shape()
        )));
    }
    let n = p.nrows();
    let intensity = intensity.map(|a| a.as_array());
    let flags = flags.map(|a| a.as_array());
    for (name, len) in [
        ("intensity", intensity.as_ref().map(|a| a.len())),
        ("flags", flags.as_ref().map(|a| a.len())),
    ] {
        if let Some(len) = len
            && len != n
        {
            return Err(PyValueError::new_err(format!(
                "{name} has {len} entries for {n} points"
            )));
        }
    }
    Ok(p.rows()
        .into_iter()
        .enumerate()
        .map(|(i, r)| {
            let mut s = ScanPoint::new(r[0], r[1], r[2]);
            if let Some(a) = &intensity {
                s.intensity = a[i];
            }
            if let Some(a) = &flags {
                s.flags = ScanPointFlags(a[i]);
            }
            s
        })
        .collect())
}

#[pymethods]
impl Cell {
    /// Opens the services of the agent serving `prefix`, waiting up to `wait` seconds for it.
    #[new]
    #[pyo3(signature = (prefix, *, max_points_per_chunk = 16_384, wait = 10.0))]
    fn new(py: Python<'_>, prefix: &str, max_points_per_chunk: usize, wait: f64) -> PyResult<Self> {
        if !(wait >= 0.0 && wait.is_finite()) {
            return Err(PyValueError::new_err(format!(
                "wait must be seconds >= 0, got {wait}"
            )));
        }
        let names = ServiceNames::new(prefix);
        // iceoryx2's ports are not Send: they are opened on this thread, with the GIL held.
        let _ = py;
        let (node, ports) = asbuilt_protocol::ipc::CellPorts::connect(
            &names,
            max_points_per_chunk,
            Duration::from_secs_f64(wait),
        )
        .map_err(|e| anyhow_err(e.into()))?;
        Ok(Self {
            ports,
            _node: node,
            max_points_per_chunk,
            opened_ns: asbuilt_protocol::unix_time_ns(),
        })
    }

    /// Sends one station: Begin (with its name, layer and printed height), the pose, the points
    /// in chunks of at most `chunk_points`, End. `translation` and `rotation_xyzw` are the pose
    /// the robot reports, in the frame `pose_mode` says. `attempt` numbers a station sent
    /// again (after an interrupted report): 1 the first time. `job_started_ns` is when the
    /// job started (ns since the Unix epoch), which tells this print from another that reuses
    /// the job number; by default when this `Cell` was opened, so a cell process that resumes
    /// a job after a restart passes the first run's. Returns the points sent.
    #[pyo3(signature = (
        station, points, translation, rotation_xyzw, *, job = 1, name = "", layer = 0,
        printed_height = f64::NAN, position_sigma = 0.001, pose_mode = "design_scanner",
        intensity = None, flags = None, chunk_points = None, attempt = 1, job_started_ns = None
    ))]
    #[allow(clippy::too_many_arguments)] // a station's Begin and pose, one keyword each
    fn send_station(
        &self,
        station: u32,
        points: PyReadonlyArray2<'_, f32>,
        translation: [f64; 3],
        rotation_xyzw: [f64; 4],
        job: u64,
        name: &str,
        layer: u32,
        printed_height: f64,
        position_sigma: f64,
        pose_mode: &str,
        intensity: Option<PyReadonlyArray1<'_, f32>>,
        flags: Option<PyReadonlyArray1<'_, u16>>,
        chunk_points: Option<usize>,
        attempt: u8,
        job_started_ns: Option<u64>,
    ) -> PyResult<u64> {
        if attempt == 0 {
            return Err(PyValueError::new_err("attempt counts from 1"));
        }
        let chunk = chunk_points.unwrap_or(self.max_points_per_chunk);
        if chunk == 0 || chunk > self.max_points_per_chunk {
            return Err(PyValueError::new_err(format!(
                "chunk_points must be 1 to {} (the cell's max_points_per_chunk), got {chunk}",
                self.max_points_per_chunk
            )));
        }
        let pts = scan_points(&points, intensity.as_ref(), flags.as_ref())?;
        let mut begin = StationEvent::new(StationEventKind::Begin, job, station);
        begin.job_started_ns = job_started_ns.unwrap_or(self.opened_ns);
        begin.name = FixedText::truncated(name);
        begin.layer = layer;
        begin.printed_height = printed_height;
        begin.expected_chunks = pts.len().div_ceil(chunk) as u32;
        begin.expected_points = pts.len() as u64;
        begin.attempt = attempt;
        let mut pose = PoseSnapshot::new(job, station, self::pose_mode(pose_mode)?);
        pose.translation = translation;
        pose.rotation_xyzw = rotation_xyzw;
        pose.position_sigma = position_sigma;
        // iceoryx2 ports are not Send: the sending stays on this thread, with the GIL held.
        let mut sink = &self.ports;
        let mut sender = StationSender::start(begin, pose, &mut sink).map_err(runtime)?;
        for c in pts.chunks(chunk) {
            sender.chunk(c, &mut sink).map_err(runtime)?;
        }
        let end = sender.finish(&mut sink).map_err(runtime)?;
        Ok(end.expected_points)
    }

    /// Opens (`end=False`) or closes (`end=True`) a line profiler's pass, numbered `pass_`
    /// (a station: its layer and printed height on the Begin; on the End the profile chunks
    /// and points it sent). Its mount poses and profiles go with `send_mount_pose` and
    /// `send_profiles` in between.
    #[pyo3(signature = (
        pass_, *, end = false, job = 1, name = "", layer = 0, printed_height = f64::NAN,
        chunks = 0, points = 0, attempt = 1, job_started_ns = None
    ))]
    #[allow(clippy::too_many_arguments)] // a pass's Begin or End, one keyword each
    fn send_pass(
        &self,
        pass_: u32,
        end: bool,
        job: u64,
        name: &str,
        layer: u32,
        printed_height: f64,
        chunks: u32,
        points: u64,
        attempt: u8,
        job_started_ns: Option<u64>,
    ) -> PyResult<()> {
        let kind = if end {
            StationEventKind::End
        } else {
            StationEventKind::Begin
        };
        let mut ev = StationEvent::new(kind, job, pass_);
        ev.job_started_ns = job_started_ns.unwrap_or(self.opened_ns);
        ev.name = FixedText::truncated(name);
        ev.layer = layer;
        ev.printed_height = printed_height;
        ev.expected_chunks = chunks;
        ev.expected_points = points;
        ev.attempt = attempt.max(1);
        ev.timestamp_ns = asbuilt_protocol::unix_time_ns();
        self.ports.send_event(&ev).map_err(runtime)
    }

    /// Sends a robot pose of the profiler's mount sampled at `time_ns` on the robot's clock:
    /// `T_base_mount` and the calibrated `T_mount_sensor`, metres and unit quaternions (scalar
    /// last).
    #[pyo3(signature = (
        time_ns, translation, rotation_xyzw, *, job = 1, pass_ = 0, sequence = 0,
        mount_sensor_translation = [0.0; 3], mount_sensor_rotation_xyzw = [0.0, 0.0, 0.0, 1.0]
    ))]
    #[allow(clippy::too_many_arguments)] // a pose and its calibration, one keyword each
    fn send_mount_pose(
        &self,
        time_ns: u64,
        translation: [f64; 3],
        rotation_xyzw: [f64; 4],
        job: u64,
        pass_: u32,
        sequence: u64,
        mount_sensor_translation: [f64; 3],
        mount_sensor_rotation_xyzw: [f64; 4],
    ) -> PyResult<()> {
        let mut m = MountPose::new(job, pass_, sequence, time_ns);
        m.translation = translation;
        m.rotation_xyzw = rotation_xyzw;
        m.mount_sensor_translation = mount_sensor_translation;
        m.mount_sensor_rotation_xyzw = mount_sensor_rotation_xyzw;
        self.ports.send_mount_pose(&m).map_err(runtime)
    }

    /// Sends chunk `sequence` of a pass: profiles taken at `sensor_ns` (the profiler's clock),
    /// `counts[i]` points each, their points one after the other in `points` (N × 2: along the
    /// line, along the view; metres, sensor frame). At most 32 profiles a chunk.
    #[pyo3(signature = (pass_, sequence, sensor_ns, counts, points, *, job = 1, last = false, attempt = 1))]
    #[allow(clippy::too_many_arguments)] // a chunk's header, one keyword each
    fn send_profiles(
        &self,
        pass_: u32,
        sequence: u64,
        sensor_ns: Vec<u64>,
        counts: Vec<u32>,
        points: PyReadonlyArray2<'_, f32>,
        job: u64,
        last: bool,
        attempt: u16,
    ) -> PyResult<()> {
        let mut h = ProfileHeader::new(job, pass_, sequence);
        h.attempt = attempt.max(1);
        h.last = u8::from(last);
        h.timestamp_ns = asbuilt_protocol::unix_time_ns();
        if sensor_ns.len() != counts.len() {
            return Err(PyValueError::new_err(
                "sensor_ns and counts need one entry a profile",
            ));
        }
        for (&t, &n) in sensor_ns.iter().zip(&counts) {
            if !h.push(t, n) {
                return Err(PyValueError::new_err(format!(
                    "{} profiles: a chunk holds at most {}",
                    counts.len(),
                    asbuilt_protocol::MAX_PROFILES_PER_CHUNK
                )));
            }
        }
        let a = points.as_array();
        if a.ncols() != 2 {
            return Err(PyValueError::new_err("points must be N × 2 (x, z)"));
        }
        let pts: Vec<ProfilePoint> = a
            .rows()
            .into_iter()
            .map(|r| ProfilePoint { x: r[0], z: r[1] })
            .collect();
        if let Err(e) = h.profiles(pts.len()) {
            return Err(PyValueError::new_err(e.to_string()));
        }
        self.ports.send_profiles(&h, &pts).map_err(runtime)
    }

    /// Tells the agent what the printer applied to `layer` once it is printed: the z offset
    /// (metres), the flow factor and the path offset (metres, x and y), and the layer of the
    /// advice it followed (`None`: printed without advice). The agent's next advice builds on
    /// what was applied, not on what it advised.
    #[pyo3(signature = (
        layer, *, job = 1, z_offset = 0.0, flow = 1.0, path_offset = (0.0, 0.0),
        advice_layer = None
    ))]
    fn send_applied(
        &self,
        layer: u32,
        job: u64,
        z_offset: f64,
        flow: f64,
        path_offset: (f64, f64),
        advice_layer: Option<u32>,
    ) -> PyResult<()> {
        let mut a = LayerApplied::nominal(job, layer);
        a.z_offset = z_offset;
        a.flow = flow;
        a.path_offset = [path_offset.0, path_offset.1];
        a.advice_layer = advice_layer.unwrap_or(u32::MAX);
        a.timestamp_ns = asbuilt_protocol::unix_time_ns();
        if !a.is_valid() {
            return Err(PyValueError::new_err(format!(
                "z_offset, flow and path_offset must be finite and flow above 0, got {z_offset}, \
                 {flow}, {path_offset:?}"
            )));
        }
        self.ports.send_applied(&a).map_err(runtime)
    }

    /// The agent's reports and findings that arrived, as dicts with `kind` "report" or
    /// "findings"; waits up to `timeout` seconds for the first when none is there.
    #[pyo3(signature = (timeout = 0.0))]
    fn receive<'py>(&self, py: Python<'py>, timeout: f64) -> PyResult<Bound<'py, PyList>> {
        let out = PyList::empty(py);
        let deadline = Instant::now() + Duration::from_secs_f64(timeout.max(0.0));
        loop {
            self.drain(py, &out)?;
            let now = Instant::now();
            if !out.is_empty() || now >= deadline {
                return Ok(out);
            }
            let wait = (deadline - now).min(Duration::from_millis(100));
            self.ports.wait_for_output(wait).map_err(runtime)?;
            py.check_signals()?;
        }
    }

    fn __repr__(&self) -> String {
        "Cell(connected)".into()
    }
}

impl Cell {
    fn drain(&self, py: Python<'_>, out: &Bound<'_, PyList>) -> PyResult<()> {
        let bad = |e: iceoryx2::port::ReceiveError| {
            runtime(IpcError::iceoryx("cannot read the agent's outputs", e))
        };
        while let Some(r) = self.ports.reports.receive().map_err(bad)? {
            let r: StationReport = *r.payload();
            out.append(tagged(py, "report", &r)?)?;
        }
        while let Some(s) = self.ports.findings.receive().map_err(bad)? {
            let f: StationFindings = codec::decode(s.payload()).map_err(runtime)?;
            out.append(tagged(py, "findings", &f)?)?;
        }
        while let Some(s) = self.ports.surface.receive().map_err(bad)? {
            let s: asbuilt_protocol::SurfaceFindings =
                codec::decode(s.payload()).map_err(runtime)?;
            out.append(tagged(py, "surface", &s)?)?;
        }
        while let Some(c) = self.ports.corrections.receive().map_err(bad)? {
            let c: LayerCorrection = *c.payload();
            out.append(tagged(py, "correction", &c)?)?;
        }
        // Deviations are for viewers; a cell that does not read them must not fill the queue.
        while let Ok(Some(_)) = self.ports.deviations.receive() {}
        Ok(())
    }
}

/// An agent's correction, as `Cell.receive` gives it, back into the message.
fn advice_from(d: &Bound<'_, PyDict>) -> PyResult<LayerCorrection> {
    let get = |key: &str| {
        d.get_item(key)?
            .ok_or_else(|| PyValueError::new_err(format!("correction: no {key:?}")))
    };
    let mut c = LayerCorrection::neutral(
        get("job")?.extract()?,
        get("station")?.extract()?,
        1,
        get("layer")?.extract()?,
    );
    c.from_layer = get("from_layer")?.extract()?;
    c.first_layers = get("first_layers")?.extract()?;
    c.z_first = get("z_first")?.extract()?;
    c.z_then = get("z_then")?.extract()?;
    c.flow = get("flow")?.extract()?;
    c.path_offset = get("path_offset")?.extract()?;
    if !(c.flow > 0.0 && c.flow.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "correction: flow {} is not a factor above 0",
            c.flow
        )));
    }
    Ok(c)
}

fn tagged<'py>(
    py: Python<'py>,
    kind: &str,
    value: &impl serde::Serialize,
) -> PyResult<Bound<'py, PyAny>> {
    let v = convert::to_json(py, value)?.into_bound(py);
    v.set_item("kind", kind)?;
    Ok(v)
}

/// A simulated print job, as `asbuilt sim` runs it: the part, its defects, where the robot
/// scans and what the scanner sees. Keywords are `asbuilt sim`'s job flags, typed
/// (`SimulatedJob(part="wall", scan_after=[8, 16], defect=["bulge:..."])`); a keyword left out
/// takes `asbuilt sim`'s default.
#[pyclass(frozen, subclass, module = "asbuilt")]
pub struct SimulatedJob {
    job: SimJob,
    /// What the printer applied to each layer printed so far ([`SimulatedJob::print_to`]).
    settings: Mutex<Vec<LayerSettings>>,
    /// The as-built part of the last layer count scanned, with the settings it was built with.
    built: Mutex<Option<(u32, usize, std::sync::Arc<AsBuilt>)>>,
}

/// `part`: `wall`, `column` or a design file (with `units` and `layer_height`).
fn part_spec(
    part: std::path::PathBuf,
    units: Option<&str>,
    layer_height: Option<f64>,
) -> PyResult<PartSpec> {
    Ok(match part.to_str() {
        Some("wall") => PartSpec::Wall,
        Some("column") => PartSpec::Column,
        _ => PartSpec::File {
            path: part,
            units: units
                .ok_or_else(|| {
                    PyValueError::new_err(
                        "units='m' or 'mm' is required with a design file: units are never guessed",
                    )
                })?
                .parse()
                .map_err(|e| PyValueError::new_err(format!("units: {e}")))?,
            layer_height: layer_height.ok_or_else(|| {
                PyValueError::new_err("layer_height (metres) is required with a design file")
            })?,
        },
    })
}

/// `rate`: points per second, or `"max"` for as fast as the agent takes them.
fn rate(value: &Bound<'_, PyAny>) -> PyResult<Option<f64>> {
    if let Ok(text) = value.extract::<String>() {
        return match text.as_str() {
            "max" => Ok(None),
            _ => Err(PyValueError::new_err(format!(
                "rate {text:?}: give points per second or \"max\""
            ))),
        };
    }
    Ok(Some(value.extract::<f64>()?))
}

#[pymethods]
impl SimulatedJob {
    #[new]
    #[pyo3(signature = (
        *, part = None, units = None, layer_height = None, scan_after = None, stations = None,
        defect = None, seed = None, pose_mode = "fixed", pose_sigma = None, rate = None,
        step_deg = None, job = None, sensor = "tls", profile_points = None, layers = None,
        clock_offset_ns = 0
    ))]
    #[allow(clippy::too_many_arguments)] // Python's keywords, one per `asbuilt sim` flag
    fn new(
        part: Option<std::path::PathBuf>,
        units: Option<&str>,
        layer_height: Option<f64>,
        scan_after: Option<Vec<u32>>,
        stations: Option<u32>,
        defect: Option<Vec<String>>,
        seed: Option<u64>,
        pose_mode: &str,
        pose_sigma: Option<f64>,
        rate: Option<Bound<'_, PyAny>>,
        step_deg: Option<f64>,
        job: Option<u64>,
        sensor: &str,
        profile_points: Option<usize>,
        layers: Option<u32>,
        clock_offset_ns: i64,
    ) -> PyResult<Self> {
        let d = JobSpec::default();
        let profiler = match sensor {
            "tls" => None,
            "profiler" => {
                let d = asbuilt_sim::ProfilerSpec::default();
                Some(asbuilt_sim::ProfilerSpec {
                    points: profile_points.unwrap_or(d.points),
                    layers,
                    clock_offset_ns,
                    ..d
                })
            }
            other => {
                return Err(PyValueError::new_err(format!(
                    "sensor {other:?}: give \"tls\" or \"profiler\""
                )));
            }
        };
        let spec = JobSpec {
            part: part_spec(part.unwrap_or_else(|| "wall".into()), units, layer_height)?,
            scan_after: scan_after.unwrap_or(d.scan_after),
            stations: stations.unwrap_or(d.stations),
            defects: defect.unwrap_or(d.defects),
            seed: seed.unwrap_or(d.seed),
            pose_mode: match self::pose_mode(pose_mode)? {
                PoseMode::DesignScanner => {
                    return Err(PyValueError::new_err(
                        "pose_mode: a simulated job's robot reports fixed or 6dof poses",
                    ));
                }
                m => m,
            },
            pose_sigma: pose_sigma.unwrap_or(d.pose_sigma),
            rate: match rate {
                Some(r) => self::rate(&r)?,
                // A profiler sends as fast as the agent takes, unless told a rate.
                None if profiler.is_some() => None,
                None => d.rate,
            },
            step_deg: step_deg.unwrap_or(d.step_deg),
            job: job.unwrap_or(d.job),
            attempts: d.attempts,
            closed_loop: d.closed_loop,
            apply: d.apply,
            profiler,
        };
        Ok(Self {
            job: spec
                .build()
                .map_err(|e| PyValueError::new_err(asbuilt_tools::error_message(&e)))?,
            settings: Mutex::new(Vec::new()),
            built: Mutex::new(None),
        })
    }

    /// The width a layer comes out at nominal flow, metres: what the agent's
    /// `[corrections] bead_width` should say for this part.
    #[getter]
    fn bead_width(&self) -> PyResult<f64> {
        self.job
            .part
            .bead_width()
            .map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// Prints the layers up to `layers` (a count) not printed yet with `correction` (an
    /// agent's `"correction"` message from `Cell.receive`; `None`: as designed), as the
    /// printer's controller applies the latest advice from the next layer it prints. Later
    /// scans see them as printed. Returns the layers printed.
    #[pyo3(signature = (layers, correction = None))]
    fn print_to(&self, layers: u32, correction: Option<&Bound<'_, PyDict>>) -> PyResult<u32> {
        let advice = correction.map(advice_from).transpose()?;
        let mut settings = self.settings.lock().unwrap_or_else(|e| e.into_inner());
        let from = settings.len() as u32;
        let to = layers.min(self.job.part.layers());
        settings.extend((from..to).map(|j| {
            advice
                .as_ref()
                .map_or(LayerSettings::NOMINAL, |c| LayerSettings::advised(c, j))
        }));
        Ok(to.saturating_sub(from))
    }

    /// What layer `layer` was printed with, as the printer tells the agent
    /// (`Cell.send_applied(layer, **job.applied(layer))`): `z_offset`, `flow` and
    /// `path_offset`. A layer not printed yet is an error.
    fn applied<'py>(&self, py: Python<'py>, layer: u32) -> PyResult<Bound<'py, PyDict>> {
        let settings = self.settings.lock().unwrap_or_else(|e| e.into_inner());
        let s = settings.get(layer as usize).ok_or_else(|| {
            PyValueError::new_err(format!(
                "layer {layer} is not printed yet ({} layers printed)",
                settings.len()
            ))
        })?;
        let d = PyDict::new(py);
        d.set_item("z_offset", s.z_offset)?;
        d.set_item("flow", s.flow)?;
        d.set_item("path_offset", (s.path_offset[0], s.path_offset[1]))?;
        Ok(d)
    }

    /// The design being printed.
    #[getter]
    fn design(&self) -> crate::design::Design {
        crate::design::Design::new(self.job.part.design.clone(), self.job.part.name.clone())
    }

    #[getter]
    fn layer_height(&self) -> f64 {
        self.job.part.layer_height
    }

    #[getter]
    fn layers(&self) -> u32 {
        self.job.part.layers()
    }

    #[getter]
    fn job(&self) -> u64 {
        self.job.job
    }

    /// Runs the whole job through `cell` as `asbuilt sim` does (a profiler's job: every
    /// layer a pass, its poses and profiles interleaved), waiting up to `wait` seconds for
    /// the last reports (and findings, with `findings=True`). Returns the reports and
    /// findings as `Cell.receive` gives them, `points_sent` and `seconds`.
    #[pyo3(signature = (cell, *, findings = false, wait = 60.0))]
    fn run<'py>(
        &self,
        py: Python<'py>,
        cell: PyRef<'_, Cell>,
        findings: bool,
        wait: f64,
    ) -> PyResult<Bound<'py, PyDict>> {
        let wait = Duration::from_secs_f64(wait.max(0.0));
        let o = asbuilt_sim::run(&self.job, &cell.ports, findings, wait, &mut |_| {})
            .map_err(runtime)?;
        let out = PyDict::new(py);
        let reports = PyList::empty(py);
        for r in &o.reports {
            reports.append(tagged(py, "report", r)?)?;
        }
        let found = PyList::empty(py);
        for f in &o.findings {
            found.append(tagged(py, "findings", f)?)?;
        }
        out.set_item("reports", reports)?;
        out.set_item("findings", found)?;
        out.set_item("points_sent", o.points_sent)?;
        out.set_item("seconds", o.seconds)?;
        Ok(out)
    }

    /// Every station in the order the robot visits them: `index`, `name`, `printed` (layers
    /// printed), `printed_height`, and the pose the robot reports (`translation`,
    /// `rotation_xyzw`, `pose_mode`, `position_sigma`).
    fn stations<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let out = PyList::empty(py);
        for st in self.job.plan() {
            let d = PyDict::new(py);
            d.set_item("index", st.index)?;
            d.set_item("name", &st.name)?;
            d.set_item("printed", st.printed)?;
            d.set_item("printed_height", st.printed_height)?;
            let t: [f64; 3] = st.nominal.translation.vector.into();
            let q = st.nominal.rotation.coords;
            d.set_item("translation", t)?;
            d.set_item("rotation_xyzw", [q.x, q.y, q.z, q.w])?;
            d.set_item(
                "pose_mode",
                match self.job.pose_mode {
                    PoseMode::SixDof => "6dof",
                    PoseMode::FixedOrientation => "fixed",
                    PoseMode::DesignScanner => "design_scanner",
                },
            )?;
            d.set_item("position_sigma", self.job.position_sigma)?;
            out.append(d)?;
        }
        Ok(out)
    }

    /// Scans station `index` of the plan: the as-built part after its layers, seen from where
    /// the scanner really was. Returns `points` ((N, 3) float32, scanner frame), `intensity`
    /// and `flags`, in scan-line order, the same points `asbuilt sim` sends.
    fn scan<'py>(&self, py: Python<'py>, index: u32) -> PyResult<Bound<'py, PyDict>> {
        let plan = self.job.plan();
        let st = plan
            .iter()
            .find(|s| s.index == index)
            .ok_or_else(|| {
                PyValueError::new_err(format!("no station {index}: the plan has {}", plan.len()))
            })?
            .clone();
        let settings = self
            .settings
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        // The layers scanned were printed with the settings of as many of them as are set.
        let set = settings.len().min(st.printed as usize);
        let part = {
            let mut slot = self.built.lock().unwrap_or_else(|e| e.into_inner());
            match &*slot {
                Some((k, n, b)) if *k == st.printed && *n == set => b.clone(),
                _ => {
                    let b = py
                        .detach(|| self.job.as_built_with(st.printed, &settings))
                        .map_err(runtime)?;
                    let b = std::sync::Arc::new(b);
                    *slot = Some((st.printed, set, b.clone()));
                    b
                }
            }
        };
        let scan = py.detach(|| self.job.scan(&st, &part));
        let d = PyDict::new(py);
        let xyz: Vec<[f32; 3]> = scan.points.iter().map(|p| p.xyz).collect();
        d.set_item("points", convert::array3(py, &xyz))?;
        let i: Vec<f32> = scan.points.iter().map(|p| p.intensity).collect();
        d.set_item("intensity", i.into_pyarray(py))?;
        let f: Vec<u16> = scan.points.iter().map(|p| p.flags.0).collect();
        d.set_item("flags", f.into_pyarray(py))?;
        Ok(d)
    }
}
