//! `asbuilt` for Python: the native module behind the `asbuilt` package (`python/asbuilt`).
//!
//! Thin, as the command line is: designs and C2M come from `asbuilt-core`, files from
//! `asbuilt-io`, the deviation suite from `asbuilt-report`, recordings and commands from
//! `asbuilt-tools`, the cell's ports from `asbuilt-agent`. Arrays cross as NumPy arrays; the GIL
//! is released while Rust works.

#![warn(missing_docs)]

mod cell;
mod commands;
mod convert;
mod design;
mod recording;
mod suite;

use pyo3::prelude::*;

/// The native module; `asbuilt/__init__.py` re-exports it with Python-side conveniences.
#[pymodule]
fn _asbuilt(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<design::Design>()?;
    m.add_class::<cell::Cell>()?;
    m.add_function(wrap_pyfunction!(commands::run, m)?)?;
    m.add_function(wrap_pyfunction!(commands::inspect, m)?)?;
    m.add_function(wrap_pyfunction!(suite::suite, m)?)?;
    m.add_function(wrap_pyfunction!(recording::read_recording_parts, m)?)?;
    m.add_function(wrap_pyfunction!(recording::report_job, m)?)?;
    m.add_class::<cell::SimulatedJob>()?;
    Ok(())
}
