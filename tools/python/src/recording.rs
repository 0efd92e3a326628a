//! `asbuilt.read_recording`: a recording read back with `asbuilt report`'s own code, each
//! station's inputs (pose, scanner-frame points) and outputs (deviations, report, findings) as
//! arrays and dicts.

use std::path::PathBuf;

use asbuilt_agent::log::{self, Level};
use asbuilt_readback::Judging;
use asbuilt_readback::{Overrides, StationReadBack, read_back};
use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::commands::parsed;
use crate::convert::{self, runtime};

/// `(report, stations)`: report.json's content as `asbuilt report` writes it, and a dict per
/// station (see `asbuilt.Station`).
#[pyfunction]
#[pyo3(signature = (path, tolerance = None, max_distance = None))]
pub fn read_recording_parts<'py>(
    py: Python<'py>,
    path: PathBuf,
    tolerance: Option<f64>,
    max_distance: Option<f64>,
) -> PyResult<(Py<PyAny>, Bound<'py, PyList>)> {
    let overrides = Overrides {
        tolerance,
        max_distance,
        ..Default::default()
    };
    // The agent's lifecycle reads the recording; its progress lines (a few per station) are
    // not the Python caller's business, its warnings are.
    let (report, stations) = py
        .detach(|| {
            let before = log::set_min_level(Level::Warn);
            let read = read_back(&path, overrides);
            log::set_min_level(before);
            read
        })
        .map_err(runtime)?;
    let list = PyList::empty(py);
    for s in &stations {
        list.append(station(py, s)?)?;
    }
    Ok((convert::to_json(py, &report)?, list))
}

fn station<'py>(py: Python<'py>, s: &StationReadBack) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("job", s.job)?;
    d.set_item("station", s.station)?;
    if let Some(b) = &s.begin {
        d.set_item("name", b.name.as_str())?;
        d.set_item("layer", b.layer)?;
        d.set_item("printed_height", b.printed_height)?;
    }
    d.set_item(
        "pose",
        match &s.pose {
            Some(p) => convert::to_json(py, p)?,
            None => py.None(),
        },
    )?;
    let scan: Vec<[f32; 3]> = s.chunks.values().flatten().map(|p| p.xyz).collect();
    let scan_chunk: Vec<u64> = s
        .chunks
        .iter()
        .flat_map(|(k, v)| std::iter::repeat_n(*k, v.len()))
        .collect();
    d.set_item("scan_points", convert::array3(py, &scan))?;
    d.set_item("scan_chunk", scan_chunk.into_pyarray(py))?;
    let devs: Vec<_> = s.deviations.values().flatten().copied().collect();
    let dev_chunk: Vec<u64> = s
        .deviations
        .iter()
        .flat_map(|(k, v)| std::iter::repeat_n(*k, v.len()))
        .collect();
    let dd = convert::deviations_dict(py, &devs)?;
    dd.set_item("chunk", dev_chunk.into_pyarray(py))?;
    d.set_item("deviations", dd)?;
    for (key, value) in [
        ("report", s.report.as_ref().map(|r| convert::to_json(py, r))),
        (
            "findings",
            s.findings.as_ref().map(|f| convert::to_json(py, f)),
        ),
    ] {
        d.set_item(key, value.transpose()?.unwrap_or_else(|| py.None()))?;
    }
    Ok(d)
}

/// `(report, started_ns)`: report.json's content for the job of `paths` (one job's files, in
/// any order), as `asbuilt report` draws it, holding no station's points; and the Unix time in
/// ns of the job's first station event (`None` when it has none). `limits` are `--limit`
/// values (`"width=4mm@1-10"`), `flatness` and `dimensions` the standards and `decision_rule`
/// (`"iso14253-1"` or `"simple"`) as the command line spells them; each overrides the
/// recording's own. `quiet` keeps the lifecycle's warnings
/// back too (what the report itself warns of is in report.json's `warnings`): a fleet's
/// worker logs stay readable.
#[pyfunction]
#[pyo3(signature = (paths, tolerance = None, max_distance = None, limits = None, flatness = None,
                    dimensions = None, decision_rule = None, quiet = false))]
#[allow(clippy::too_many_arguments)] // one keyword per option, as Python calls it
pub fn report_job(
    py: Python<'_>,
    paths: Vec<PathBuf>,
    tolerance: Option<f64>,
    max_distance: Option<f64>,
    limits: Option<Vec<String>>,
    flatness: Option<String>,
    dimensions: Option<String>,
    decision_rule: Option<String>,
    quiet: bool,
) -> PyResult<(Py<PyAny>, Option<u64>)> {
    let overrides = Overrides {
        tolerance,
        max_distance,
        job: None,
        judging: Judging {
            limits: limits
                .unwrap_or_default()
                .iter()
                .map(|l| parsed("limit", l))
                .collect::<PyResult<_>>()?,
            png: false,
            flatness: flatness.map(|f| parsed("flatness", &f)).transpose()?,
            dimensions: dimensions.map(|d| parsed("dimensions", &d)).transpose()?,
            // Else the recording's [tolerances] decision_rule, ISO 14253-1 by default.
            decision_rule: decision_rule
                .map(|r| parsed("decision_rule", &r))
                .transpose()?,
        },
    };
    let (report, started) = py
        .detach(|| {
            let before = log::set_min_level(if quiet { Level::Error } else { Level::Warn });
            let read = asbuilt_readback::report(&paths, overrides);
            log::set_min_level(before);
            read
        })
        .map_err(runtime)?;
    Ok((convert::to_json(py, &report)?, started))
}
