//! `asbuilt.run` and the commands over it: the command line's own code, in this process.

use std::process::ExitCode;

use std::path::PathBuf;

use asbuilt_tools::inspect::InspectArgs;
use clap::Parser;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::anyhow_err;

/// Runs an `asbuilt` command, `args` as on the command line without the program name
/// (`["inspect", "--design", "part.stl", ...]`). Returns the command's exit code (0 when every
/// station is within its limits, 1 when not); raises ValueError for arguments the command
/// refuses (with its usage) and RuntimeError when the command fails.
#[pyfunction]
pub fn run(py: Python<'_>, args: Vec<String>) -> PyResult<u8> {
    let argv = std::iter::once("asbuilt".to_string()).chain(args);
    let cli = match asbuilt_tools::Cli::try_parse_from(argv) {
        Ok(cli) => cli,
        // --help and --version are answers, not errors.
        Err(e) if !e.use_stderr() => {
            print!("{}", e.render());
            return Ok(0);
        }
        Err(e) => return Err(PyValueError::new_err(e.render().to_string())),
    };
    let code = py.detach(|| asbuilt_tools::run(cli)).map_err(anyhow_err)?;
    Ok(exit_code(code))
}

/// ExitCode keeps its value private; the commands return these.
fn exit_code(code: ExitCode) -> u8 {
    [0u8, 1, 2]
        .into_iter()
        .find(|&c| ExitCode::from(c) == code)
        .unwrap_or(2)
}

/// `asbuilt inspect` in this process, its arguments as typed keywords (the command's flags with
/// `_` for `-`; `method` a list or a comma-separated string, `limit` a list of `--limit` values);
/// one left out takes the command's default. Returns the exit code (1 when out of tolerance);
/// raises ValueError for a value the command refuses, TypeError for a keyword it does not
/// have, RuntimeError when inspecting fails.
#[pyfunction]
#[pyo3(signature = (design, units, *, out, stations = None, scan = None, translation = None,
    rotation_xyzw = None, tolerance = None, limit = None, png = false, flatness = None,
    dimensions = None, max_distance = None, method = None, spacing = None,
    projection_diameter = None, max_depth = None, normal_diameter = None,
    coverage_threshold = None, scanner_step_mrad = None, printed_height = None,
    layer_height = None, reference = None, rerun = None, rerun_url = None, rerun_points = None,
    ascii = false, local_plane = None, no_maps = false, ros2 = None, cloud_topic = None,
    frame = None))]
#[allow(clippy::too_many_arguments)] // one keyword per flag, as Python calls it
pub fn inspect(
    py: Python<'_>,
    design: PathBuf,
    units: &str,
    out: PathBuf,
    stations: Option<PathBuf>,
    scan: Option<PathBuf>,
    translation: Option<Vec<f64>>,
    rotation_xyzw: Option<Vec<f64>>,
    tolerance: Option<f64>,
    limit: Option<Vec<String>>,
    png: bool,
    flatness: Option<&str>,
    dimensions: Option<&str>,
    max_distance: Option<f64>,
    method: Option<Methods>,
    spacing: Option<f64>,
    projection_diameter: Option<f64>,
    max_depth: Option<f64>,
    normal_diameter: Option<f64>,
    coverage_threshold: Option<f64>,
    scanner_step_mrad: Option<f64>,
    printed_height: Option<f64>,
    layer_height: Option<f64>,
    reference: Option<PathBuf>,
    rerun: Option<PathBuf>,
    rerun_url: Option<String>,
    rerun_points: Option<usize>,
    ascii: bool,
    local_plane: Option<usize>,
    no_maps: bool,
    ros2: Option<PathBuf>,
    cloud_topic: Option<String>,
    frame: Option<String>,
) -> PyResult<u8> {
    let mut a = InspectArgs::new(design, parsed("units", units)?);
    a.ros2.ros2 = ros2;
    a.ros2.cloud_topic = cloud_topic;
    a.ros2.frame = frame.unwrap_or(a.ros2.frame);
    a.out = out;
    (a.stations, a.scan, a.translation, a.rotation_xyzw) =
        (stations, scan, translation, rotation_xyzw);
    a.tolerance = tolerance.unwrap_or(a.tolerance);
    a.judging.limits = limit
        .unwrap_or_default()
        .iter()
        .map(|l| parsed("limit", l))
        .collect::<PyResult<_>>()?;
    a.judging.png = png;
    a.judging.flatness = flatness.map(|f| parsed("flatness", f)).transpose()?;
    a.judging.dimensions = dimensions.map(|d| parsed("dimensions", d)).transpose()?;
    a.max_distance = max_distance;
    if let Some(m) = method {
        a.method = asbuilt_report::suite::parse_methods(&m.joined())
            .map_err(|e| PyValueError::new_err(format!("method: {e}")))?;
    }
    a.spacing = spacing.unwrap_or(a.spacing);
    (a.projection_diameter, a.max_depth, a.normal_diameter) =
        (projection_diameter, max_depth, normal_diameter);
    (a.coverage_threshold, a.scanner_step_mrad) = (coverage_threshold, scanner_step_mrad);
    (a.printed_height, a.layer_height, a.reference) = (printed_height, layer_height, reference);
    (a.rerun, a.rerun_url) = (rerun, rerun_url);
    a.rerun_points = rerun_points.unwrap_or(a.rerun_points);
    (a.ascii, a.local_plane, a.no_maps) = (ascii, local_plane, no_maps);
    let code = py
        .detach(|| asbuilt_tools::inspect::run(a))
        .map_err(anyhow_err)?;
    Ok(exit_code(code))
}

/// `method=`: a list of names or one comma-separated string.
#[derive(FromPyObject)]
pub enum Methods {
    /// `"c2m,m3c2"` or `"all"`.
    Text(String),
    /// `["c2m", "m3c2"]`.
    List(Vec<String>),
}

impl Methods {
    fn joined(&self) -> String {
        match self {
            Methods::List(v) => v.join(","),
            Methods::Text(t) => t.to_string(),
        }
    }
}

/// A keyword's text through the type's own parser, as the command line parses its flag.
pub(crate) fn parsed<T: std::str::FromStr>(what: &str, v: &str) -> PyResult<T>
where
    T::Err: std::fmt::Display,
{
    v.parse()
        .map_err(|e| PyValueError::new_err(format!("{what} {v:?}: {e}")))
}
