//! Writing point clouds: PTX and E57 keep each scan in its own frame with its pose; LAS, PLY and
//! ASCII hold points in the file's frame (the pose applied), at f64. PLY and ASCII carry
//! `intensity` and `scan` as scalar fields that CloudCompare shows. Writers stream: a scan is fed
//! chunk by chunk and never held whole.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::error::{Context, Result, ScanError, SinkError, bail};
use asbuilt_protocol::ScanPoint;
use nalgebra::{Isometry3, Point3};

use super::{Format, Sink};
use crate::ply::{PlyWriter, Property, Scalar, point_columns};

/// A scan to write: its name, pose (`p_file = pose · p_scan`) and point count.
#[derive(Debug, Clone)]
pub struct OutScan {
    /// The scan's name, where the format keeps one.
    pub name: String,
    /// `p_file = pose · p_scan`.
    pub pose: Isometry3<f64>,
    /// Points that will be fed, invalid ones included (PTX headers and PLY counts need it).
    pub points: u64,
}

/// Calls its argument with every chunk of the scan.
pub type Feed<'f> = &'f mut dyn FnMut(&mut Sink) -> Result<(), SinkError>;

/// A scan file being written, scan after scan.
pub trait CloudWriter {
    /// Writes one scan; returns the points written (formats without an invalid flag leave
    /// invalid points out).
    fn write_scan(&mut self, scan: &OutScan, feed: Feed) -> Result<u64>;
    /// Ends the file (counts, footers) and flushes it.
    fn finish(self: Box<Self>) -> Result<()>;
}

/// A writer for `path`'s format. `total` is the number of points all scans will feed.
pub fn create(path: &Path, total: u64) -> Result<Box<dyn CloudWriter>> {
    let file = |p: &Path| -> Result<BufWriter<File>> {
        Ok(BufWriter::with_capacity(
            1 << 20,
            File::create(p).with_context(|| format!("cannot write {}", p.display()))?,
        ))
    };
    Ok(match Format::from_path(path)? {
        Format::Ptx => Box::new(Ptx { out: file(path)? }),
        Format::Xyz => {
            let mut out = file(path)?;
            writeln!(out, "//X Y Z Intensity Scan")?;
            Box::new(Ascii { out, scan: 0 })
        }
        Format::Ply => Box::new(Ply::new(path, total)?),
        Format::Las => Box::new(Las {
            path: path.to_path_buf(),
            writer: None,
        }),
        Format::E57 => Box::new(E57 {
            writer: e57::E57Writer::from_file(path, &guid(path, "file"))
                .map_err(|e| ScanError::Content(format!("cannot write {}: {e}", path.display())))?,
            scans: 0,
            path: path.to_path_buf(),
        }),
        // Never from an extension: nothing to write.
        Format::Ros2 => {
            return Err(ScanError::Content(
                "asbuilt does not write ROS 2 bags; convert to .e57, .las, .ptx, .ply or .xyz"
                    .into(),
            ));
        }
    })
}

fn guid(path: &Path, what: &str) -> String {
    format!(
        "asbuilt-{}-{what}-{}",
        path.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        asbuilt_protocol::unix_time_ns()
    )
}

fn world(pose: &Isometry3<f64>, p: &ScanPoint) -> Point3<f64> {
    pose * Point3::new(p.xyz[0] as f64, p.xyz[1] as f64, p.xyz[2] as f64)
}

struct Ptx {
    out: BufWriter<File>,
}

impl CloudWriter for Ptx {
    fn write_scan(&mut self, scan: &OutScan, feed: Feed) -> Result<u64> {
        let r = scan.pose.rotation.to_rotation_matrix();
        let t = scan.pose.translation.vector;
        let o = &mut self.out;
        // An unorganised scan: one row of all its points.
        writeln!(o, "{}\n1", scan.points)?;
        writeln!(o, "{} {} {}", t.x, t.y, t.z)?;
        for k in 0..3 {
            let axis = r.matrix().column(k);
            writeln!(o, "{} {} {}", axis[0], axis[1], axis[2])?;
        }
        for k in 0..3 {
            let axis = r.matrix().column(k);
            writeln!(o, "{} {} {} 0", axis[0], axis[1], axis[2])?;
        }
        writeln!(o, "{} {} {} 1", t.x, t.y, t.z)?;
        let mut n = 0u64;
        feed(&mut |chunk| {
            for p in chunk {
                if p.flags.is_invalid() {
                    writeln!(o, "0 0 0 {}", p.intensity)?;
                } else {
                    writeln!(o, "{} {} {} {}", p.xyz[0], p.xyz[1], p.xyz[2], p.intensity)?;
                }
            }
            n += chunk.len() as u64;
            Ok(())
        })?;
        if n != scan.points {
            bail!(
                "PTX scan {}: header says {} points, {n} were fed",
                scan.name,
                scan.points
            );
        }
        Ok(n)
    }

    fn finish(mut self: Box<Self>) -> Result<()> {
        self.out.flush()?;
        Ok(())
    }
}

struct Ascii {
    out: BufWriter<File>,
    scan: u32,
}

impl CloudWriter for Ascii {
    fn write_scan(&mut self, scan: &OutScan, feed: Feed) -> Result<u64> {
        let (o, k) = (&mut self.out, self.scan);
        let mut n = 0u64;
        feed(&mut |chunk| {
            for p in chunk.iter().filter(|p| !p.flags.is_invalid()) {
                let w = world(&scan.pose, p);
                writeln!(o, "{:.6} {:.6} {:.6} {} {k}", w.x, w.y, w.z, p.intensity)?;
                n += 1;
            }
            Ok(())
        })?;
        self.scan += 1;
        Ok(n)
    }

    fn finish(mut self: Box<Self>) -> Result<()> {
        self.out.flush()?;
        Ok(())
    }
}

/// Binary PLY: x y z double, intensity float, scan ushort. The header's count is the total
/// announced; invalid points are written at NaN so the count holds.
struct Ply {
    out: PlyWriter,
    scan: u16,
}

/// The columns after the point's.
const PLY_MEASUREMENT: [Property; 2] = [
    Property::new("intensity", Scalar::F32),
    Property::new("scan", Scalar::U16),
];

impl Ply {
    fn new(path: &Path, total: u64) -> Result<Self> {
        let out = PlyWriter::create(
            path,
            "asbuilt point cloud, metres; NaN coordinates mark points the scanner flagged invalid",
            &point_columns(&PLY_MEASUREMENT),
            Some(total),
        )?;
        Ok(Self { out, scan: 0 })
    }
}

impl CloudWriter for Ply {
    fn write_scan(&mut self, scan: &OutScan, feed: Feed) -> Result<u64> {
        let (o, k) = (&mut self.out, self.scan);
        let mut n = 0u64;
        feed(&mut |chunk| {
            for p in chunk {
                let w = if p.flags.is_invalid() {
                    Point3::from([f64::NAN; 3])
                } else {
                    world(&scan.pose, p)
                };
                let mut rec = [0u8; 30];
                rec[0..8].copy_from_slice(&w.x.to_le_bytes());
                rec[8..16].copy_from_slice(&w.y.to_le_bytes());
                rec[16..24].copy_from_slice(&w.z.to_le_bytes());
                rec[24..28].copy_from_slice(&p.intensity.to_le_bytes());
                rec[28..30].copy_from_slice(&k.to_le_bytes());
                o.record(&rec)?;
            }
            n += chunk.len() as u64;
            Ok(())
        })?;
        self.scan = self.scan.saturating_add(1);
        Ok(n)
    }

    fn finish(self: Box<Self>) -> Result<()> {
        self.out.finish()?;
        Ok(())
    }
}

struct Las {
    path: PathBuf,
    writer: Option<las::Writer<BufWriter<File>>>,
}

impl CloudWriter for Las {
    fn write_scan(&mut self, scan: &OutScan, feed: Feed) -> Result<u64> {
        if self.writer.is_none() {
            let mut b = las::Builder::from((1, 4));
            b.point_format = las::point::Format::new(0)?;
            b.generating_software = format!("asbuilt {}", env!("CARGO_PKG_VERSION"));
            // 0.1 mm steps around the first scan's position keep i32 coordinates in range
            // for kilometres.
            let t = scan.pose.translation.vector.map(|v| v.round());
            b.transforms = las::Vector {
                x: las::Transform {
                    scale: 1e-4,
                    offset: t.x,
                },
                y: las::Transform {
                    scale: 1e-4,
                    offset: t.y,
                },
                z: las::Transform {
                    scale: 1e-4,
                    offset: t.z,
                },
            };
            let header = b.into_header()?;
            self.writer = Some(las::Writer::from_path(&self.path, header).map_err(|e| {
                ScanError::Content(format!("cannot write {}: {e}", self.path.display()))
            })?);
        }
        let w = self.writer.as_mut().expect("created above");
        let mut n = 0u64;
        feed(&mut |chunk| {
            for p in chunk.iter().filter(|p| !p.flags.is_invalid()) {
                let q = world(&scan.pose, p);
                let point = las::Point {
                    x: q.x,
                    y: q.y,
                    z: q.z,
                    intensity: (p.intensity.clamp(0.0, 1.0) * 65535.0).round() as u16,
                    ..Default::default()
                };
                w.write_point(point)?;
                n += 1;
            }
            Ok(())
        })?;
        Ok(n)
    }

    fn finish(mut self: Box<Self>) -> Result<()> {
        if let Some(mut w) = self.writer.take() {
            w.close()?;
        }
        Ok(())
    }
}

struct E57 {
    writer: e57::E57Writer<File>,
    scans: u32,
    path: PathBuf,
}

impl CloudWriter for E57 {
    fn write_scan(&mut self, scan: &OutScan, feed: Feed) -> Result<u64> {
        use e57::{Record, RecordDataType, RecordName, RecordValue};
        let prototype = vec![
            Record {
                name: RecordName::CartesianX,
                data_type: RecordDataType::Double {
                    min: None,
                    max: None,
                },
            },
            Record {
                name: RecordName::CartesianY,
                data_type: RecordDataType::Double {
                    min: None,
                    max: None,
                },
            },
            Record {
                name: RecordName::CartesianZ,
                data_type: RecordDataType::Double {
                    min: None,
                    max: None,
                },
            },
            Record {
                name: RecordName::CartesianInvalidState,
                data_type: RecordDataType::Integer { min: 0, max: 2 },
            },
            Record {
                name: RecordName::Intensity,
                data_type: RecordDataType::Single {
                    min: Some(0.0),
                    max: Some(1.0),
                },
            },
        ];
        let guid = guid(&self.path, &format!("scan{}", self.scans));
        let mut pc = self
            .writer
            .add_pointcloud(&guid, prototype)
            .map_err(|e| ScanError::Content(format!("E57 {}: {e}", scan.name)))?;
        pc.set_name(Some(scan.name.clone()));
        let q = scan.pose.rotation.quaternion();
        let t = scan.pose.translation.vector;
        pc.set_transform(Some(e57::Transform {
            rotation: e57::Quaternion {
                w: q.w,
                x: q.i,
                y: q.j,
                z: q.k,
            },
            translation: e57::Translation {
                x: t.x,
                y: t.y,
                z: t.z,
            },
        }));
        let mut n = 0u64;
        feed(&mut |chunk| {
            for p in chunk {
                let invalid = p.flags.is_invalid();
                pc.add_point(vec![
                    RecordValue::Double(p.xyz[0] as f64),
                    RecordValue::Double(p.xyz[1] as f64),
                    RecordValue::Double(p.xyz[2] as f64),
                    RecordValue::Integer(if invalid { 2 } else { 0 }),
                    RecordValue::Single(p.intensity.clamp(0.0, 1.0)),
                ])
                .map_err(|e| ScanError::Content(format!("E57 {}: {e}", scan.name)))?;
            }
            n += chunk.len() as u64;
            Ok(())
        })?;
        pc.finalize()
            .map_err(|e| ScanError::Content(format!("E57 {}: {e}", scan.name)))?;
        self.scans += 1;
        Ok(n)
    }

    fn finish(mut self: Box<Self>) -> Result<()> {
        self.writer
            .finalize()
            .map_err(|e| ScanError::Content(format!("cannot finish {}: {e}", self.path.display())))
    }
}
