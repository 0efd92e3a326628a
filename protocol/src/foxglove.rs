//! Foxglove's well-known schemas beside a recording's own channels, so that Foxglove opens an
//! asbuilt recording as it is and shows the part, the stations and the deviation-coloured
//! points. These channels repeat what the asbuilt channels say; nothing reads them back.
//!
//! | topic | schema | from |
//! | --- | --- | --- |
//! | [`TOPIC_DESIGN`] | `foxglove.SceneUpdate` | the design, once per file |
//! | [`TOPIC_STATIONS`] | `foxglove.FrameTransform` | each pose: [`DESIGN_FRAME`] → `station_<job>_<n>` |
//! | [`TOPIC_DEVIATIONS`] | `foxglove.PointCloud` | each deviation chunk: design frame, `x y z distance_mm` (f32) and `red green blue alpha` (u8) |
//! | [`json_topic`] of each channel the message table marks (`/foxglove/reports`, `findings`, `corrections`, `surface`) | JSON | each station report, findings, correction and surface judgement |
//! | [`TOPIC_SCANS`] (when asked for: `pack`) | `foxglove.PointCloud` | each scan chunk in its station's frame, `x y z intensity` (f32) |

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use foxglove::Encode;
use foxglove::messages::{
    Color, FrameTransform, PackedElementField, PointCloud, Pose, Quaternion, SceneEntity,
    SceneUpdate, Timestamp, TriangleListPrimitive, Vector3, packed_element_field::NumericType,
};

use crate::recording::{Channel, Recorded};
use crate::{DeviationFlags, DeviationHeader, PointDeviation, PoseSnapshot};

/// The design as a `foxglove.SceneUpdate` (one triangle list), once per recording.
pub const TOPIC_DESIGN: &str = "/foxglove/design";
/// Each station's scanner pose as a `foxglove.FrameTransform` from the design frame.
pub const TOPIC_STATIONS: &str = "/foxglove/stations";
/// Each deviation chunk as a `foxglove.PointCloud` coloured by signed distance.
pub const TOPIC_DEVIATIONS: &str = "/foxglove/deviations";
/// The topic of a channel's JSON copy: `/foxglove/` and the last part of its service
/// (`/foxglove/reports`), for the channels whose [`Channel::foxglove_json`] says so.
pub fn json_topic(channel: Channel) -> String {
    let service = channel.service();
    format!(
        "/foxglove/{}",
        service.rsplit('/').next().unwrap_or(service)
    )
}
/// Each scan chunk as a `foxglove.PointCloud` in its station's frame (`pack --foxglove`).
pub const TOPIC_SCANS: &str = "/foxglove/scans";
/// The frame every point and the design are in; stations hang from it.
pub const DESIGN_FRAME: &str = "design";
/// Bytes of one point in a [`TOPIC_DEVIATIONS`] cloud.
pub const POINT_STRIDE: u32 = 20;

/// A deviation's colour, metres to RGB (the viewer's scale lives with the geometry).
pub type Colour = Box<dyn Fn(f64) -> [u8; 3] + Send>;

/// The Foxglove channels of one file.
pub(crate) struct FoxgloveChannels {
    design: u16,
    stations: u16,
    deviations: u16,
    /// The JSON copies of the channels the message table marks.
    json: BTreeMap<Channel, u16>,
    /// Scan chunks too (a packed file has no deviations to show).
    scans: Option<u16>,
    colour: Colour,
    /// One point in this many of a chunk, if it matched, goes into the deviations' cloud.
    every: usize,
}

fn add<W: Write + Seek, E: Encode>(
    mcap: &mut mcap::Writer<W>,
    topic: &str,
) -> Result<u16, mcap::McapError> {
    let s = E::get_schema().expect("Foxglove's schemas are known");
    let schema = mcap.add_schema(&s.name, &s.encoding, &s.data)?;
    mcap.add_channel(schema, topic, &E::get_message_encoding(), &BTreeMap::new())
}

fn add_json<W: Write + Seek>(
    mcap: &mut mcap::Writer<W>,
    topic: &str,
    name: &str,
) -> Result<u16, mcap::McapError> {
    let schema = mcap.add_schema(name, "jsonschema", br#"{"type":"object"}"#)?;
    mcap.add_channel(schema, topic, "json", &BTreeMap::new())
}

impl FoxgloveChannels {
    pub(crate) fn add<W: Write + Seek>(
        mcap: &mut mcap::Writer<W>,
        colour: Colour,
    ) -> Result<Self, mcap::McapError> {
        Ok(Self {
            design: add::<_, SceneUpdate>(mcap, TOPIC_DESIGN)?,
            stations: add::<_, FrameTransform>(mcap, TOPIC_STATIONS)?,
            deviations: add::<_, PointCloud>(mcap, TOPIC_DEVIATIONS)?,
            json: Channel::ALL
                .into_iter()
                .filter(|c| c.foxglove_json())
                .map(|c| Ok((c, add_json(mcap, &json_topic(c), c.schema_name())?)))
                .collect::<Result<_, mcap::McapError>>()?,
            scans: None,
            colour,
            every: 1,
        })
    }

    /// Keeps one point in `every` of a chunk in the deviations' cloud, if it matched (at least
    /// 1: all).
    pub(crate) fn decimate(&mut self, every: usize) {
        self.every = every.max(1);
    }

    pub(crate) fn add_scans<W: Write + Seek>(
        &mut self,
        mcap: &mut mcap::Writer<W>,
    ) -> Result<(), mcap::McapError> {
        self.scans = Some(add::<_, PointCloud>(mcap, TOPIC_SCANS)?);
        Ok(())
    }

    pub(crate) fn design_channel(&self) -> u16 {
        self.design
    }

    /// The Foxglove message a recorded message also makes, with its channel; `None` for the
    /// messages Foxglove is not shown (scan chunks, events, status).
    pub(crate) fn message(&self, m: &Recorded) -> Option<(u16, Vec<u8>)> {
        match m {
            Recorded::Pose(p) => Some((self.stations, encode(&transform(p)))),
            Recorded::Deviations(h, points) => {
                Some(self.cloud(h, cloud_points(points, self.every)))
            }
            Recorded::Chunk(h, points) => self.scan(h, points),
            m => Some((*self.json.get(&m.channel())?, m.foxglove_json()?)),
        }
    }

    /// A scan chunk's cloud with its channel, when scan chunks are shown (`pack --foxglove`).
    pub(crate) fn scan(
        &self,
        h: &crate::ChunkHeader,
        points: &[crate::ScanPoint],
    ) -> Option<(u16, Vec<u8>)> {
        Some((
            self.scans?,
            encode(&scan_cloud(h.timestamp_ns, h.job, h.station, points)),
        ))
    }

    /// The deviations' cloud of `points` already selected, with its channel.
    pub(crate) fn cloud<'a>(
        &self,
        h: &DeviationHeader,
        points: impl Iterator<Item = &'a PointDeviation>,
    ) -> (u16, Vec<u8>) {
        let cloud = cloud(h.timestamp_ns, points, &self.colour);
        (self.deviations, encode(&cloud))
    }
}

fn encode<E: Encode>(m: &E) -> Vec<u8> {
    let mut buf = Vec::with_capacity(m.encoded_len().unwrap_or(256));
    m.encode(&mut buf)
        .expect("a growable buffer has room for any message");
    buf
}

fn timestamp(ns: u64) -> Timestamp {
    Timestamp::new(
        (ns / 1_000_000_000).min(u32::MAX as u64) as u32,
        (ns % 1_000_000_000) as u32,
    )
}

/// The frame of a station's scanner.
pub fn station_frame(job: u64, station: u32) -> String {
    format!("station_{job}_{station}")
}

fn transform(p: &PoseSnapshot) -> FrameTransform {
    let [x, y, z] = p.translation;
    let [qx, qy, qz, qw] = p.rotation_xyzw;
    FrameTransform {
        timestamp: Some(timestamp(p.timestamp_ns)),
        parent_frame_id: DESIGN_FRAME.into(),
        child_frame_id: station_frame(p.job, p.station),
        translation: Some(Vector3 { x, y, z }),
        rotation: Some(Quaternion {
            x: qx,
            y: qy,
            z: qz,
            w: qw,
        }),
    }
}

/// The points of a deviation chunk that its Foxglove cloud shows: one in `every` by their place
/// in the chunk (the first, then every `every`th), as the rerun view picks them, less those
/// without a match or rejected. The agent selects them on its event loop, before the chunk
/// leaves it, when only Foxglove's channel records deviations, so the rest are never copied;
/// picked by place, the others are never read either. Picking one in `every` of the matched
/// points instead read every point, and took the loop 1.9–2.5 ns a point of a chunk against
/// 1.1–1.6 (a timing loop over deviations just written by two threads, four runs each).
pub fn cloud_points(
    points: &[PointDeviation],
    every: usize,
) -> impl Iterator<Item = &PointDeviation> {
    points
        .iter()
        .step_by(every.max(1))
        .filter(|d| !d.flags.contains(DeviationFlags::REJECTED) && d.distance.is_finite())
}

/// `points`, as [`cloud_points`] selected them, in the design frame, coloured by their
/// deviation.
fn cloud<'a>(
    time_ns: u64,
    points: impl Iterator<Item = &'a PointDeviation>,
    colour: &Colour,
) -> PointCloud {
    let mut data = Vec::with_capacity(points.size_hint().0 * POINT_STRIDE as usize);
    for d in points {
        // The point's record whole, then one append instead of six; its last byte, alpha,
        // keeps the 255 it starts with.
        let mut record = [255u8; POINT_STRIDE as usize];
        for (at, v) in d.position.into_iter().enumerate() {
            record[4 * at..4 * at + 4].copy_from_slice(&(v as f32).to_le_bytes());
        }
        record[12..16].copy_from_slice(&((d.distance * 1e3) as f32).to_le_bytes());
        record[16..19].copy_from_slice(&colour(d.distance));
        data.extend_from_slice(&record);
    }
    PointCloud {
        timestamp: Some(timestamp(time_ns)),
        frame_id: DESIGN_FRAME.into(),
        pose: Some(identity()),
        point_stride: POINT_STRIDE,
        fields: vec![
            field("x", 0, NumericType::Float32),
            field("y", 4, NumericType::Float32),
            field("z", 8, NumericType::Float32),
            field("distance_mm", 12, NumericType::Float32),
            field("red", 16, NumericType::Uint8),
            field("green", 17, NumericType::Uint8),
            field("blue", 18, NumericType::Uint8),
            field("alpha", 19, NumericType::Uint8),
        ],
        data: data.into(),
    }
}

fn field(name: &str, offset: u32, t: NumericType) -> PackedElementField {
    PackedElementField {
        name: name.into(),
        offset,
        r#type: t as i32,
    }
}

/// A scan chunk's valid points in its station's frame (the scanner's), with their intensity.
fn scan_cloud(time_ns: u64, job: u64, station: u32, points: &[crate::ScanPoint]) -> PointCloud {
    let mut data = Vec::with_capacity(points.len() * 16);
    for p in points {
        if p.flags.is_invalid() || !p.xyz.iter().all(|v| v.is_finite()) {
            continue;
        }
        for v in p.xyz.iter().chain([&p.intensity]) {
            data.extend_from_slice(&v.to_le_bytes());
        }
    }
    PointCloud {
        timestamp: Some(timestamp(time_ns)),
        frame_id: station_frame(job, station),
        pose: Some(identity()),
        point_stride: 16,
        fields: vec![
            field("x", 0, NumericType::Float32),
            field("y", 4, NumericType::Float32),
            field("z", 8, NumericType::Float32),
            field("intensity", 12, NumericType::Float32),
        ],
        data: data.into(),
    }
}

fn identity() -> Pose {
    Pose {
        position: Some(Vector3 {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    }
}

/// The design as a grey triangle list in the design frame, metres.
pub(crate) fn design_scene(
    time_ns: u64,
    vertices: impl IntoIterator<Item = [f64; 3]>,
    triangles: &[[u32; 3]],
) -> Vec<u8> {
    let entity = SceneEntity {
        timestamp: Some(timestamp(time_ns)),
        frame_id: DESIGN_FRAME.into(),
        id: "design".into(),
        triangles: vec![TriangleListPrimitive {
            pose: Some(identity()),
            points: vertices
                .into_iter()
                .map(|[x, y, z]| foxglove::messages::Point3 { x, y, z })
                .collect(),
            color: Some(Color {
                r: 0.75,
                g: 0.75,
                b: 0.75,
                a: 0.6,
            }),
            colors: Vec::new(),
            indices: triangles.iter().flatten().copied().collect(),
        }],
        ..Default::default()
    };
    encode(&SceneUpdate {
        deletions: Vec::new(),
        entities: vec![entity],
    })
}
