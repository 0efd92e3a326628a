//! `asbuilt.suite`: the deviation suite of `asbuilt inspect --method ...` over arrays: C2C,
//! coverage (missing material), design-referenced M3C2 and the findings a crew acts on, with
//! the command's parameters and defaults (`asbuilt_report::suite::SuiteOptions`).

use std::path::PathBuf;

use asbuilt_core::coverage::SampleClass;
use asbuilt_core::scan_layer::{SampleState, defaults};
use asbuilt_report::suite::{Suite, SuiteOptions, findings_message, parse_methods};
use asbuilt_report::{SuiteSection, SuiteTotals};
use nalgebra::Point3;
use numpy::{IntoPyArray, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::convert::{self, anyhow_err, runtime};
use crate::design::{Design, deviations};

/// One station's points (design frame) and where it was scanned from.
struct StationInput {
    points: Vec<Point3<f64>>,
    origin: Point3<f64>,
    sigma: f64,
}

fn station_input(item: &Bound<'_, PyAny>, n: usize) -> PyResult<StationInput> {
    let bad = || {
        PyValueError::new_err(format!(
            "station {n}: give a dict with 'points' ((N, 3) design frame, metres), 'origin' \
             (the scanner's position) and optionally 'sigma' (its position σ, metres)"
        ))
    };
    let get = |key: &str| -> PyResult<Option<Bound<'_, PyAny>>> {
        item.get_item(key).map(Some).or_else(|e| {
            if e.is_instance_of::<pyo3::exceptions::PyKeyError>(item.py()) {
                Ok(None)
            } else {
                Err(e)
            }
        })
    };
    let points: PyReadonlyArray2<'_, f64> = get("points")?.ok_or_else(bad)?.extract()?;
    let origin: [f64; 3] = get("origin")?.ok_or_else(bad)?.extract()?;
    let sigma: f64 = match get("sigma")? {
        Some(s) => s.extract()?,
        None => 0.001,
    };
    Ok(StationInput {
        points: convert::points(&format!("station {n}'s points"), &points)?,
        origin: origin.into(),
        sigma,
    })
}

/// Runs the suite over `stations` (a list of dicts: `points`, `origin`, `sigma`) against
/// `design`. Keywords are `asbuilt inspect`'s flags with the same defaults. Returns a dict:
/// `stations` (each station's sections), `total` (the job's, with `layers` per band when
/// `layer_height` is given), `findings` (with coverage and M3C2: layer rows, regions out of
/// tolerance, missing areas) and `samples` (every design sample's position, normal, M3C2
/// distance, significance and coverage class, as arrays).
#[pyfunction]
#[pyo3(signature = (
    design, stations, *, methods = vec!["coverage".to_string(), "m3c2".to_string()],
    tolerance = 0.005, max_distance = None, spacing = defaults::SPACING,
    projection_diameter = None, max_depth = None, normal_diameter = None,
    coverage_threshold = None, scanner_step_mrad = None, layer_height = None,
    printed_height = None, reference = None, local_plane = None, out = None
))]
#[allow(clippy::too_many_arguments)] // the command's flags, one keyword each
pub fn suite<'py>(
    py: Python<'py>,
    design: &Design,
    stations: &Bound<'py, PyList>,
    methods: Vec<String>,
    tolerance: f64,
    max_distance: Option<f64>,
    spacing: f64,
    projection_diameter: Option<f64>,
    max_depth: Option<f64>,
    normal_diameter: Option<f64>,
    coverage_threshold: Option<f64>,
    scanner_step_mrad: Option<f64>,
    layer_height: Option<f64>,
    printed_height: Option<f64>,
    reference: Option<PathBuf>,
    local_plane: Option<usize>,
    out: Option<PathBuf>,
) -> PyResult<Bound<'py, PyDict>> {
    let config = SuiteOptions {
        methods: parse_methods(&methods.join(","))
            .map_err(|e| PyValueError::new_err(e.to_string()))?
            .0,
        tolerance,
        max_distance,
        spacing,
        projection_diameter,
        max_depth,
        normal_diameter,
        coverage_threshold,
        scanner_step_mrad,
        layer_height,
        printed_height,
        reference,
        local_plane,
    }
    .resolve()
    .map_err(|e| PyValueError::new_err(format!("{e:#}")))?;
    let inputs: Vec<StationInput> = stations
        .iter()
        .enumerate()
        .map(|(n, s)| station_input(&s, n))
        .collect::<PyResult<_>>()?;
    // As `inspect --printed-height`: the design as printed, cut and capped.
    let cut;
    let compared = match printed_height {
        Some(h) => {
            cut = design.cut(py, h)?;
            &cut
        }
        None => design,
    };
    let index = compared.index(py, config.reach)?;
    let scratch = match &out {
        Some(_) => None,
        None => Some(tempfile::tempdir().map_err(runtime)?),
    };
    let out_dir = out
        .clone()
        .unwrap_or_else(|| scratch.as_ref().expect("made above").path().to_path_buf());
    let whole = compared.design.clone();
    let lowest = whole.bounds().0.z;
    let (sections, totals) = py
        .detach(|| -> anyhow::Result<_> {
            std::fs::create_dir_all(&out_dir)?;
            let mut suite = Suite::new(&whole, config.clone())?;
            let mut sections = Vec::new();
            for s in &inputs {
                suite.begin_station();
                for batch in s.points.chunks(1 << 16) {
                    suite.chunk(&deviations(&index, batch, Some(tolerance)));
                }
                sections.push(suite.end_station(s.origin, s.sigma, &index));
            }
            Ok((sections, suite.finish(&index, &out_dir)?))
        })
        .map_err(anyhow_err)?;
    suite_result(
        py,
        (&sections, &totals),
        tolerance,
        (printed_height, layer_height),
        lowest,
    )
}

/// What `suite` returns: each station's section, the totals, the findings judged as an agent
/// with this tolerance and no other limits judges them, and the design samples.
fn suite_result<'py>(
    py: Python<'py>,
    (sections, totals): (&[SuiteSection], &SuiteTotals),
    tolerance: f64,
    heights: (Option<f64>, Option<f64>),
    lowest: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let result = PyDict::new(py);
    let list = PyList::empty(py);
    for s in sections {
        list.append(convert::to_json(py, s)?)?;
    }
    result.set_item("stations", list)?;
    result.set_item("total", convert::to_json(py, &totals)?)?;
    let findings = match &totals.findings {
        Some((f, n)) => {
            // Judged as an agent with this tolerance and no other limits judges them.
            let limits = asbuilt_core::verdict::Limits::from_tolerance(tolerance);
            let m = findings_message(f, *n, (tolerance, &limits), heights, lowest);
            convert::to_json(py, &m)?
        }
        None => py.None(),
    };
    result.set_item("findings", findings)?;
    result.set_item("samples", samples(py, &totals.samples)?)?;
    Ok(result)
}

/// The design samples' states as arrays; `class` is 0 observed, 1 missing, 2 occluded, 3 not
/// scanned.
fn samples<'py>(py: Python<'py>, s: &[SampleState]) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let pos: Vec<[f64; 3]> = s.iter().map(|x| x.position.into()).collect();
    let nrm: Vec<[f64; 3]> = s.iter().map(|x| x.normal.into()).collect();
    d.set_item("position", convert::array3(py, &pos))?;
    d.set_item("normal", convert::array3(py, &nrm))?;
    let m3c2: Vec<f64> = s.iter().map(|x| x.m3c2.unwrap_or(f64::NAN)).collect();
    d.set_item("m3c2", m3c2.into_pyarray(py))?;
    let sig: Vec<bool> = s.iter().map(|x| x.significant).collect();
    d.set_item("significant", sig.into_pyarray(py))?;
    let class: Vec<u8> = s
        .iter()
        .map(|x| match x.class {
            SampleClass::Observed => 0,
            SampleClass::Missing => 1,
            SampleClass::Occluded => 2,
            SampleClass::NotScanned => 3,
        })
        .collect();
    d.set_item("class", class.into_pyarray(py))?;
    Ok(d)
}
