//! Small bags written the way rosbag2 writes them, for tests and the fuzzer's seeds: the same
//! CDR messages, in MCAP (with its schemas) or in rosbag2's SQLite tables. Real bags come from
//! `ros2 bag record`; the tests check this reader against an independent writer too
//! (`rosbags`, in the Python tests).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Isometry3;

use super::msgs::{
    Header, PointCloud2, PointField, QuaternionMsg, TfMessage, Time, Transform, TransformStamped,
    Vector3,
};
use super::{POINT_CLOUD2, TF_MESSAGE};

/// A cloud of a sample bag.
#[derive(Debug, Clone)]
pub struct SampleCloud {
    /// Its stamp, seconds.
    pub stamp: f64,
    /// Its frame.
    pub frame: String,
    /// Its points in that frame.
    pub points: Vec<[f64; 3]>,
    /// x, y, z as float64 (after an intensity) instead of float32.
    pub float64: bool,
    /// The data big endian.
    pub big_endian: bool,
}

/// A transform of a sample bag: `p_parent = pose · p_child` at `stamp` (seconds).
#[derive(Debug, Clone)]
pub struct SampleTransform {
    /// Its stamp, seconds.
    pub stamp: f64,
    /// The parent frame.
    pub parent: String,
    /// The child frame.
    pub child: String,
    /// The pose.
    pub pose: Isometry3<f64>,
    /// On `/tf_static` instead of `/tf`.
    pub fixed: bool,
}

fn time(t: f64) -> Time {
    let ns = (t * 1e9).round() as i64;
    Time {
        sec: ns.div_euclid(1_000_000_000) as i32,
        nanosec: ns.rem_euclid(1_000_000_000) as u32,
    }
}

/// A record: the CDR little-endian encapsulation header, then the message.
fn cdr<T: serde::Serialize>(m: &T) -> Vec<u8> {
    let mut out = vec![0, 1, 0, 0];
    out.extend(re_cdr::to_vec::<_, re_cdr::LittleEndian>(m).expect("a sample message encodes"));
    out
}

fn cloud_record(c: &SampleCloud) -> Vec<u8> {
    // (name, offset, datatype): float64 x, y, z after an intensity, or float32 x, y, z, intensity.
    let (layout, step): (&[(&str, u32, u8)], usize) = if c.float64 {
        (
            &[("intensity", 0, 7), ("x", 8, 8), ("y", 16, 8), ("z", 24, 8)],
            32,
        )
    } else {
        (
            &[("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7)],
            16,
        )
    };
    let fields = layout
        .iter()
        .map(|&(name, offset, datatype)| PointField {
            name: name.into(),
            offset,
            datatype,
            count: 1,
        })
        .collect();
    let mut data = Vec::with_capacity(c.points.len() * step);
    for (k, p) in c.points.iter().enumerate() {
        let put32 = |d: &mut Vec<u8>, v: f32| {
            d.extend(if c.big_endian {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            })
        };
        let put64 = |d: &mut Vec<u8>, v: f64| {
            d.extend(if c.big_endian {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            })
        };
        if c.float64 {
            put32(&mut data, k as f32);
            put32(&mut data, 0.0);
            p.iter().for_each(|&v| put64(&mut data, v));
        } else {
            p.iter().for_each(|&v| put32(&mut data, v as f32));
            put32(&mut data, k as f32);
        }
    }
    cdr(&PointCloud2 {
        header: Header {
            stamp: time(c.stamp),
            frame_id: c.frame.clone(),
        },
        height: 1,
        width: c.points.len() as u32,
        fields,
        is_bigendian: c.big_endian,
        point_step: step as u32,
        row_step: (step * c.points.len()) as u32,
        data: &data,
        is_dense: true,
    })
}

fn tf_record(t: &SampleTransform) -> Vec<u8> {
    let v = t.pose.translation.vector;
    let q = t.pose.rotation.coords;
    cdr(&TfMessage {
        transforms: vec![TransformStamped {
            header: Header {
                stamp: time(t.stamp),
                frame_id: t.parent.clone(),
            },
            child_frame_id: t.child.clone(),
            transform: Transform {
                translation: Vector3 {
                    x: v.x,
                    y: v.y,
                    z: v.z,
                },
                rotation: QuaternionMsg {
                    x: q.x,
                    y: q.y,
                    z: q.z,
                    w: q.w,
                },
            },
        }],
    })
}

/// Every message of the bag in recording order: (time ns, topic, type, record).
fn messages(
    topic: &str,
    clouds: &[SampleCloud],
    tf: &[SampleTransform],
) -> Vec<(u64, String, &'static str, Vec<u8>)> {
    let ns = |t: f64| (t * 1e9).round() as u64;
    let mut out: Vec<_> = tf
        .iter()
        .map(|t| {
            let topic = if t.fixed { "/tf_static" } else { "/tf" };
            (ns(t.stamp), topic.to_string(), TF_MESSAGE, tf_record(t))
        })
        .chain(clouds.iter().map(|c| {
            (
                ns(c.stamp),
                topic.to_string(),
                POINT_CLOUD2,
                cloud_record(c),
            )
        }))
        .collect();
    out.sort_by_key(|m| m.0);
    out
}

/// Writes the bag as one MCAP file, as rosbag2's MCAP storage does.
pub fn write_mcap(
    path: &Path,
    topic: &str,
    clouds: &[SampleCloud],
    tf: &[SampleTransform],
) -> std::io::Result<()> {
    let io = |e: mcap::McapError| std::io::Error::other(e.to_string());
    let mut w =
        mcap::Writer::new(std::io::BufWriter::new(std::fs::File::create(path)?)).map_err(io)?;
    let mut channels: BTreeMap<String, u16> = BTreeMap::new();
    for (t, name, kind, data) in messages(topic, clouds, tf) {
        let id = match channels.get(&name) {
            Some(&id) => id,
            None => {
                let schema = w.add_schema(kind, "ros2msg", b"").map_err(io)?;
                let id = w
                    .add_channel(schema, &name, "cdr", &BTreeMap::new())
                    .map_err(io)?;
                channels.insert(name.clone(), id);
                id
            }
        };
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: 0,
            log_time: t,
            publish_time: t,
        };
        w.write_to_known_channel(&header, &data).map_err(io)?;
    }
    w.finish().map_err(io)?;
    Ok(())
}

/// Writes the bag as one SQLite file, in rosbag2's tables.
pub fn write_sqlite(
    path: &Path,
    topic: &str,
    clouds: &[SampleCloud],
    tf: &[SampleTransform],
) -> std::io::Result<()> {
    let io = |e: rusqlite::Error| std::io::Error::other(e.to_string());
    let db = rusqlite::Connection::open(path).map_err(io)?;
    db.execute_batch(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, \
         serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
         CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, \
         timestamp INTEGER NOT NULL, data BLOB NOT NULL);",
    )
    .map_err(io)?;
    let mut ids: BTreeMap<String, i64> = BTreeMap::new();
    for (t, name, kind, data) in messages(topic, clouds, tf) {
        let id = match ids.get(&name) {
            Some(&id) => id,
            None => {
                let id = ids.len() as i64 + 1;
                db.execute(
                    "INSERT INTO topics VALUES (?1, ?2, ?3, 'cdr', '')",
                    rusqlite::params![id, name, kind],
                )
                .map_err(io)?;
                ids.insert(name.clone(), id);
                id
            }
        };
        db.execute(
            "INSERT INTO messages(topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
            rusqlite::params![id, t as i64, data],
        )
        .map_err(io)?;
    }
    Ok(())
}
