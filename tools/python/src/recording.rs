//! `asbuilt.read_recording`: a recording read back with `asbuilt report`'s own code, each
//! station's inputs (pose, scanner-frame points) and outputs (deviations, report, findings) as
//! arrays and dicts.

use std::path::PathBuf;

use asbuilt_agent::log::{self, Level};
use asbuilt_tools::read_back::{Overrides, StationReadBack, read_back};
use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::convert::{self, anyhow_err};

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
        .map_err(anyhow_err)?;
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
