//! The rerun view of a job, for someone who was not there: the design, each station where it
//! stood, its points coloured by deviation, the scan layer's findings as numbered markers (the
//! report's numbers), the stations' statistics and each layer band's history.
//!
//! A thread of its own owns the rerun stream; callers hand it decimated copies through a
//! bounded queue and never wait: when the queue is full the item is dropped and counted, so a
//! slow or absent viewer never slows the agent. Positions are sent relative to a local origin
//! (the design's centre), so f32 keeps sub-millimetre precision on a site far from 0.
//!
//! The layout is a table ([`PANELS`]); every panel has data on the timeline the view opens on
//! ([`Job::timeline`]): `layer` (the scan layer) for a print, `station` for a survey. Entities:
//! `design` (static mesh), `legend`, `stations/<name>` (the scanner's pose),
//! `deviations/<name>/<part>` (points, a part per chunk shown), `profiler/{sensor,latest}` (a
//! line profiler's sensor and the profiles it just took), `histogram`,
//! `stats/{mean,median_abs,p95_abs}_mm`, `findings/{markers,areas/*,ruler,table}`, `history/*` (one series per band), `layers/*`
//! (per-band means), and from `asbuilt inspect` also `missing` and `m3c2` (design samples and
//! core points).
//!
//! Colours: a diverging scale centred on 0, saturated at ± the tolerance: blue (missing
//! material) through white (on the design) to red (excess); grey for no match.

#![warn(missing_docs)]

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::mpsc::{SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;

use asbuilt_protocol::StationReport;
use nalgebra::{Isometry3, Point3};

mod findings;
mod layout;
mod paint;
mod survey;

pub use layout::{Job, PANELS, Panel, PanelKind, Tab, blueprint, panels};
use paint::Painter;

/// Where the view goes, and how much of it.
#[derive(Debug, Clone)]
pub struct ViewerParams {
    /// A `.rrd` file to write.
    pub rrd: Option<PathBuf>,
    /// Whether the file ends with rerun's footer, its manifest of every chunk for random
    /// access: rerun keeps that manifest in memory until the file closes (rerun #12623), so it
    /// grows with the job (8 MB over the column's 60 passes). A bounded run writes it; the
    /// agent, which runs for as long as the cell prints, does not (`rerun rrd optimize` adds
    /// it to a file afterwards).
    pub footer: bool,
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
    /// What kind of job it is: its timeline and panels.
    pub job: Job,
    /// What the findings are held to, for their verdicts and numbers (the report's); `None`:
    /// the job's tolerance for every kind.
    pub limits: Option<asbuilt_core::verdict::Limits>,
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
    /// A line profiler's sensor (`T_design_sensor`) at the latest profile compared of pass
    /// `index`, of layer `layer`: drawn where it is now, and the pass's points that follow are
    /// also drawn as its latest profiles.
    Sensor {
        /// The pass's number.
        index: u32,
        /// The layer the pass scans.
        layer: u32,
        /// `T_design_sensor`.
        pose: Isometry3<f64>,
    },
    /// Design-frame positions and their signed distance (NaN: no match): one part of a
    /// station's points. Each part is an entity of its own under the station's: rerun shows an
    /// entity's latest points only, and a station's chunks come at one time.
    Points {
        /// The station's number.
        index: u32,
        /// The station's name.
        name: String,
        /// Which of the station's parts, from 0 (a part sent again replaces itself).
        part: u32,
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
    /// A scan layer's findings (again after each of its stations): judged as the report judges
    /// them, drawn as numbered markers, boxes and a table; each band's width and shift and the
    /// top height as series once the scan layer is complete.
    Findings {
        /// The station whose report the findings follow.
        index: u32,
        /// The findings.
        findings: Box<asbuilt_protocol::StationFindings>,
    },
    /// Advice for the layers still to print: z offsets, flow and path as series across scan
    /// layers.
    Correction(Box<asbuilt_protocol::LayerCorrection>),
    /// Why a job has no findings, in the findings' place, once.
    NoFindings {
        /// Markdown a reviewer reads.
        why: String,
    },
    /// A survey's means per layer band, once.
    Bands(Vec<BandMeans>),
}

/// One layer band's mean distances by each method, metres (`None`: the method did not run or
/// saw nothing of it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandMeans {
    /// The band's layer, from 0.
    pub layer: u32,
    /// Its bottom and top, design frame, metres.
    pub z: [f64; 2],
    /// Mean signed point-to-mesh distance.
    pub c2m: Option<f64>,
    /// Mean reverse cloud-to-cloud distance of its design samples.
    pub c2c: Option<f64>,
    /// Mean M3C2 distance of its core points.
    pub m3c2: Option<f64>,
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
        let file = |path: &std::path::PathBuf| {
            let options = rerun::sink::FileSinkOptions {
                write_footer: settings.footer,
            };
            rerun::sink::FileSink::with_options(path, options).map_err(|source| ViewerError::File {
                path: path.clone(),
                source,
            })
        };
        let rec = match (&settings.rrd, &settings.url) {
            (Some(path), Some(url)) => {
                let uri = url.parse().map_err(|source| ViewerError::Url {
                    url: url.clone(),
                    source,
                })?;
                builder
                    .set_sinks((file(path)?, rerun::sink::GrpcSink::new(uri)))
                    .map_err(ViewerError::Stream)?
            }
            (Some(path), None) => builder
                .set_sinks((file(path)?,))
                .map_err(ViewerError::Stream)?,
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
        if let Err(e) = blueprint(settings.job).send(&rec, Default::default()) {
            (settings.warn)(format_args!("viewer: the layout was not sent: {e}"));
        }
        let (tx, rx) = sync_channel(settings.queue.max(1));
        let painter = Painter::new(rec, &settings);
        let thread = std::thread::Builder::new()
            .name("viewer".into())
            .spawn(move || painter.run(rx))
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

    /// Queues every one of `views`, waiting for room: for drawing again what a job holds
    /// already (an agent resuming one), before anything waits on the agent.
    pub fn show_all(&self, views: impl IntoIterator<Item = View>) {
        let Some(tx) = &self.tx else { return };
        for v in views {
            if tx.send(v).is_err() {
                return;
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

/// Blue (−tolerance) through white (0) to red (+tolerance), saturated beyond; grey for NaN:
/// core's scale, the one the report's maps use.
pub fn colour(d: f32, tolerance: f64) -> [u8; 3] {
    asbuilt_core::colour::deviation_colour(f64::from(d), tolerance)
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
