//! The viewer thread's side: each [`View`] drawn into the rerun stream, every item placed on
//! both the `station` and the `layer` timelines so each panel has data on the one the view
//! opens on.

use std::collections::BTreeMap;
use std::sync::mpsc::Receiver;

use asbuilt_protocol::StationReport;
use nalgebra::{Isometry3, Point3, Vector3};

use crate::findings::ScanLayers;
use crate::{BandMeans, View, ViewerParams, colour};

/// Stations whose scan layer is remembered for their points, at most (the oldest go first).
const STATIONS_REMEMBERED: usize = 4096;

pub(crate) struct Painter {
    pub(crate) rec: rerun::RecordingStream,
    pub(crate) tolerance: f64,
    /// The design's centre, design frame: subtracted from every position.
    pub(crate) origin: Vector3<f64>,
    /// The design's bounds, local: where the layer bands' ruler stands.
    pub(crate) bounds: Option<(Point3<f64>, Point3<f64>)>,
    pub(crate) warn: fn(std::fmt::Arguments<'_>),
    /// Each recent station's scan layer, for its points (which do not carry it).
    station_layer: BTreeMap<u32, u32>,
    /// The current job's findings, for their verdicts and numbers.
    pub(crate) scan_layers: ScanLayers,
    /// The line profiler's pass whose sensor came last: its points are its latest profiles.
    pass: Option<u32>,
    /// The latest scan layer's findings and the station that brought them, whose history is
    /// drawn once the scan layer is complete.
    pub(crate) pending_history: Option<(u32, asbuilt_protocol::StationFindings)>,
}

impl Painter {
    pub(crate) fn new(rec: rerun::RecordingStream, settings: &ViewerParams) -> Self {
        let t = settings.tolerance * 1e3;
        let legend = format!(
            "# asbuilt deviation colours\n\nSigned distance to the design, saturated at the \
             tolerance (±{t:.1} mm): **blue** −{t:.1} mm and below (missing material), **white** \
             0, **red** +{t:.1} mm and above (excess material), **grey** no match within the \
             maximum distance. Positions are relative to the design's centre.\n\n\
             Findings: a numbered marker per warning or failure of the scan layer at the time \
             cursor, its number as in the report; **red** fail, **amber** warn, **violet** \
             inconclusive. Layer bands' findings stand on the ruler at the part's corner. \
             Boxes: out-of-tolerance regions (red excess, blue deficit), amber missing material."
        );
        let _ = rec.log_static(
            "legend",
            &rerun::TextDocument::new(legend).with_media_type(rerun::MediaType::markdown()),
        );
        // A dot per station: several stations share a scan layer, and a line through them
        // would draw spikes.
        for (series, rgb) in [
            ("mean_mm", [80, 80, 80]),
            ("median_abs_mm", [40, 120, 200]),
            ("p95_abs_mm", [220, 60, 40]),
        ] {
            let _ = rec.log_static(
                format!("stats/{series}"),
                &rerun::SeriesPoints::new()
                    .with_names([series])
                    .with_colors([rerun::Color::from_rgb(rgb[0], rgb[1], rgb[2])])
                    .with_marker_sizes([3.0]),
            );
        }
        let limits = settings
            .limits
            .clone()
            .unwrap_or_else(|| asbuilt_core::verdict::Limits::from_tolerance(settings.tolerance));
        Self {
            rec,
            tolerance: settings.tolerance,
            origin: Vector3::zeros(),
            bounds: None,
            warn: settings.warn,
            station_layer: BTreeMap::new(),
            pass: None,
            scan_layers: ScanLayers::new(limits),
            pending_history: None,
        }
    }

    pub(crate) fn local(&self, p: &Point3<f64>) -> [f32; 3] {
        let v = p.coords - self.origin;
        [v.x as f32, v.y as f32, v.z as f32]
    }

    /// What follows is logged at station `station` of scan layer `layer`.
    pub(crate) fn at(&self, station: u32, layer: u32) {
        self.rec.set_time_sequence("station", i64::from(station));
        self.rec.set_time_sequence("layer", i64::from(layer));
    }

    pub(crate) fn run(mut self, rx: Receiver<View>) {
        while let Ok(v) = rx.recv() {
            if let Err(e) = self.paint(v) {
                (self.warn)(format_args!("viewer: {e}"));
            }
        }
        if let Err(e) = self.flush_history() {
            (self.warn)(format_args!("viewer: {e}"));
        }
        let _ = self.rec.flush_blocking();
    }

    fn paint(&mut self, v: View) -> Result<(), rerun::RecordingStreamError> {
        match v {
            View::Design {
                vertices,
                triangles,
            } => self.design(&vertices, &triangles),
            View::Station {
                index,
                name,
                layer,
                pose,
                time_ns,
            } => {
                self.at_station(index, layer);
                self.rec
                    .set_timestamp_nanos_since_epoch("time", time_ns as i64);
                self.rec
                    .log(format!("stations/{name}"), &self.transform(&pose))
            }
            View::Sensor { index, layer, pose } => self.sensor(index, layer, &pose),
            View::Points {
                index,
                name,
                part,
                positions,
                distances,
            } => self.points(index, &format!("{name}/{part:04}"), &positions, &distances),
            View::Report { name, report, .. } => self.report(&name, &report),
            View::Samples {
                path,
                positions,
                values,
                significant,
            } => self.samples(path, &positions, &values, significant.as_deref()),
            View::Findings { index, findings } => self.findings(index, &findings),
            View::Correction(c) => self.correction(&c),
            View::Bands(rows) => self.bands(&rows),
            // Static: nothing comes after it (it is sent at the end of a job without findings).
            View::NoFindings { why } => self.rec.log_static(
                "findings/table",
                &rerun::TextDocument::new(why).with_media_type(rerun::MediaType::markdown()),
            ),
        }
    }

    /// The design, once, as a translucent mesh; its centre becomes the view's origin.
    fn design(
        &mut self,
        vertices: &[Point3<f64>],
        triangles: &[[u32; 3]],
    ) -> Result<(), rerun::RecordingStreamError> {
        if let Some(first) = vertices.first() {
            let (lo, hi) = vertices
                .iter()
                .fold((*first, *first), |(lo, hi), p| (lo.inf(p), hi.sup(p)));
            self.origin = (lo.coords + hi.coords) * 0.5;
            self.bounds = Some((lo - self.origin, hi - self.origin));
        }
        let positions: Vec<[f32; 3]> = vertices.iter().map(|p| self.local(p)).collect();
        self.rec.log_static(
            "design",
            &rerun::Mesh3D::new(positions)
                .with_triangle_indices(triangles.iter().map(|t| (t[0], t[1], t[2])))
                .with_albedo_factor(rerun::Rgba32::from_unmultiplied_rgba(200, 200, 200, 90)),
        )?;
        Ok(())
    }

    /// A station's decimated points, beside its pose (they are in the design frame already, so
    /// not under its transform).
    fn points(
        &mut self,
        index: u32,
        name: &str,
        positions: &[Point3<f64>],
        distances: &[f32],
    ) -> Result<(), rerun::RecordingStreamError> {
        let layer = self.station_layer.get(&index).copied().unwrap_or(0);
        self.at(index, layer);
        let colours: Vec<rerun::Color> = distances
            .iter()
            .map(|&d| {
                let [r, g, b] = colour(d, self.tolerance);
                rerun::Color::from_rgb(r, g, b)
            })
            .collect();
        let pts: Vec<[f32; 3]> = positions.iter().map(|p| self.local(p)).collect();
        if self.pass == Some(index) {
            // A pass's newest batch is what the profiler just swept: drawn again, larger, in
            // place of the batch before, so the view shows the line profiles being laid.
            self.rec.log(
                "profiler/latest",
                &rerun::Points3D::new(pts.iter().copied())
                    .with_colors(colours.iter().copied())
                    .with_radii([rerun::Radius::new_ui_points(4.0)]),
            )?;
        }
        self.rec.log(
            format!("deviations/{name}"),
            &rerun::Points3D::new(pts)
                .with_colors(colours)
                .with_radii([rerun::Radius::new_ui_points(2.0)]),
        )
    }

    /// A line profiler's sensor where its latest profile was taken: its axes (z the view,
    /// x along the line) under `profiler/sensor`, at the pass and its layer.
    fn sensor(
        &mut self,
        index: u32,
        layer: u32,
        pose: &Isometry3<f64>,
    ) -> Result<(), rerun::RecordingStreamError> {
        self.pass = Some(index);
        self.at_station(index, layer);
        self.rec.log("profiler/sensor", &self.transform(pose))?;
        self.rec
            .log("profiler/sensor", &rerun::TransformAxes3D::new(0.1))
    }

    /// Station `index` is of scan layer `layer` (its points do not carry it), and the time
    /// cursor goes to it.
    fn at_station(&mut self, index: u32, layer: u32) {
        self.station_layer.insert(index, layer);
        if self.station_layer.len() > STATIONS_REMEMBERED {
            self.station_layer.pop_first();
        }
        self.at(index, layer);
    }

    /// A design-frame pose as a transform from the view's origin.
    fn transform(&self, pose: &Isometry3<f64>) -> rerun::Transform3D {
        let t = pose.translation.vector - self.origin;
        let q = pose.rotation.quaternion();
        rerun::Transform3D::from_translation_rotation(
            [t.x as f32, t.y as f32, t.z as f32],
            rerun::Quaternion::from_xyzw([q.i as f32, q.j as f32, q.k as f32, q.w as f32]),
        )
    }

    /// A station's statistics (a dot each) and its histogram, at the station and its scan
    /// layer.
    fn report(
        &mut self,
        name: &str,
        report: &StationReport,
    ) -> Result<(), rerun::RecordingStreamError> {
        self.at(report.station, report.layer);
        let s = &report.stats;
        for (series, v) in [
            ("mean_mm", s.mean),
            ("median_abs_mm", s.median_abs),
            ("p95_abs_mm", s.p95_abs),
        ] {
            if v.is_finite() {
                self.rec
                    .log(format!("stats/{series}"), &rerun::Scalars::new([v * 1e3]))?;
            }
        }
        let bins: Vec<f64> = report.histogram.bins.iter().map(|&b| b as f64).collect();
        let chart = rerun::BarChart::new(bins.as_slice());
        self.rec.log(format!("stations/{name}/histogram"), &chart)?;
        // The one the side column shows: the station at the time cursor.
        self.rec.log("histogram", &chart)
    }

    /// Design samples or core points coloured by their value; M3C2's insignificant ones pale.
    fn samples(
        &mut self,
        path: String,
        positions: &[Point3<f64>],
        values: &[f32],
        significant: Option<&[bool]>,
    ) -> Result<(), rerun::RecordingStreamError> {
        let colours: Vec<rerun::Color> = values
            .iter()
            .enumerate()
            .map(|(i, &d)| {
                let faint = significant.is_some_and(|s| !s.get(i).copied().unwrap_or(true));
                let rgb = colour(d, self.tolerance);
                // Paled towards white, opaque: translucent points draw dark in rerun.
                let [r, g, b] = if faint {
                    rgb.map(|c| c + ((255 - c) as f32 * 0.7) as u8)
                } else {
                    rgb
                };
                rerun::Color::from_rgb(r, g, b)
            })
            .collect();
        let pts: Vec<[f32; 3]> = positions.iter().map(|p| self.local(p)).collect();
        self.rec.log_static(
            path,
            &rerun::Points3D::new(pts)
                .with_colors(colours)
                .with_radii([rerun::Radius::new_ui_points(3.0)]),
        )
    }

    /// A survey's means per band, static (they hold for the whole job): C2M's as a bar chart
    /// against the band, every method's in a table.
    fn bands(&mut self, rows: &[BandMeans]) -> Result<(), rerun::RecordingStreamError> {
        let (bands, means): (Vec<i64>, Vec<f64>) = rows
            .iter()
            .filter_map(|r| Some((i64::from(r.layer), r.c2m? * 1e3)))
            .unzip();
        if !means.is_empty() {
            self.rec.log_static(
                "layers/c2m_mean_mm",
                &rerun::BarChart::new(means.as_slice()).with_abscissa(bands.as_slice()),
            )?;
        }
        let mm = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{:+.2}", v * 1e3));
        let mut table = String::from(
            "# Layer bands\n\nMean distance of each band (mm), by method; - where the method \
             saw nothing of it.\n\n| band | z (m) | C2M | reverse C2C | M3C2 |\n\
             | --- | --- | --- | --- | --- |\n",
        );
        for r in rows {
            table += &format!(
                "| {} | {:.3} to {:.3} | {} | {} | {} |\n",
                r.layer,
                r.z[0],
                r.z[1],
                mm(r.c2m),
                mm(r.c2c),
                mm(r.m3c2)
            );
        }
        self.rec.log_static(
            "layers/table",
            &rerun::TextDocument::new(table).with_media_type(rerun::MediaType::markdown()),
        )
    }

    /// Advice as series at the scan layer it follows: the z offset per layer for the first
    /// layers and after, the flow's departure from nominal, and the path.
    fn correction(
        &mut self,
        c: &asbuilt_protocol::LayerCorrection,
    ) -> Result<(), rerun::RecordingStreamError> {
        self.at(c.station, c.layer);
        for (series, value) in [
            ("z_first_mm", c.z_first * 1e3),
            ("z_then_mm", c.z_then * 1e3),
            ("flow_minus_1_percent", (c.flow - 1.0) * 1e2),
            ("path_x_mm", c.path_offset[0] * 1e3),
            ("path_y_mm", c.path_offset[1] * 1e3),
        ] {
            self.rec.log(
                format!("history/corrections/{series}"),
                &rerun::Scalars::new([value]),
            )?;
        }
        Ok(())
    }
}
