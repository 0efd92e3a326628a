//! `asbuilt.Design`: a design model in metres, its cut at a printed height, and signed
//! cloud-to-mesh distances from the same index `asbuilt inspect` builds.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use asbuilt_core::{C2mIndex, C2mParams, Closest, Units};
use asbuilt_protocol::PointDeviation;
use nalgebra::Point3;
use numpy::{PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{self, runtime};

/// Points queried at once: bounds the memory of a query to about 100 MB whatever the array's
/// size. Results do not depend on it (each point's answer is its own).
const BATCH: usize = 1 << 20;

/// A triangle mesh in metres, as asbuilt compares scans with it.
///
/// Load one with `Design.load(path, units="m")` (STL, OBJ or PLY; the units are declared, never
/// guessed) or make one with `Design.from_arrays(vertices, triangles, units="m")`.
#[pyclass(frozen, module = "asbuilt")]
pub struct Design {
    pub(crate) design: Arc<asbuilt_core::Design>,
    /// Where the design came from, for messages and reports.
    #[pyo3(get)]
    source: String,
    /// The last index built, by its maximum distance: repeated queries do not build again.
    index: Mutex<Option<(u64, Arc<C2mIndex>)>>,
}

impl Design {
    pub(crate) fn new(design: asbuilt_core::Design, source: String) -> Self {
        Self {
            design: Arc::new(design),
            source,
            index: Mutex::new(None),
        }
    }

    /// The index at `max_distance`, built once per distance (off the GIL).
    pub(crate) fn index(&self, py: Python<'_>, max_distance: f64) -> PyResult<Arc<C2mIndex>> {
        if !(max_distance > 0.0 && max_distance.is_finite()) {
            return Err(PyValueError::new_err(format!(
                "max_distance must be a positive number of metres, got {max_distance}"
            )));
        }
        let mut slot = self.index.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((bits, ix)) = &*slot
            && *bits == max_distance.to_bits()
        {
            return Ok(ix.clone());
        }
        let design = self.design.clone();
        let params = C2mParams::within(max_distance);
        let ix = py
            .detach(|| C2mIndex::build(&design, params))
            .map_err(runtime)?;
        let ix = Arc::new(ix);
        *slot = Some((max_distance.to_bits(), ix.clone()));
        Ok(ix)
    }
}

fn units(text: &str) -> PyResult<Units> {
    text.parse::<Units>().map_err(PyValueError::new_err)
}

/// The deviations of design-frame points against `index`, batch by batch.
pub(crate) fn deviations(
    index: &C2mIndex,
    points: &[Point3<f64>],
    tolerance: Option<f64>,
) -> Vec<PointDeviation> {
    let mut out = Vec::with_capacity(points.len());
    let mut found: Vec<Option<Closest>> = Vec::new();
    for batch in points.chunks(BATCH) {
        found.clear();
        found.resize(batch.len(), None);
        index.query_batch(batch, &mut found);
        out.extend(
            batch
                .iter()
                .zip(&found)
                .map(|(p, c)| convert::deviation(p, *c, tolerance)),
        );
    }
    out
}

#[pymethods]
impl Design {
    /// Reads an STL (binary or ASCII), OBJ or PLY mesh written in `units` ("m" or "mm").
    #[staticmethod]
    #[pyo3(signature = (path, units))]
    fn load(py: Python<'_>, path: PathBuf, units: &str) -> PyResult<Self> {
        let u = self::units(units)?;
        let d = py
            .detach(|| asbuilt_io::read_design(&path, u))
            .map_err(runtime)?;
        Ok(Self::new(d, path.display().to_string()))
    }

    /// A design from an (N, 3) float array of vertices and an (M, 3) integer array of triangles
    /// (counter-clockwise seen from outside), in `units`. Vertices at the same position are
    /// merged and degenerate triangles dropped, as when a file is read.
    #[staticmethod]
    #[pyo3(signature = (vertices, triangles, units = "m"))]
    fn from_arrays(
        vertices: PyReadonlyArray2<'_, f64>,
        triangles: PyReadonlyArray2<'_, i64>,
        units: &str,
    ) -> PyResult<Self> {
        let scale = self::units(units)?.scale();
        let v = convert::points("vertices", &vertices)?;
        let t = triangles.as_array();
        if t.ncols() != 3 {
            return Err(PyValueError::new_err(format!(
                "triangles must be an (M, 3) array of vertex indices, got shape {:?}",
                triangles.shape()
            )));
        }
        let mut tris = Vec::with_capacity(t.nrows());
        for (n, row) in t.rows().into_iter().enumerate() {
            let mut tri = [0u32; 3];
            for (k, &i) in row.iter().enumerate() {
                tri[k] = u32::try_from(i)
                    .ok()
                    .filter(|&i| (i as usize) < v.len())
                    .ok_or_else(|| {
                        PyValueError::new_err(format!(
                            "triangle {n} refers to vertex {i}: there are {} vertices",
                            v.len()
                        ))
                    })?;
            }
            tris.push(tri);
        }
        let d = asbuilt_core::Design::from_indexed(v, tris, scale).map_err(runtime)?;
        Ok(Self::new(d, "arrays".into()))
    }

    /// The vertices, (N, 3) float64, metres.
    #[getter]
    fn vertices(&self, py: Python<'_>) -> Py<PyAny> {
        let rows: Vec<[f64; 3]> = self
            .design
            .vertices
            .iter()
            .map(|p| [p.x, p.y, p.z])
            .collect();
        convert::array3(py, &rows)
    }

    /// The triangles, (M, 3) uint32 vertex indices.
    #[getter]
    fn triangles(&self, py: Python<'_>) -> Py<PyAny> {
        convert::array3(py, &self.design.triangles)
    }

    /// The lowest and highest corner of the design's box, metres.
    #[getter]
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let (lo, hi) = self.design.bounds();
        (lo.into(), hi.into())
    }

    /// What loading and cleaning the mesh found (merged vertices, dropped faces, open edges).
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.design.report.warnings()
    }

    fn __len__(&self) -> usize {
        self.design.triangles.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "Design({:?}: {} vertices, {} triangles)",
            self.source,
            self.design.vertices.len(),
            self.design.triangles.len()
        )
    }

    /// The design as printed up to `height` (design frame z, metres): cut there and closed by
    /// its cap, as `asbuilt inspect --printed-height` compares with. Triangle ids of the cut
    /// design are those of the pieces' design triangles, then the cap's after them.
    pub(crate) fn cut(&self, py: Python<'_>, height: f64) -> PyResult<Self> {
        let design = self.design.clone();
        let (cut, report) = py
            .detach(|| asbuilt_core::layers::cut_at(&design, height))
            .map_err(runtime)?;
        if report.open_chains > 0 {
            let msg = format!(
                "the cut at {height} m crosses {} open outline(s) of the design (it has holes): \
                 those are not capped",
                report.open_chains
            );
            py.import("warnings")?.call_method1("warn", (msg,))?;
        }
        Ok(Self::new(cut, format!("{} cut at {height} m", self.source)))
    }

    /// Signed cloud-to-mesh distances of `points` ((N, 3) float64, design frame, metres), with
    /// the index and the rules of `asbuilt inspect`: positive outside the design, NaN beyond
    /// `max_distance` (never clamped), ties to the lowest triangle. With `tolerance`, points
    /// farther than it are flagged (flag 4). Returns a dict of arrays: `distance`, `triangle`,
    /// `feature`, `feature_index`, `flags`, `position`.
    #[pyo3(signature = (points, max_distance = 0.05, tolerance = None))]
    fn c2m<'py>(
        &self,
        py: Python<'py>,
        points: PyReadonlyArray2<'py, f64>,
        max_distance: f64,
        tolerance: Option<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let pts = convert::points("points", &points)?;
        drop(points);
        let index = self.index(py, max_distance)?;
        let devs = py.detach(|| deviations(&index, &pts, tolerance));
        convert::deviations_dict(py, &devs)
    }

    /// Writes the design as a binary STL in metres (for an agent's `[design]`, or any viewer).
    fn write_stl(&self, path: PathBuf) -> PyResult<()> {
        asbuilt_sim::write_stl(&path, &self.design).map_err(runtime)
    }

    /// The C2M index's figures for `max_distance`: cells, cell size (m), bytes.
    #[pyo3(signature = (max_distance = 0.05))]
    fn index_stats<'py>(&self, py: Python<'py>, max_distance: f64) -> PyResult<Bound<'py, PyDict>> {
        let s = self.index(py, max_distance)?.stats();
        let d = PyDict::new(py);
        d.set_item("triangles", s.triangles)?;
        d.set_item("cells", s.cells)?;
        d.set_item("cell_size", s.cell_size)?;
        d.set_item("bytes", s.bytes)?;
        Ok(d)
    }
}
