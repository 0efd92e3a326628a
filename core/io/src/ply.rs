//! The one PLY writer: binary little-endian, one `vertex` element of scalar properties, which
//! CloudCompare opens with every property beyond x, y, z as a scalar field.
//!
//! A PLY header states the row count. When it is known up front (a scan of announced size) the
//! header goes first and the rows stream after it; when it is not (deviations, tables) the
//! header leaves the count room for any u64, and the rows stream to a part file beside the
//! output whose count [`PlyWriter::finish`] writes in place before the file takes its name. So
//! memory never grows with the rows, nothing is copied at the end (a 50 M point scan's
//! deviations are 1.8 GB), and the output's name holds only a complete file.

use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use crate::IoError;

pub(crate) mod read;

/// A property's scalar type, as the PLY header names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scalar {
    /// `double`.
    F64,
    /// `float`.
    F32,
    /// `uint`.
    U32,
    /// `ushort`.
    U16,
    /// `uchar`.
    U8,
}

impl Scalar {
    fn name(self) -> &'static str {
        match self {
            Scalar::F64 => "double",
            Scalar::F32 => "float",
            Scalar::U32 => "uint",
            Scalar::U16 => "ushort",
            Scalar::U8 => "uchar",
        }
    }

    fn size(self) -> usize {
        match self {
            Scalar::F64 => 8,
            Scalar::F32 | Scalar::U32 => 4,
            Scalar::U16 => 2,
            Scalar::U8 => 1,
        }
    }
}

/// One column of the vertex element.
#[derive(Debug, Clone, Copy)]
pub struct Property {
    /// The property's name in the header.
    pub name: &'static str,
    /// Its scalar type.
    pub scalar: Scalar,
}

impl Property {
    /// A column `name` of type `scalar`.
    pub const fn new(name: &'static str, scalar: Scalar) -> Self {
        Self { name, scalar }
    }
}

/// A point table's columns: x, y and z in metres as doubles, so a point keeps its full
/// precision however far it is from the origin, then `rest`.
pub fn point_columns(rest: &[Property]) -> Vec<Property> {
    let xyz = ["x", "y", "z"].map(|axis| Property::new(axis, Scalar::F64));
    [&xyz[..], rest].concat()
}

/// Where the rows go until the count is known.
enum Body {
    /// The header is written: rows go straight after it, and exactly `announced` must come.
    Direct { announced: u64 },
    /// Rows go to a part file beside the output, after a header whose count is written at
    /// `slot` at the end ([`count_slot`]).
    Part { part: PathBuf, slot: u64 },
}

/// Digits of the largest count.
const COUNT_DIGITS: usize = 20;

/// The count and what pads it to a fixed width: a comment line, which every reader passes over
/// (a count padded with zeros or spaces is not read alike by all).
fn count_slot(rows: u64) -> String {
    let count = rows.to_string();
    format!("{count}\ncomment{}", " ".repeat(COUNT_DIGITS - count.len()))
}

/// Writes a binary PLY row by row. Call [`PlyWriter::finish`]: a writer dropped without it
/// leaves no complete file.
pub struct PlyWriter {
    path: PathBuf,
    out: BufWriter<File>,
    body: Body,
    record: usize,
    rows: u64,
    /// One row's bytes for [`PlyWriter::row`], reused.
    scratch: Vec<u8>,
}

impl PlyWriter {
    /// A PLY at `path` with `properties` per row; `rows` is the count if known now. The comment
    /// says what the file holds, with its frame and units.
    pub fn create(
        path: &Path,
        comment: &str,
        properties: &[Property],
        rows: Option<u64>,
    ) -> Result<Self, IoError> {
        let mut header = format!(
            "ply\nformat binary_little_endian 1.0\ncomment {}\n",
            comment.replace('\n', " ")
        );
        let properties_text: String = properties
            .iter()
            .map(|p| format!("property {} {}\n", p.scalar.name(), p.name))
            .collect();
        let record = properties.iter().map(|p| p.scalar.size()).sum();
        let tail = format!("\n{properties_text}end_header\n");
        header += "element vertex ";
        let (file_path, body) = match rows {
            Some(n) => {
                header += &format!("{n}{tail}");
                (path.to_path_buf(), Body::Direct { announced: n })
            }
            None => {
                let part = path.with_extension("ply.part");
                let slot = header.len() as u64;
                header += &format!("{}{tail}", count_slot(0));
                (part.clone(), Body::Part { part, slot })
            }
        };
        let file = File::create(&file_path).map_err(|source| IoError::Open {
            path: file_path.clone(),
            source,
        })?;
        let mut out = BufWriter::with_capacity(1 << 20, file);
        out.write_all(header.as_bytes())
            .map_err(|e| written(path, e))?;
        Ok(Self {
            path: path.to_path_buf(),
            out,
            body,
            record,
            rows: 0,
            scratch: Vec::with_capacity(record),
        })
    }

    /// The bytes of one row, little-endian, in the properties' order.
    #[inline]
    pub fn record(&mut self, bytes: &[u8]) -> Result<(), IoError> {
        debug_assert_eq!(bytes.len(), self.record, "a record holds every property");
        self.rows += 1;
        self.out
            .write_all(bytes)
            .map_err(|e| written(&self.path, e))
    }

    /// One row from values in the properties' order, each converted to its property's type
    /// (`as`: floats round, integers saturate). For tables; a hot loop builds its bytes.
    pub fn row(&mut self, properties: &[Property], values: &[f64]) -> Result<(), IoError> {
        debug_assert_eq!(properties.len(), values.len());
        let mut bytes = std::mem::take(&mut self.scratch);
        bytes.clear();
        for (p, &v) in properties.iter().zip(values) {
            match p.scalar {
                Scalar::F64 => bytes.extend_from_slice(&v.to_le_bytes()),
                Scalar::F32 => bytes.extend_from_slice(&(v as f32).to_le_bytes()),
                Scalar::U32 => bytes.extend_from_slice(&(v as u32).to_le_bytes()),
                Scalar::U16 => bytes.extend_from_slice(&(v as u16).to_le_bytes()),
                Scalar::U8 => bytes.push(v as u8),
            }
        }
        let written = self.record(&bytes);
        self.scratch = bytes;
        written
    }

    /// Completes the file; returns the rows written. A count announced up front must be met.
    pub fn finish(self) -> Result<u64, IoError> {
        let Self {
            path,
            mut out,
            body,
            rows,
            ..
        } = self;
        out.flush().map_err(|e| written(&path, e))?;
        let file = out
            .into_inner()
            .map_err(|e| written(&path, e.into_error()))?;
        match body {
            Body::Direct { announced } if announced != rows => Err(IoError::Malformed {
                path,
                format: "PLY",
                what: format!("the header announced {announced} points but {rows} were written"),
            }),
            Body::Direct { .. } => Ok(rows),
            Body::Part { part, slot } => {
                let mut file = file;
                file.seek(SeekFrom::Start(slot))
                    .and_then(|_| file.write_all(count_slot(rows).as_bytes()))
                    .and_then(|()| std::fs::rename(&part, &path))
                    .map_err(|e| written(&path, e))?;
                Ok(rows)
            }
        }
    }
}

/// A small table (design samples, core points: they grow with the design, never with the scan)
/// as a PLY, one row of values per item in the properties' order. Returns the row count.
pub fn write_table(
    path: &Path,
    comment: &str,
    properties: &[Property],
    rows: impl Iterator<Item = Vec<f64>>,
) -> Result<u64, IoError> {
    let mut w = PlyWriter::create(path, comment, properties, None)?;
    for row in rows {
        w.row(properties, &row)?;
    }
    w.finish()
}

fn written(path: &Path, source: std::io::Error) -> IoError {
    IoError::Write {
        path: path.to_path_buf(),
        source,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{DefaultElement, Property as P};

    const COLUMNS: [Property; 4] = [
        Property::new("x", Scalar::F64),
        Property::new("d", Scalar::F32),
        Property::new("triangle", Scalar::U32),
        Property::new("station", Scalar::U16),
    ];

    fn read(path: &Path) -> Vec<DefaultElement> {
        let mut f = std::io::BufReader::new(File::open(path).unwrap());
        let ply = Parser::<DefaultElement>::new().read_ply(&mut f).unwrap();
        ply.payload["vertex"].clone()
    }

    #[test]
    fn rows_read_back_whether_the_count_is_known_or_not() {
        let dir = tempfile::tempdir().unwrap();
        for known in [Some(5), None] {
            let path = dir.path().join(format!("t{}.ply", known.is_some()));
            let mut w = PlyWriter::create(&path, "test\ntwo lines", &COLUMNS, known).unwrap();
            for i in 0..5 {
                w.row(
                    &COLUMNS,
                    &[i as f64 * 0.5, -(i as f64), 7.0 + i as f64, 2.0],
                )
                .unwrap();
            }
            assert_eq!(w.finish().unwrap(), 5);
            let v = read(&path);
            assert_eq!(v.len(), 5);
            assert!(matches!(v[3]["x"], P::Double(x) if x == 1.5));
            assert!(matches!(v[3]["d"], P::Float(d) if d == -3.0));
            assert!(matches!(v[3]["triangle"], P::UInt(10)));
            assert!(matches!(v[3]["station"], P::UShort(2)));
            assert!(!path.with_extension("ply.part").exists());
        }
    }

    #[test]
    fn the_count_written_at_the_end_fills_the_room_left_for_it() {
        let width = count_slot(0).len();
        for n in [1, 5_000_000, u64::MAX] {
            assert_eq!(count_slot(n).len(), width, "{n}");
        }
    }

    #[test]
    fn an_announced_count_not_met_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("short.ply");
        let mut w = PlyWriter::create(&path, "test", &COLUMNS, Some(3)).unwrap();
        w.row(&COLUMNS, &[0.0, 0.0, 0.0, 0.0]).unwrap();
        let e = w.finish().unwrap_err();
        assert!(e.to_string().contains("announced 3 points but 1"), "{e}");
    }
}
