//! A ROS 2 bag (`ros2 bag record`, MCAP or SQLite storage) as scans with poses: each
//! `sensor_msgs/PointCloud2` of the cloud topic is placed in the design's frame through the
//! bag's transform tree (`/tf_static`, `/tf`) at the cloud's stamp, and forms a station, or
//! several form one when the caller names time windows.
//!
//! Reading is two passes: the first reads every message once for the transforms and the clouds'
//! headers (the points stay in the file), the second streams a station's clouds. Memory holds
//! the transforms and one entry per cloud, never the points.

mod msgs;
pub mod sample;
mod storage;
#[cfg(test)]
mod tests;
mod tf;

use std::path::Path;

use asbuilt_protocol::{ScanPoint, ScanPointFlags};
use nalgebra::{Isometry3, Point3};
use serde::Deserialize;

pub use tf::{TfError, TfTree, interpolate};

use super::error::ScanError;
use super::{Batcher, PoseSource, ReadNotes, ScanInfo, Sink};
use storage::{Place, Storage};

const POINT_CLOUD2: &str = "sensor_msgs/msg/PointCloud2";
const TF_MESSAGE: &str = "tf2_msgs/msg/TFMessage";

/// How to read a bag: which clouds, in which frame, grouped how.
#[derive(Debug, Clone)]
pub struct Ros2Options {
    /// The `PointCloud2` topic; `None`: the bag's only one.
    pub cloud_topic: Option<String>,
    /// The design's frame in the transform tree.
    pub frame: String,
    /// The clouds each station is made of; `None`: every cloud is a station.
    pub stations: Option<Vec<StationWindow>>,
}

impl Default for Ros2Options {
    fn default() -> Self {
        Self {
            cloud_topic: None,
            frame: "world".into(),
            stations: None,
        }
    }
}

/// A station made of the clouds stamped from `from` to `to` (seconds of the bag's clock,
/// inclusive), for a sensor that publishes many small clouds.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StationWindow {
    /// The station's name in reports.
    pub id: String,
    /// The first stamp, seconds.
    pub from: f64,
    /// The last stamp, seconds.
    pub to: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct WindowsFile {
    station: Vec<StationWindow>,
}

/// Reads a bag's station windows: `[[station]]` tables with `id`, `from` and `to`.
pub fn load_windows(path: &Path) -> Result<Vec<StationWindow>, ScanError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| ScanError::Content(format!("cannot read {}: {e}", path.display())))?;
    let file: WindowsFile = toml::from_str(&text).map_err(|e| {
        ScanError::Content(format!(
            "{}: not a list of station windows ([[station]] with id, from and to, seconds): {e}",
            path.display()
        ))
    })?;
    if let Some(w) = file
        .station
        .iter()
        .find(|w| !(w.from <= w.to && w.from.is_finite() && w.to.is_finite()))
    {
        return Err(ScanError::Content(format!(
            "{}: station {} ends ({}) before it starts ({})",
            path.display(),
            w.id,
            w.to,
            w.from
        )));
    }
    Ok(file.station)
}

/// One cloud of the cloud topic: where it is, when, and where it was taken.
#[derive(Debug, Clone)]
struct Cloud {
    place: Place,
    stamp_ns: i64,
    frame_id: String,
    points: u64,
    /// `p_design = T · p_cloud`, or why the tree cannot say.
    pose: Result<Isometry3<f64>, String>,
}

/// A station: its name and clouds (indices into the bag's), the first the station's frame.
#[derive(Debug, Clone)]
struct BagStation {
    name: String,
    clouds: Vec<usize>,
}

/// A bag opened for its scans.
#[derive(Debug)]
pub struct Ros2Bag {
    storage: Storage,
    topic: String,
    frame: String,
    clouds: Vec<Cloud>,
    stations: Vec<BagStation>,
    transforms: usize,
    /// Clouds whose message could not be read, with why (the first few).
    unreadable: Vec<String>,
}

impl Ros2Bag {
    /// Reads the bag's transforms and its clouds' headers.
    pub fn open(path: &Path, options: &Ros2Options) -> Result<Self, ScanError> {
        let storage = Storage::open(path)?;
        let mut tree = TfTree::default();
        let mut clouds: std::collections::BTreeMap<String, Vec<Cloud>> = Default::default();
        let mut unreadable = Vec::new();
        storage.each(&mut |m| {
            match m.kind {
                POINT_CLOUD2 => match cloud_header(&m) {
                    Ok(c) => clouds.entry(m.topic.to_string()).or_default().push(c),
                    Err(e) => unreadable.push(format!(
                        "{} message logged at {:.3} s: {e}",
                        m.topic,
                        m.place.log_time as f64 * 1e-9
                    )),
                },
                TF_MESSAGE => {
                    let fixed = m.topic.ends_with("tf_static");
                    add_transforms(&mut tree, &m, fixed)?;
                }
                _ => {}
            }
            Ok(())
        })?;
        tree.finish();
        let topic = pick_topic(&clouds, options.cloud_topic.as_deref())?;
        let mut clouds = clouds.remove(&topic).unwrap_or_default();
        for c in &mut clouds {
            c.pose = tree
                .pose(&options.frame, &c.frame_id, c.stamp_ns)
                .map_err(|e| e.to_string());
        }
        let stations = group(&topic, &clouds, options.stations.as_deref());
        Ok(Self {
            storage,
            topic,
            frame: options.frame.clone(),
            clouds,
            stations,
            transforms: tree.len(),
            unreadable,
        })
    }

    /// What was found, for the log: the topic, its clouds, the stations and the transforms.
    pub fn describe(&self) -> String {
        let placed = self.clouds.iter().filter(|c| c.pose.is_ok()).count();
        let mut s = format!(
            "{} cloud(s) on {} ({} placed in {:?} by {} transform(s)), {} station(s)",
            self.clouds.len(),
            self.topic,
            placed,
            self.frame,
            self.transforms,
            self.stations.len()
        );
        if !self.unreadable.is_empty() {
            s += &format!(
                "; {} message(s) unreadable, the first: {}",
                self.unreadable.len(),
                self.unreadable[0]
            );
        }
        s
    }

    /// The stations as scans: name, points, and the pose of the station's first cloud.
    pub(crate) fn scans(&self) -> Vec<ScanInfo> {
        self.stations
            .iter()
            .enumerate()
            .map(|(index, st)| ScanInfo {
                index,
                name: st.name.clone(),
                points: Some(st.clouds.iter().map(|&c| self.clouds[c].points).sum()),
                pose: self.clouds[st.clouds[0]]
                    .pose
                    .as_ref()
                    .ok()
                    .map(|p| (*p, PoseSource::Ros2Tf)),
                offset: 0,
                first_line: 0,
            })
            .collect()
    }

    /// Why station `index` has no pose, when it has none.
    pub fn pose_error(&self, index: usize) -> Option<String> {
        let st = self.stations.get(index)?;
        let c = &self.clouds[st.clouds[0]];
        c.pose.as_ref().err().map(|e| {
            format!(
                "cloud at {:.3} s in frame {:?}: {e}",
                c.stamp_ns as f64 * 1e-9,
                c.frame_id
            )
        })
    }

    /// Streams station `index`'s points, each cloud's placed in the frame of the first.
    pub(crate) fn stream(
        &self,
        index: usize,
        chunk: usize,
        sink: &mut Sink,
    ) -> Result<ReadNotes, ScanError> {
        let st = &self.stations[index];
        let first = match &self.clouds[st.clouds[0]].pose {
            Ok(p) => *p,
            Err(_) => {
                return Err(ScanError::Content(
                    self.pose_error(index).expect("the pose failed"),
                ));
            }
        };
        // Each cloud in the station's frame; a cloud that cannot be placed is said and left
        // out. Each is read where the first pass found it, nothing before it.
        let mut notes = ReadNotes::default();
        let mut out = Batcher::new(chunk, sink);
        for &c in &st.clouds {
            let cloud = &self.clouds[c];
            let t = match &cloud.pose {
                Ok(p) => first.inverse() * p,
                Err(e) => {
                    eprintln!(
                        "warning: station {}: the cloud at {:.3} s is left out: {e}",
                        st.name,
                        cloud.stamp_ns as f64 * 1e-9
                    );
                    continue;
                }
            };
            let bytes = self.storage.read_at(cloud.place)?;
            let msg: msgs::PointCloud2 = msgs::decode(&bytes, "a PointCloud2")?;
            let layout = msg.layout().map_err(ScanError::Content)?;
            for (xyz, intensity) in msg.points(&layout) {
                let p = t * Point3::from(xyz);
                let mut sp = ScanPoint::new(p.x as f32, p.y as f32, p.z as f32);
                sp.intensity = intensity;
                if !xyz.iter().all(|v| v.is_finite()) {
                    sp.flags = ScanPointFlags(ScanPointFlags::INVALID);
                    notes.invalid += 1;
                }
                out.push(sp)?;
            }
        }
        out.finish()?;
        Ok(notes)
    }
}

/// A cloud's header: stamp, frame and size, its layout checked.
fn cloud_header(m: &storage::BagMessage<'_>) -> Result<Cloud, ScanError> {
    let c: msgs::PointCloud2 = msgs::decode(m.data, "a PointCloud2")?;
    let layout = c.layout().map_err(ScanError::Content)?;
    Ok(Cloud {
        place: m.place,
        stamp_ns: c.header.stamp.ns(),
        frame_id: c.header.frame_id,
        points: layout.points as u64,
        pose: Err("not placed yet".into()),
    })
}

/// Adds a TFMessage's transforms to the tree; a transform that is no pose is an error that
/// names it.
fn add_transforms(
    tree: &mut TfTree,
    m: &storage::BagMessage<'_>,
    fixed: bool,
) -> Result<(), ScanError> {
    let tf: msgs::TfMessage = msgs::decode(m.data, &format!("a TFMessage on {}", m.topic))?;
    for t in &tf.transforms {
        let pose = t
            .isometry()
            .map_err(|e| ScanError::Content(format!("{}: {e}", m.topic)))?;
        tree.add(
            &t.header.frame_id,
            &t.child_frame_id,
            t.header.stamp.ns(),
            pose,
            fixed,
        )
        .map_err(|e| ScanError::Content(format!("{}: {e}", m.topic)))?;
    }
    Ok(())
}

/// The cloud topic: the one asked for, else the bag's only one.
fn pick_topic(
    clouds: &std::collections::BTreeMap<String, Vec<Cloud>>,
    asked: Option<&str>,
) -> Result<String, ScanError> {
    let names: Vec<&str> = clouds.keys().map(String::as_str).collect();
    match asked {
        Some(t) if clouds.contains_key(t) => Ok(t.to_string()),
        Some(t) => Err(ScanError::Content(format!(
            "the bag has no PointCloud2 messages on {t}; its cloud topics: {names:?}"
        ))),
        None => match names.as_slice() {
            [one] => Ok(one.to_string()),
            [] => Err(ScanError::Content(
                "the bag holds no sensor_msgs/msg/PointCloud2 message".into(),
            )),
            _ => Err(ScanError::Content(format!(
                "the bag has several cloud topics, {names:?}: pick one with --cloud-topic"
            ))),
        },
    }
}

/// The stations: a cloud each, or the clouds of each window (a window with none is said).
fn group(topic: &str, clouds: &[Cloud], windows: Option<&[StationWindow]>) -> Vec<BagStation> {
    let tail = topic.rsplit('/').next().unwrap_or(topic);
    match windows {
        None => (0..clouds.len())
            .map(|i| BagStation {
                name: format!("{tail}-{:04}", i + 1),
                clouds: vec![i],
            })
            .collect(),
        Some(windows) => windows
            .iter()
            .filter_map(|w| {
                let (from, to) = ((w.from * 1e9).round() as i64, (w.to * 1e9).round() as i64);
                let clouds: Vec<usize> = (0..clouds.len())
                    .filter(|&i| (from..=to).contains(&clouds[i].stamp_ns))
                    .collect();
                if clouds.is_empty() {
                    eprintln!(
                        "warning: station {}: no cloud on {topic} is stamped from {} s to {} s",
                        w.id, w.from, w.to
                    );
                    return None;
                }
                Some(BagStation {
                    name: w.id.clone(),
                    clouds,
                })
            })
            .collect(),
    }
}
