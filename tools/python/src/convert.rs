//! What crosses between Rust and Python: NumPy arrays in and out, JSON values as Python
//! objects, Rust errors as Python exceptions that keep their whole chain.

use asbuilt_core::Closest;
use asbuilt_core::c2m::triangle::Region;
use asbuilt_protocol::{DeviationFlags, Feature, PointDeviation};
use nalgebra::Point3;
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// An error with every cause, as the command line prints it.
pub fn runtime(e: impl std::error::Error + 'static) -> PyErr {
    PyRuntimeError::new_err(asbuilt_tools::error_message(&e))
}

pub fn anyhow_err(e: anyhow::Error) -> PyErr {
    PyRuntimeError::new_err(asbuilt_tools::error_message(e.as_ref()))
}

/// An (N, 3) array of f64 as points. Any layout is accepted (a copy is made once).
pub fn points(name: &str, a: &PyReadonlyArray2<'_, f64>) -> PyResult<Vec<Point3<f64>>> {
    let v = a.as_array();
    if v.ncols() != 3 {
        return Err(PyValueError::new_err(format!(
            "{name} must be an (N, 3) array of x, y, z in metres, got shape {:?}",
            v.shape()
        )));
    }
    Ok(v.rows()
        .into_iter()
        .map(|r| Point3::new(r[0], r[1], r[2]))
        .collect())
}

/// A JSON text as Python objects (dicts, lists, floats; null as None).
pub fn json(py: Python<'_>, text: &str) -> PyResult<Py<PyAny>> {
    Ok(py.import("json")?.call_method1("loads", (text,))?.unbind())
}

pub fn to_json(py: Python<'_>, value: &impl serde::Serialize) -> PyResult<Py<PyAny>> {
    let text = serde_json::to_string(value).map_err(runtime)?;
    json(py, &text)
}

/// Rows of three as an (N, 3) array.
pub fn array3<T: numpy::Element + Copy>(py: Python<'_>, rows: &[[T; 3]]) -> Py<PyAny> {
    let flat: Vec<T> = rows.iter().flatten().copied().collect();
    Array2::from_shape_vec((rows.len(), 3), flat)
        .expect("three values a row")
        .into_pyarray(py)
        .into_any()
        .unbind()
}

/// The deviation of a design-frame point, as `asbuilt inspect` writes it: the same fields and
/// flags as `core::station` gives a scan point that reached the design frame.
pub fn deviation(p: &Point3<f64>, c: Option<Closest>, tolerance: Option<f64>) -> PointDeviation {
    let mut d = PointDeviation {
        position: [p.x, p.y, p.z],
        distance: f64::NAN,
        triangle: u32::MAX,
        feature: Feature::None as u8,
        feature_index: 0,
        flags: DeviationFlags(0),
        _reserved: 0,
    };
    if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
        d.flags = DeviationFlags(DeviationFlags::REJECTED);
        return d;
    }
    let Some(c) = c else {
        d.flags = DeviationFlags(DeviationFlags::NO_MATCH);
        return d;
    };
    let (feature, index) = match c.region {
        Region::Face => (Feature::Face, 0),
        Region::Edge(i) => (Feature::Edge, i),
        Region::Vertex(i) => (Feature::Vertex, i),
    };
    d.distance = c.distance;
    d.triangle = c.triangle;
    d.feature = feature as u8;
    d.feature_index = index;
    if tolerance.is_some_and(|t| c.distance.abs() > t) {
        d.flags = DeviationFlags(DeviationFlags::OUT_OF_TOLERANCE);
    }
    d
}

/// Deviations as a dict of arrays: `distance` (NaN: no match or rejected), `triangle`
/// (2**32 - 1: none), `feature` (0 none, 1 face, 2 edge, 3 vertex), `feature_index`, `flags`
/// (1 no match, 2 rejected, 4 out of tolerance) and `position` (N, 3), design frame.
pub fn deviations_dict<'py>(
    py: Python<'py>,
    devs: &[PointDeviation],
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let col = |f: &dyn Fn(&PointDeviation) -> f64| devs.iter().map(f).collect::<Vec<_>>();
    d.set_item("distance", col(&|x| x.distance).into_pyarray(py))?;
    d.set_item(
        "triangle",
        devs.iter()
            .map(|x| x.triangle)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    for (name, get) in [
        (
            "feature",
            (|x: &PointDeviation| x.feature) as fn(&PointDeviation) -> u8,
        ),
        ("feature_index", |x| x.feature_index),
        ("flags", |x| x.flags.0),
    ] {
        d.set_item(
            name,
            devs.iter().map(get).collect::<Vec<_>>().into_pyarray(py),
        )?;
    }
    let pos: Vec<[f64; 3]> = devs.iter().map(|x| x.position).collect();
    d.set_item("position", array3(py, &pos))?;
    Ok(d)
}
