//! PLY point clouds, streamed: the header is parsed, elements before `vertex` are skipped, and
//! vertices are decoded record by record (ASCII, binary little or big endian). `x y z` are
//! required; `intensity` (or CloudCompare's `scalar_intensity`) is kept. No pose.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use super::error::{Result, ScanError, bail};
use crate::ply::read::{Record, Records, Value, header};
use asbuilt_protocol::ScanPoint;

use super::{Batcher, ReadNotes, ScanInfo, Sink};

pub fn scans(path: &Path) -> Result<Vec<ScanInfo>> {
    let mut reader = BufReader::new(File::open(path)?);
    let h = header(&mut reader, path)?;
    let vertex = &h.elements[h.vertex_element(path)?];
    Ok(vec![ScanInfo {
        index: 0,
        name: super::stem(path),
        points: Some(vertex.count),
        pose: None,
        offset: 0,
        first_line: 0,
    }])
}

pub fn stream(path: &Path, chunk: usize, sink: &mut Sink) -> Result<ReadNotes> {
    let mut reader = BufReader::with_capacity(1 << 20, File::open(path)?);
    let h = header(&mut reader, path)?;
    let vi = h.vertex_element(path)?;
    let vertex = &h.elements[vi];
    let find = |names: &[&str]| vertex.scalar(names);
    let (Some(ix), Some(iy), Some(iz)) = (find(&["x"]), find(&["y"]), find(&["z"])) else {
        bail!("{}: the vertex element needs x, y and z", path.display());
    };
    let ii = find(&["intensity", "scalar_intensity"]);
    let mut notes = ReadNotes::default();
    let mut out = Batcher::new(chunk, sink);
    let mut line_no = h.lines;
    let mut records = Records::new(reader, h.encoding);
    let truncated = |n: u64| {
        ScanError::Content(format!(
            "{}: the file ends after {n} of {} vertices (truncated?)",
            path.display(),
            vertex.count
        ))
    };
    // Skip what comes before the vertices.
    for e in &h.elements[..vi] {
        for _ in 0..e.count {
            line_no += 1;
            if records.next(e, &mut |_| {})? == Record::End {
                return Err(truncated(0));
            }
        }
    }
    for n in 0..vertex.count {
        let mut v = [f64::NAN, f64::NAN, f64::NAN, 0.0];
        let mut take = |value: Value| {
            if let Value::Scalar(k, x) = value {
                if k == ix {
                    v[0] = x
                } else if k == iy {
                    v[1] = x
                } else if k == iz {
                    v[2] = x
                } else if Some(k) == ii {
                    v[3] = x
                }
            }
        };
        line_no += 1;
        match records.next(vertex, &mut take)? {
            Record::Read => {}
            Record::Malformed => {
                notes.malformed(line_no);
                continue;
            }
            Record::End => return Err(truncated(n)),
        }
        let mut p = ScanPoint::new(v[0] as f32, v[1] as f32, v[2] as f32);
        p.intensity = v[3] as f32;
        out.push(p)?;
    }
    out.finish()?;
    Ok(notes)
}
