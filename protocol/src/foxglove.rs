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
//! | [`TOPIC_BASE`] | `foxglove.FrameTransform` | the robot's base in the design frame (`T_design_base`), once per file, when the writer is told it |
//! | [`TOPIC_MOUNT_POSES`] | `foxglove.FrameTransforms` | each mount pose of a line profiler, on the robot's clock: [`BASE_FRAME`] → `profiler_mount_<job>` → `profiler_<job>` (its `T_mount_sensor`) |
//! | [`TOPIC_PROFILES`] | `foxglove.PointCloud` | each profile chunk's last profile in `profiler_<job>`, at its time on the robot's clock (the sensor's plus the clock offset the writer is told), `x y z` (f32, y = 0: the laser's plane) |
//!
//! Foxglove places a profile by the mount's transforms around its time, as the agent does; one
//! profile a chunk (1 in 32) keeps the channel light, the asbuilt channels keep every one.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use foxglove::Encode;
use foxglove::messages::{
    Color, FrameTransform, FrameTransforms, PackedElementField, PointCloud, Pose, Quaternion,
    SceneEntity, SceneUpdate, Timestamp, TriangleListPrimitive, Vector3,
    packed_element_field::NumericType,
};

use crate::recording::{Channel, Recorded};
use crate::{
    DeviationFlags, DeviationHeader, MountPose, PointDeviation, PoseSnapshot, ProfilePoint,
};

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
/// The robot's base in the design frame, once per file.
pub const TOPIC_BASE: &str = "/foxglove/robot_base";
/// Each mount pose of a line profiler as the base → mount → sensor transforms.
pub const TOPIC_MOUNT_POSES: &str = "/foxglove/mount_poses";
/// Each profile chunk's last profile in its profiler's frame.
pub const TOPIC_PROFILES: &str = "/foxglove/profiles";
/// The robot's base frame, which mount poses are in.
pub const BASE_FRAME: &str = "robot_base";
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
    base: u16,
    mount_poses: u16,
    profiles: u16,
    /// The robot's clock less the profiler's, ns: a profile's time on the robot's clock.
    clock_offset_ns: i64,
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
            base: add::<_, FrameTransform>(mcap, TOPIC_BASE)?,
            mount_poses: add::<_, FrameTransforms>(mcap, TOPIC_MOUNT_POSES)?,
            profiles: add::<_, PointCloud>(mcap, TOPIC_PROFILES)?,
            clock_offset_ns: 0,
        })
    }

    /// The profiler's clock offset (the robot's clock less the sensor's, ns).
    pub(crate) fn set_clock_offset(&mut self, ns: i64) {
        self.clock_offset_ns = ns;
    }

    pub(crate) fn base_channel(&self) -> u16 {
        self.base
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
            Recorded::MountPose(p) => Some((self.mount_poses, encode(&mount_transforms(p)))),
            Recorded::Profiles(h, points) => {
                let (ns, range) = h.profiles(points.len()).ok()?.last()?;
                let time = i128::from(ns) + i128::from(self.clock_offset_ns);
                let time = u64::try_from(time.max(0)).unwrap_or(u64::MAX);
                let cloud = profile_cloud(time, h.job, &points[range]);
                Some((self.profiles, encode(&cloud)))
            }
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

/// A line profiler's mount frame and its sensor's.
pub fn profiler_frames(job: u64) -> (String, String) {
    (format!("profiler_mount_{job}"), format!("profiler_{job}"))
}

fn frame_transform(
    time_ns: u64,
    (parent, child): (&str, &str),
    [x, y, z]: [f64; 3],
    [qx, qy, qz, qw]: [f64; 4],
) -> FrameTransform {
    FrameTransform {
        timestamp: Some(timestamp(time_ns)),
        parent_frame_id: parent.into(),
        child_frame_id: child.into(),
        translation: Some(Vector3 { x, y, z }),
        rotation: Some(Quaternion {
            x: qx,
            y: qy,
            z: qz,
            w: qw,
        }),
    }
}

/// A mount pose: the mount in the robot's base, the sensor on the mount.
fn mount_transforms(m: &MountPose) -> FrameTransforms {
    let (mount, sensor) = profiler_frames(m.job);
    FrameTransforms {
        transforms: vec![
            frame_transform(
                m.time_ns,
                (BASE_FRAME, &mount),
                m.translation,
                m.rotation_xyzw,
            ),
            frame_transform(
                m.time_ns,
                (&mount, &sensor),
                m.mount_sensor_translation,
                m.mount_sensor_rotation_xyzw,
            ),
        ],
    }
}

/// The robot's base in the design frame (`T_design_base`: translation, quaternion xyzw).
pub(crate) fn base_transform(time_ns: u64, translation: [f64; 3], rotation: [f64; 4]) -> Vec<u8> {
    encode(&frame_transform(
        time_ns,
        (DESIGN_FRAME, BASE_FRAME),
        translation,
        rotation,
    ))
}

/// One profile's points in its profiler's frame: x along the line, z along the view.
fn profile_cloud(time_ns: u64, job: u64, points: &[ProfilePoint]) -> PointCloud {
    let mut data = Vec::with_capacity(points.len() * 12);
    for p in points.iter().filter(|p| p.x.is_finite() && p.z.is_finite()) {
        for v in [p.x, 0.0, p.z] {
            data.extend_from_slice(&v.to_le_bytes());
        }
    }
    f32_cloud(time_ns, profiler_frames(job).1, &["x", "y", "z"], data)
}

fn transform(p: &PoseSnapshot) -> FrameTransform {
    frame_transform(
        p.timestamp_ns,
        (DESIGN_FRAME, &station_frame(p.job, p.station)),
        p.translation,
        p.rotation_xyzw,
    )
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
    f32_cloud(
        time_ns,
        station_frame(job, station),
        &["x", "y", "z", "intensity"],
        data,
    )
}

/// A cloud in `frame_id` whose points are the f32 `fields`, in order, in `data`.
fn f32_cloud(time_ns: u64, frame_id: String, fields: &[&str], data: Vec<u8>) -> PointCloud {
    PointCloud {
        timestamp: Some(timestamp(time_ns)),
        frame_id,
        pose: Some(identity()),
        point_stride: 4 * fields.len() as u32,
        fields: (0..)
            .zip(fields)
            .map(|(i, name)| field(name, 4 * i, NumericType::Float32))
            .collect(),
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

#[cfg(test)]
mod tests {
    use foxglove::Decode;

    use super::*;
    use crate::recording::RecordingWriter;

    /// A mount pose and a chunk of two profiles, with the sensor's clock 5 ms behind the
    /// robot's: the pose's two transforms, and the chunk's last profile in the profiler's frame
    /// at its time on the robot's clock.
    #[test]
    fn a_profilers_poses_and_profiles_reach_foxglove_in_its_frames() {
        let mut w = RecordingWriter::new(std::io::Cursor::new(Vec::new()))
            .unwrap()
            .with_foxglove(Box::new(|_| [0, 0, 0]))
            .unwrap()
            .foxglove_clock_offset(5_000_000);
        w.foxglove_base(1, [1.0, 2.0, 0.0], [0.0, 0.0, 0.0, 1.0])
            .unwrap();
        let mut m = MountPose::new(7, 3, 0, 2_000_000_000);
        m.translation = [0.5, 0.0, 0.6];
        m.mount_sensor_translation = [0.0, -0.06, 0.0];
        w.write(2, &Recorded::MountPose(m)).unwrap();
        let mut h = crate::ProfileHeader::new(7, 3, 0);
        h.push(1_995_000_000, 2);
        h.push(1_995_500_000, 3);
        let p = |x: f32, z: f32| ProfilePoint { x, z };
        let points = vec![
            p(0.0, 0.1),
            p(0.1, 0.1),
            p(-0.01, 0.1),
            p(f32::NAN, f32::NAN),
            p(0.01, 0.11),
        ];
        w.write(3, &Recorded::Profiles(Box::new(h), points))
            .unwrap();
        let bytes = w.finish().unwrap().into_inner();
        let mut seen = 0;
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            match m.channel.topic.as_str() {
                TOPIC_BASE => {
                    let t = FrameTransform::decode(&m.data[..]).unwrap();
                    assert_eq!(
                        (t.parent_frame_id.as_str(), t.child_frame_id.as_str()),
                        (DESIGN_FRAME, BASE_FRAME)
                    );
                    assert_eq!(t.translation.unwrap().x, 1.0);
                    seen += 1;
                }
                TOPIC_MOUNT_POSES => {
                    let t = FrameTransforms::decode(&m.data[..]).unwrap().transforms;
                    let frames: Vec<(&str, &str)> = t
                        .iter()
                        .map(|t| (t.parent_frame_id.as_str(), t.child_frame_id.as_str()))
                        .collect();
                    assert_eq!(
                        frames,
                        [
                            (BASE_FRAME, "profiler_mount_7"),
                            ("profiler_mount_7", "profiler_7")
                        ]
                    );
                    assert_eq!(t[0].translation.unwrap().z, 0.6);
                    assert_eq!(t[1].translation.unwrap().y, -0.06);
                    assert_eq!(t[0].timestamp, Some(timestamp(2_000_000_000)));
                    seen += 1;
                }
                TOPIC_PROFILES => {
                    let c = PointCloud::decode(&m.data[..]).unwrap();
                    assert_eq!(c.frame_id, "profiler_7");
                    // 1.9955 s on the sensor's clock is 2.0005 s on the robot's.
                    assert_eq!(c.timestamp, Some(timestamp(2_000_500_000)));
                    let xyz: Vec<f32> = c
                        .data
                        .chunks(4)
                        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
                        .collect();
                    // The last profile's returns; its no-return is left out.
                    assert_eq!(xyz, [-0.01, 0.0, 0.1, 0.01, 0.0, 0.11]);
                    seen += 1;
                }
                _ => {}
            }
        }
        assert_eq!(seen, 3);
    }
}
