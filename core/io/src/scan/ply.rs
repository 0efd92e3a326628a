//! PLY point clouds, streamed: the header is parsed, elements before `vertex` are skipped, and
//! vertices are decoded record by record (ASCII, binary little or big endian). `x y z` are
//! required; `intensity` (or CloudCompare's `scalar_intensity`) is kept. No pose.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use super::error::{Result, ScanError, bail};
use crate::ply::read::{Encoding, Record, Records, Type, Value, fixed_layout, header, place};
use asbuilt_protocol::ScanPoint;

use super::{Batcher, ReadNotes, ScanInfo, Sink};

/// Bytes of binary records read at a time.
const BLOCK_BYTES: usize = 1 << 16;

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
    let layout = fixed_layout(vertex).filter(|_| h.encoding != Encoding::Ascii);
    if let Some((layout, size)) = layout.filter(|(_, size)| *size > 0) {
        // Binary records of one size: a block of them at a time, each decoded in place.
        let at = |k: usize| layout[k];
        let (x, y, z, i) = (at(ix), at(iy), at(iz), ii.map(at));
        let mut buf = vec![0u8; size * (BLOCK_BYTES / size).max(1)];
        let mut n = 0u64;
        while n < vertex.count {
            let room = buf.len() / size;
            let want = room.min(usize::try_from(vertex.count - n).unwrap_or(room));
            let got = records.block(&mut buf[..want * size], size)?;
            for r in buf[..got * size].chunks_exact(size) {
                let value = |(o, t): (usize, Type)| records.decode(t, &r[o..]);
                out.push(scan_point([
                    value(x),
                    value(y),
                    value(z),
                    i.map_or(0.0, value),
                ]))?;
            }
            n += got as u64;
            if got < want {
                return Err(truncated(n));
            }
        }
        out.finish()?;
        return Ok(notes);
    }
    for n in 0..vertex.count {
        let mut v = [f64::NAN, f64::NAN, f64::NAN, 0.0];
        let mut take = |value: Value| {
            if let Value::Scalar(k, x) = value {
                place(&mut v, [Some(ix), Some(iy), Some(iz), ii], k, x);
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
        out.push(scan_point(v))?;
    }
    out.finish()?;
    Ok(notes)
}

/// A point from its x, y, z and intensity.
fn scan_point([x, y, z, intensity]: [f64; 4]) -> ScanPoint {
    let mut p = ScanPoint::new(x as f32, y as f32, z as f32);
    p.intensity = intensity as f32;
    p
}
