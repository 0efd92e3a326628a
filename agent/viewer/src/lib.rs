//! The rerun view of a job, for someone who was not there: the design, each station where it
//! stood, its points coloured by deviation, its statistics over time and its histogram.
//!
//! A thread of its own owns the rerun stream; callers hand it decimated copies through a
//! bounded queue and never wait: when the queue is full the item is dropped and counted, so a
//! slow or absent viewer never slows the agent. Positions are sent relative to a local origin
//! (the design's centre), so f32 keeps sub-millimetre precision on a site far from 0.
//!
//! Entities: `design` (static mesh), `legend` (the colour scale), `stations/<name>` (the
//! scanner's pose), `stations/<name>/deviations` (points), `stations/<name>/histogram`,
//! `stats/{mean,median_abs,p95_abs}_mm` (time series), and from `asbuilt inspect` also
//! `missing` (design samples) and `m3c2` (core points). Timelines: `station`, `layer`, `time`.
//!
//! Colours: a diverging scale centred on 0, saturated at ± the tolerance: blue (missing
//! material) through white (on the design) to red (excess); grey for no match.

#![warn(missing_docs)]

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;

use asbuilt_protocol::StationReport;
use nalgebra::{Isometry3, Point3, Vector3};

/// Where the view goes, and how much of it.
#[derive(Debug, Clone)]
pub struct ViewerParams {
    /// A `.rrd` file to write.
    pub rrd: Option<PathBuf>,
    /// A viewer to stream to, `rerun+http://HOST:PORT/proxy`.
    pub url: Option<String>,
    /// Points shown per station, at most.
    pub max_points_per_station: usize,
    /// Items waiting for the viewer thread beyond which new ones are dropped.
    pub queue: usize,
    /// The tolerance the colours are scaled to, metres.
    pub tolerance: f64,
    /// Where the viewer's warnings go (it never fails its caller): the agent's log, stderr.
    pub warn: fn(std::fmt::Arguments<'_>),
}

/// One thing to show.
pub enum View {
    /// The design mesh, once.
    Design {
        /// Vertices, design frame, metres.
        vertices: Vec<Point3<f64>>,
        /// Triangles as vertex indices.
        triangles: Vec<[u32; 3]>,
    },
    /// A station's scanner pose, on the station's timeline.
    Station {
        /// The station's number.
        index: u32,
        /// The station's name.
        name: String,
        /// The last printed layer when it scanned.
        layer: u32,
        /// `T_design_scanner`.
        pose: Isometry3<f64>,
        /// When it began, nanoseconds since the Unix epoch.
        time_ns: u64,
    },
    /// Design-frame positions and their signed distance (NaN: no match).
    Points {
        /// The station's number.
        index: u32,
        /// The station's name.
        name: String,
        /// Design frame, metres.
        positions: Vec<Point3<f64>>,
        /// Signed distances, metres, one per position.
        distances: Vec<f32>,
    },
    /// A station's report: its statistics as series and its histogram.
    Report {
        /// The station's number.
        index: u32,
        /// The station's name.
        name: String,
        /// The report.
        report: Box<StationReport>,
    },
    /// Design samples or core points with a value in metres and, for M3C2, significance.
    Samples {
        /// The entity path to log them under.
        path: String,
        /// Design frame, metres.
        positions: Vec<Point3<f64>>,
        /// Metres, one per position; NaN where there is none.
        values: Vec<f32>,
        /// Whether each value is beyond its level of detection (M3C2).
        significant: Option<Vec<bool>>,
    },
    /// A scan layer's findings: regions and missing material as boxes, per-layer width and
    /// top height as series.
    Findings {
        /// The station whose report the findings follow.
        index: u32,
        /// The findings.
        findings: Box<asbuilt_protocol::StationFindings>,
    },
    /// Advice for the layers still to print: z offsets, flow and path as series across scan
    /// layers.
    Correction(Box<asbuilt_protocol::LayerCorrection>),
    /// A per-layer value as a time series on the `layer` timeline.
    LayerValue {
        /// The series' entity path.
        series: String,
        /// The layer, 0-based.
        layer: u32,
        /// The value, metres.
        value: f64,
    },
}

/// A rerun view fed from a thread of its own, so showing never blocks its caller.
pub struct Viewer {
    tx: Option<SyncSender<View>>,
    thread: Option<JoinHandle<()>>,
    /// Views dropped because the viewer thread was behind.
    pub dropped: Arc<AtomicU64>,
    settings: ViewerParams,
}

/// The view could not start: a file that cannot be written, a URL that is not a viewer's.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// Neither a file nor a viewer was named.
    #[error("cannot start the rerun view: give a .rrd file or a viewer URL")]
    NoSink,
    /// The .rrd file cannot be written.
    #[error("cannot start the rerun view: cannot write {path}")]
    File {
        /// The file.
        path: std::path::PathBuf,
        /// rerun's error.
        #[source]
        source: rerun::sink::FileSinkError,
    },
    /// The viewer URL is not one (`rerun+http://HOST:PORT/proxy`).
    #[error(
        "cannot start the rerun view: {url:?} is not a viewer URL (rerun+http://HOST:PORT/proxy)"
    )]
    Url {
        /// The URL given.
        url: String,
        /// rerun's error.
        #[source]
        source: rerun::external::re_uri::Error,
    },
    /// The recording stream could not be made.
    #[error("cannot start the rerun view")]
    Stream(#[source] rerun::RecordingStreamError),
}

impl Viewer {
    /// Opens the sinks the settings name; at least one is needed.
    pub fn start(settings: ViewerParams) -> Result<Self, ViewerError> {
        let builder = rerun::RecordingStreamBuilder::new("asbuilt");
        let rec = match (&settings.rrd, &settings.url) {
            (Some(path), Some(url)) => {
                let sink =
                    rerun::sink::FileSink::new(path).map_err(|source| ViewerError::File {
                        path: path.clone(),
                        source,
                    })?;
                let uri = url.parse().map_err(|source| ViewerError::Url {
                    url: url.clone(),
                    source,
                })?;
                builder
                    .set_sinks((sink, rerun::sink::GrpcSink::new(uri)))
                    .map_err(ViewerError::Stream)?
            }
            (Some(path), None) => builder.save(path).map_err(ViewerError::Stream)?,
            (None, Some(url)) => builder
                .connect_grpc_opts(url.clone())
                .map_err(ViewerError::Stream)?,
            (None, None) => return Err(ViewerError::NoSink),
        };
        Ok(Self::with_stream(rec, settings))
    }

    /// Shows on an existing stream (tests use rerun's memory sink).
    pub fn with_stream(rec: rerun::RecordingStream, settings: ViewerParams) -> Self {
        // The layout a reviewer opens on, sent ahead of the data (a failure leaves rerun's own).
        if let Err(e) = blueprint().send(&rec, Default::default()) {
            (settings.warn)(format_args!("viewer: the layout was not sent: {e}"));
        }
        let (tx, rx) = sync_channel(settings.queue.max(1));
        let (tolerance, warn) = (settings.tolerance, settings.warn);
        let thread = std::thread::Builder::new()
            .name("viewer".into())
            .spawn(move || Painter::new(rec, tolerance, warn).run(rx))
            .expect("a thread can be started");
        Self {
            tx: Some(tx),
            thread: Some(thread),
            dropped: Arc::new(AtomicU64::new(0)),
            settings,
        }
    }

    /// Points shown per station, at most.
    pub fn max_points_per_station(&self) -> usize {
        self.settings.max_points_per_station
    }

    /// Queues `view`, or drops and counts it when the viewer is behind.
    pub fn show(&self, view: View) {
        let Some(tx) = &self.tx else { return };
        match tx.try_send(view) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                let n = self.dropped.fetch_add(1, Relaxed);
                if n.is_power_of_two() {
                    (self.settings.warn)(format_args!(
                        "viewer: {} item(s) dropped so far: the viewer is behind",
                        n + 1
                    ));
                }
            }
        }
    }

    /// Sends what is queued and closes the stream (the `.rrd` is complete after this).
    pub fn finish(&mut self) {
        self.tx.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        self.finish();
    }
}

/// What a reviewer sees first: the part (design, stations, coloured points, findings) large,
/// beside the current station's histogram, the station statistics and the findings as text; a
/// second tab with each layer band's history across scan layers. The `station` timeline first.
pub fn blueprint() -> rerun::blueprint::Blueprint {
    use rerun::blueprint::{
        BarChartView, Blueprint, BlueprintPanel, Horizontal, SelectionPanel, Spatial3DView, Tabs,
        TextDocumentView, TimePanel, TimeSeriesView, Vertical,
    };
    let part = Horizontal::new([
        Spatial3DView::new("part")
            .with_origin("/")
            .with_contents([
                "+ /design",
                "+ /stations/**",
                "+ /deviations/**",
                "+ /findings/**",
                "+ /missing",
                "+ /m3c2",
                "- /stations/*/histogram",
                "- /findings/summary",
            ])
            .into(),
        Vertical::new([
            BarChartView::new("current station: deviation histogram")
                .with_origin("/histogram")
                .into(),
            TimeSeriesView::new("station statistics (mm)")
                .with_origin("/stats")
                .into(),
            TextDocumentView::new("findings")
                .with_origin("/findings/summary")
                .into(),
            TextDocumentView::new("colours")
                .with_origin("/legend")
                .into(),
        ])
        .with_row_shares([1.0, 1.0, 1.4, 0.6])
        .into(),
    ])
    .with_name("part")
    .with_column_shares([3.0, 1.0]);
    let history = Vertical::new([
        TimeSeriesView::new("width per layer band (mm), by scan layer")
            .with_origin("/history/width_mm")
            .into(),
        TimeSeriesView::new(
            "relative width per layer band (mm): less the scan layer's median; a rising line is creep",
        )
        .with_origin("/history/relative_width_mm")
        .into(),
        TimeSeriesView::new("shift per layer band (mm), by scan layer")
            .with_origin("/history/shift_mm")
            .into(),
        TimeSeriesView::new("top height deviation (mm), by scan layer")
            .with_origin("/history/top_mm")
            .into(),
        TimeSeriesView::new(
            "corrections advised, by scan layer: z per layer (mm), flow − 1 (%), path (mm)",
        )
        .with_origin("/history/corrections")
        .into(),
        TimeSeriesView::new("mean deviation per layer band (mm), over the bands (time: band)")
            .with_origin("/layers")
            .into(),
    ])
    .with_name("layer history");
    // The side panels start folded away: the part gets the window.
    let folded = rerun::blueprint::components::PanelState::Collapsed;
    Blueprint::new(Tabs::new([part.into(), history.into()]))
        .with_blueprint_panel(BlueprintPanel::new().with_state(folded))
        .with_selection_panel(SelectionPanel::new().with_state(folded))
        .with_time_panel(TimePanel::new().with_timeline("station"))
}

/// Every `step`-th valid point of a deviation chunk: design-frame positions and distances.
pub fn decimate(
    devs: &[asbuilt_protocol::PointDeviation],
    step: usize,
) -> (Vec<Point3<f64>>, Vec<f32>) {
    devs.iter()
        .filter(|d| !d.flags.contains(asbuilt_protocol::DeviationFlags::REJECTED))
        .step_by(step.max(1))
        .map(|d| (Point3::from(d.position), d.distance as f32))
        .unzip()
}

/// Every `stride`-th element, for at most `max` of `n`.
pub fn stride(n: usize, max: usize) -> usize {
    if max == 0 {
        usize::MAX
    } else {
        n.div_ceil(max).max(1)
    }
}

struct Painter {
    rec: rerun::RecordingStream,
    tolerance: f64,
    origin: Vector3<f64>,
    warn: fn(std::fmt::Arguments<'_>),
}

/// Blue (−tolerance) through white (0) to red (+tolerance), saturated beyond; grey for NaN:
/// core's scale, the one the report's maps use.
pub fn colour(d: f32, tolerance: f64) -> [u8; 3] {
    asbuilt_core::colour::deviation_colour(f64::from(d), tolerance)
}

impl Painter {
    fn new(rec: rerun::RecordingStream, tolerance: f64, warn: fn(std::fmt::Arguments<'_>)) -> Self {
        let legend = format!(
            "# asbuilt deviation colours\n\nSigned distance to the design, saturated at the \
             tolerance (±{:.1} mm): **blue** −{:.1} mm and below (missing material), **white** \
             0, **red** +{:.1} mm and above (excess material), **grey** no match within the \
             maximum distance. Positions are relative to the design's centre.",
            tolerance * 1e3,
            tolerance * 1e3,
            tolerance * 1e3
        );
        let _ = rec.log_static(
            "legend",
            &rerun::TextDocument::new(legend).with_media_type(rerun::MediaType::markdown()),
        );
        Self {
            rec,
            tolerance,
            origin: Vector3::zeros(),
            warn,
        }
    }

    fn local(&self, p: &Point3<f64>) -> [f32; 3] {
        let v = p.coords - self.origin;
        [v.x as f32, v.y as f32, v.z as f32]
    }

    fn run(mut self, rx: Receiver<View>) {
        while let Ok(v) = rx.recv() {
            if let Err(e) = self.paint(v) {
                (self.warn)(format_args!("viewer: {e}"));
            }
        }
        let _ = self.rec.flush_blocking();
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

    /// A station's statistics as series and its histogram, on the station timeline.
    fn report(
        &mut self,
        index: u32,
        name: &str,
        report: &StationReport,
    ) -> Result<(), rerun::RecordingStreamError> {
        self.rec.set_time_sequence("station", index as i64);
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
        self.rec.log("histogram", &chart)?;
        Ok(())
    }

    /// Design samples or core points coloured by their value; M3C2's insignificant ones faint.
    fn samples(
        &mut self,
        path: String,
        positions: &[Point3<f64>],
        values: &[f32],
        significant: Option<&[bool]>,
    ) -> Result<(), rerun::RecordingStreamError> {
        let colours: Vec<rerun::Color> = values
            .iter()
            .zip(0..)
            .map(|(&d, i)| {
                let faint = significant.as_ref().is_some_and(|s| !s[i]);
                let [r, g, b] = colour(d, self.tolerance);
                rerun::Color::from_unmultiplied_rgba(r, g, b, if faint { 60 } else { 255 })
            })
            .collect();
        let pts: Vec<[f32; 3]> = positions.iter().map(|p| self.local(p)).collect();
        self.rec.log_static(
            path,
            &rerun::Points3D::new(pts)
                .with_colors(colours)
                .with_radii([rerun::Radius::new_ui_points(3.0)]),
        )?;
        Ok(())
    }

    fn paint(&mut self, v: View) -> Result<(), rerun::RecordingStreamError> {
        match v {
            View::Design {
                vertices,
                triangles,
            } => self.design(&vertices, &triangles)?,
            View::Station {
                index,
                name,
                layer,
                pose,
                time_ns,
            } => {
                self.rec.set_time_sequence("station", index as i64);
                self.rec.set_time_sequence("layer", layer as i64);
                self.rec
                    .set_timestamp_nanos_since_epoch("time", time_ns as i64);
                let t = pose.translation.vector - self.origin;
                let q = pose.rotation.quaternion();
                self.rec.log(
                    format!("stations/{name}"),
                    &rerun::Transform3D::from_translation_rotation(
                        [t.x as f32, t.y as f32, t.z as f32],
                        rerun::Quaternion::from_xyzw([
                            q.i as f32, q.j as f32, q.k as f32, q.w as f32,
                        ]),
                    ),
                )?;
            }
            View::Points {
                index,
                name,
                positions,
                distances,
            } => {
                self.rec.set_time_sequence("station", index as i64);
                let colours: Vec<rerun::Color> = distances
                    .iter()
                    .map(|&d| {
                        let [r, g, b] = colour(d, self.tolerance);
                        rerun::Color::from_rgb(r, g, b)
                    })
                    .collect();
                let pts: Vec<[f32; 3]> = positions.iter().map(|p| self.local(p)).collect();
                // Points are in the design frame: log them beside the station, not under its
                // transform.
                self.rec.log(
                    format!("deviations/{name}"),
                    &rerun::Points3D::new(pts)
                        .with_colors(colours)
                        .with_radii([rerun::Radius::new_ui_points(2.0)]),
                )?;
            }
            View::Report {
                index,
                name,
                report,
            } => self.report(index, &name, &report)?,
            View::Samples {
                path,
                positions,
                values,
                significant,
            } => self.samples(path, &positions, &values, significant.as_deref())?,
            View::Findings { index, findings } => self.findings(index, &findings)?,
            View::Correction(c) => self.correction(&c)?,
            View::LayerValue {
                series,
                layer,
                value,
            } => {
                // A profile over the bands, on a timeline of its own.
                self.rec.set_time_sequence("band", layer as i64);
                if value.is_finite() {
                    self.rec
                        .log(format!("layers/{series}"), &rerun::Scalars::new([value]))?;
                }
            }
        }
        Ok(())
    }

    /// A scan layer's findings: labelled boxes (red excess, blue deficit) and translucent
    /// amber patches where material is missing, under an entity of their own per scan layer so
    /// each can be switched off; the findings as text; and each layer band's width and shift,
    /// and the top height, as one series per band across scan layers (time `layer`: the scan
    /// layer).
    fn findings(
        &mut self,
        index: u32,
        f: &asbuilt_protocol::StationFindings,
    ) -> Result<(), rerun::RecordingStreamError> {
        use asbuilt_protocol::RegionKind;
        self.rec.set_time_sequence("station", index as i64);
        self.rec.set_time_sequence("layer", f.layer as i64);
        let scan_layer = format!("findings/scan_layer_{:03}", f.layer);
        // Out-of-tolerance regions as outlines, missing material as filled patches.
        for (what, list, fill) in [
            ("regions", &f.regions[..], rerun::FillMode::MajorWireframe),
            ("missing", &f.missing[..], rerun::FillMode::Solid),
        ] {
            let mut centres = Vec::new();
            let mut halves = Vec::new();
            let mut colours = Vec::new();
            let mut labels = Vec::new();
            for r in list {
                let (lo, hi) = (Point3::from(r.min), Point3::from(r.max));
                centres.push(self.local(&nalgebra::center(&lo, &hi)));
                let h = (hi - lo) * 0.5;
                // A flat region still gets a visible box.
                halves.push([h.x, h.y, h.z].map(|v| v.max(0.002) as f32));
                colours.push(match r.kind {
                    RegionKind::Excess => rerun::Color::from_rgb(230, 40, 40),
                    RegionKind::Deficit => rerun::Color::from_rgb(40, 70, 230),
                    RegionKind::Missing => rerun::Color::from_unmultiplied_rgba(255, 190, 0, 110),
                });
                labels.push(label(r));
            }
            let boxes = rerun::Boxes3D::from_centers_and_half_sizes(centres, halves)
                .with_colors(colours)
                .with_labels(labels)
                .with_fill_mode(fill);
            self.rec.log(format!("{scan_layer}/{what}"), &boxes)?;
        }
        self.rec.log(
            "findings/summary",
            &rerun::TextDocument::new(summary(f)).with_media_type(rerun::MediaType::markdown()),
        )?;
        if f.top_height_deviation.is_finite() {
            self.rec.log(
                "history/top_mm",
                &rerun::Scalars::new([f.top_height_deviation * 1e3]),
            )?;
        }
        // The scan layer's median band width: what its stations' pose errors do to every band
        // alike. A band's width less it is the relative width the report's creep follows.
        let mut widths: Vec<f64> = f.layers.iter().filter_map(|r| r.width()).collect();
        widths.sort_by(f64::total_cmp);
        let median = match widths.len() {
            0 => None,
            n if n % 2 == 1 => Some(widths[n / 2]),
            n => Some(0.5 * (widths[n / 2 - 1] + widths[n / 2])),
        };
        // Each scan layer's profile of the bands' mean M3C2 distance, on the `band` timeline
        // alone (as `inspect` draws its per-band means).
        let profile = format!("layers/m3c2_mean_mm/scan_layer_{:03}", f.layer);
        self.rec.reset_time();
        for row in &f.layers {
            if row.samples > 0 && row.mean.is_finite() {
                self.rec.set_time_sequence("band", row.layer as i64);
                self.rec
                    .log(profile.as_str(), &rerun::Scalars::new([row.mean * 1e3]))?;
            }
        }
        self.rec.reset_time();
        self.rec.set_time_sequence("station", index as i64);
        self.rec.set_time_sequence("layer", f.layer as i64);
        for row in &f.layers {
            let band = format!("band_{:03}", row.layer);
            if let Some(w) = row.width() {
                self.rec.log(
                    format!("history/width_mm/{band}"),
                    &rerun::Scalars::new([w * 1e3]),
                )?;
                if let Some(m) = median {
                    self.rec.log(
                        format!("history/relative_width_mm/{band}"),
                        &rerun::Scalars::new([(w - m) * 1e3]),
                    )?;
                }
            }
            if row.shift.iter().all(|v| v.is_finite()) {
                let shift = row.shift[0].hypot(row.shift[1]);
                self.rec.log(
                    format!("history/shift_mm/{band}"),
                    &rerun::Scalars::new([shift * 1e3]),
                )?;
            }
        }
        Ok(())
    }
}

impl Painter {
    /// Advice as series on the `layer` timeline (the scan layer it follows): the z offset per
    /// layer for the first layers and after, the flow's departure from nominal, and the path.
    fn correction(
        &mut self,
        c: &asbuilt_protocol::LayerCorrection,
    ) -> Result<(), rerun::RecordingStreamError> {
        self.rec.set_time_sequence("station", c.station as i64);
        self.rec.set_time_sequence("layer", c.layer as i64);
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

/// A finding's label in the 3D view: its kind and peak, or its area.
fn label(r: &asbuilt_protocol::RegionFinding) -> String {
    let layers = if r.layers[0] == u32::MAX {
        String::new()
    } else {
        format!(", layers {}-{}", r.layers[0], r.layers[1])
    };
    if r.peak.is_finite() {
        format!("{} {:+.1} mm{layers}", r.kind.as_str(), r.peak * 1e3)
    } else {
        format!("{} {:.0} cm²{layers}", r.kind.as_str(), r.area_m2 * 1e4)
    }
}

/// The findings of a scan layer as a markdown table.
fn summary(f: &asbuilt_protocol::StationFindings) -> String {
    let mut s = format!(
        "# Scan layer {} ({} station(s))\n\nTop height {}; tolerance ±{:.1} mm.\n\n",
        f.layer,
        f.stations,
        if f.top_height_deviation.is_finite() {
            format!("{:+.1} mm", f.top_height_deviation * 1e3)
        } else {
            "not seen".into()
        },
        f.tolerance * 1e3
    );
    if f.regions.is_empty() && f.missing.is_empty() {
        s += "Nothing out of tolerance.\n";
        return s;
    }
    s += "| finding | peak / area | layers | where (m) |\n| --- | --- | --- | --- |\n";
    for r in f.regions.iter().chain(f.missing.iter()) {
        let [x, y, z] = r.centroid;
        let value = if r.peak.is_finite() {
            format!("{:+.1} mm", r.peak * 1e3)
        } else {
            format!("{:.0} cm²", r.area_m2 * 1e4)
        };
        let layers = if r.layers[0] == u32::MAX {
            "-".to_string()
        } else {
            format!("{}-{}", r.layers[0], r.layers[1])
        };
        s += &format!(
            "| {} | {value} | {layers} | {x:.2}, {y:.2}, {z:.2} |\n",
            r.kind.as_str()
        );
    }
    if f.truncated > 0 {
        s += &format!("\n{} more not listed.\n", f.truncated);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_colour_scale_is_centred_and_saturates_at_the_tolerance() {
        assert_eq!(colour(0.0, 0.005), [255, 255, 255]);
        assert_eq!(colour(0.005, 0.005), [255, 0, 0]);
        assert_eq!(colour(0.02, 0.005), [255, 0, 0]);
        assert_eq!(colour(-0.005, 0.005), [0, 0, 255]);
        assert_eq!(colour(f32::NAN, 0.005), [128, 128, 128]);
        assert_eq!(stride(1000, 100), 10);
        assert_eq!(stride(50, 100), 1);
    }
}
