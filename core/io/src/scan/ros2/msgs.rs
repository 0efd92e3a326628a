//! The ROS 2 messages a bag's scans are made of, as CDR gives them: `sensor_msgs/PointCloud2`
//! and `tf2_msgs/TFMessage`, decoded with `re_cdr` after the 4-byte encapsulation header that
//! says the byte order.

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use crate::scan::error::ScanError;

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
pub(super) struct Time {
    pub(super) sec: i32,
    pub(super) nanosec: u32,
}

impl Time {
    /// Nanoseconds of the ROS clock.
    pub(super) fn ns(self) -> i64 {
        self.sec as i64 * 1_000_000_000 + self.nanosec as i64
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, Deserialize, Serialize)]
pub(super) struct Header {
    pub(super) stamp: Time,
    pub(super) frame_id: String,
}

/// `sensor_msgs/PointField`.
#[derive(Debug, Clone, Deserialize, Serialize)]
pub(super) struct PointField {
    pub(super) name: String,
    pub(super) offset: u32,
    pub(super) datatype: u8,
    pub(super) count: u32,
}

/// `sensor_msgs/PointCloud2`, its data borrowed from the record.
#[derive(Debug, Deserialize, Serialize)]
pub(super) struct PointCloud2<'a> {
    pub(super) header: Header,
    pub(super) height: u32,
    pub(super) width: u32,
    pub(super) fields: Vec<PointField>,
    pub(super) is_bigendian: bool,
    pub(super) point_step: u32,
    pub(super) row_step: u32,
    #[serde(borrow)]
    pub(super) data: &'a [u8],
    pub(super) is_dense: bool,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
pub(super) struct Vector3 {
    pub(super) x: f64,
    pub(super) y: f64,
    pub(super) z: f64,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
pub(super) struct QuaternionMsg {
    pub(super) x: f64,
    pub(super) y: f64,
    pub(super) z: f64,
    pub(super) w: f64,
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize)]
pub(super) struct Transform {
    pub(super) translation: Vector3,
    pub(super) rotation: QuaternionMsg,
}

/// `geometry_msgs/TransformStamped`: `parent ← child` at a time.
#[derive(Debug, Clone, Deserialize, Serialize)]
pub(super) struct TransformStamped {
    pub(super) header: Header,
    pub(super) child_frame_id: String,
    pub(super) transform: Transform,
}

impl TransformStamped {
    /// `p_parent = T · p_child`, or why not: a rotation that is no unit quaternion.
    pub(super) fn isometry(&self) -> Result<Isometry3<f64>, String> {
        let t = self.transform.translation;
        let q = self.transform.rotation;
        let norm = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
        if ![t.x, t.y, t.z].iter().all(|v| v.is_finite())
            || (norm - 1.0).abs() >= 1e-3
            || norm.is_nan()
        {
            return Err(format!(
                "transform {} → {} is not a pose (translation {:?}, quaternion norm {norm})",
                self.header.frame_id,
                self.child_frame_id,
                [t.x, t.y, t.z]
            ));
        }
        Ok(Isometry3::from_parts(
            Translation3::new(t.x, t.y, t.z),
            UnitQuaternion::new_normalize(Quaternion::new(q.w, q.x, q.y, q.z)),
        ))
    }
}

/// `tf2_msgs/TFMessage`.
#[derive(Debug, Deserialize, Serialize)]
pub(super) struct TfMessage {
    pub(super) transforms: Vec<TransformStamped>,
}

/// A CDR record of `what` into its message: the encapsulation header (CDR, big or little
/// endian), then the message.
pub(super) fn decode<'a, T: Deserialize<'a>>(bytes: &'a [u8], what: &str) -> Result<T, ScanError> {
    let bad = |why: String| ScanError::Content(format!("{what}: {why}"));
    if bytes.len() < 4 {
        return Err(bad(format!(
            "{} bytes, too short for a CDR record",
            bytes.len()
        )));
    }
    let body = &bytes[4..];
    let decoded = match bytes[1] {
        0 => re_cdr::from_bytes::<T, re_cdr::BigEndian>(body),
        1 => re_cdr::from_bytes::<T, re_cdr::LittleEndian>(body),
        k => {
            return Err(bad(format!(
                "encapsulation kind {k} is not plain CDR (0 big endian, 1 little endian)"
            )));
        }
    };
    decoded
        .map(|(m, _)| m)
        .map_err(|e| bad(format!("not a valid message ({e})")))
}

/// Where a value sits in a point and how to read it.
#[derive(Debug, Clone, Copy)]
struct Field {
    offset: usize,
    /// `sensor_msgs/PointField`'s data type: 1 int8, 2 uint8, 3 int16, 4 uint16, 5 int32,
    /// 6 uint32, 7 float32, 8 float64.
    datatype: u8,
}

/// The sizes of the data types, by number.
const SIZES: [usize; 9] = [0, 1, 1, 2, 2, 4, 4, 4, 8];
const FLOAT32: u8 = 7;
const FLOAT64: u8 = 8;

impl Field {
    fn size(self) -> usize {
        SIZES[self.datatype as usize]
    }

    /// The value in `point` (checked to hold it) as f64.
    #[inline]
    fn read(self, point: &[u8], big: bool) -> f64 {
        let b = &point[self.offset..self.offset + self.size()];
        macro_rules! num {
            ($t:ty, $n:literal) => {{
                let a: [u8; $n] = b.try_into().expect("sized above");
                (if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }) as f64
            }};
        }
        match self.datatype {
            1 => b[0] as i8 as f64,
            2 => b[0] as f64,
            3 => num!(i16, 2),
            4 => num!(u16, 2),
            5 => num!(i32, 4),
            6 => num!(u32, 4),
            FLOAT32 => num!(f32, 4),
            _ => num!(f64, 8),
        }
    }
}

/// How to read a cloud's points: x, y and z (float32 or float64), an optional intensity.
#[derive(Debug, Clone, Copy)]
pub(super) struct Layout {
    xyz: [Field; 3],
    intensity: Option<Field>,
    step: usize,
    big: bool,
    /// Points the data holds.
    pub(super) points: usize,
}

impl PointCloud2<'_> {
    /// The cloud's layout, checked against its data, or what is wrong with it.
    pub(super) fn layout(&self) -> Result<Layout, String> {
        let find = |name: &str| self.fields.iter().find(|f| f.name == name);
        let field = |f: &PointField| -> Result<Field, String> {
            if !(1..=FLOAT64).contains(&f.datatype) || f.count == 0 {
                return Err(format!(
                    "field {} has datatype {} and count {}",
                    f.name, f.datatype, f.count
                ));
            }
            Ok(Field {
                offset: f.offset as usize,
                datatype: f.datatype,
            })
        };
        let mut xyz = [Field {
            offset: 0,
            datatype: FLOAT32,
        }; 3];
        for (k, name) in ["x", "y", "z"].iter().enumerate() {
            let f = find(name).ok_or_else(|| {
                let names: Vec<&str> = self.fields.iter().map(|f| f.name.as_str()).collect();
                format!("the cloud has no {name} field (its fields: {names:?})")
            })?;
            if f.datatype != FLOAT32 && f.datatype != FLOAT64 {
                return Err(format!(
                    "field {name} is of datatype {}; x, y and z must be float32 or float64",
                    f.datatype
                ));
            }
            xyz[k] = field(f)?;
        }
        let intensity = find("intensity").map(field).transpose()?;
        let step = self.point_step as usize;
        for f in xyz.iter().chain(intensity.iter()) {
            if f.offset + f.size() > step {
                return Err(format!(
                    "a field at offset {} runs past the point step {step}",
                    f.offset
                ));
            }
        }
        let points = self.width as u64 * self.height as u64;
        let rows_fit = self.row_step as u64 >= self.width as u64 * step as u64;
        let needed = if self.height > 0 {
            self.row_step as u64 * (self.height as u64 - 1) + self.width as u64 * step as u64
        } else {
            0
        };
        if !rows_fit || (self.data.len() as u64) < needed {
            return Err(format!(
                "{} × {} points of {step} bytes (rows of {}) do not fit its {} bytes of data",
                self.height,
                self.width,
                self.row_step,
                self.data.len()
            ));
        }
        Ok(Layout {
            xyz,
            intensity,
            step,
            big: self.is_bigendian,
            points: points as usize,
        })
    }

    /// Each point's x, y, z and intensity (0 without one), row by row.
    pub(super) fn points(&self, layout: &Layout) -> impl Iterator<Item = ([f64; 3], f32)> + '_ {
        let l = *layout;
        let (width, row_step) = (self.width as usize, self.row_step as usize);
        (0..self.height as usize).flat_map(move |row| {
            let row = &self.data[row * row_step..];
            (0..width).map(move |i| {
                let p = &row[i * l.step..(i + 1) * l.step];
                let xyz = [
                    l.xyz[0].read(p, l.big),
                    l.xyz[1].read(p, l.big),
                    l.xyz[2].read(p, l.big),
                ];
                let intensity = l.intensity.map_or(0.0, |f| f.read(p, l.big) as f32);
                (xyz, intensity)
            })
        })
    }
}
