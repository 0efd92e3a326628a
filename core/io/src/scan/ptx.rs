//! PTX, the ASCII export of Leica and Z+F software: scans one after another, each a header
//! (columns, rows, scanner position and axes, a 4 × 4 transform with the translation in its last
//! row) followed by `columns × rows` lines of `x y z intensity [r g b]` in the scanner's frame.
//! A point at exactly 0 0 0 is a missing return.

use std::fs::File;
use std::io::{BufRead, BufReader, Seek, SeekFrom};
use std::path::Path;

use super::error::{Context, Result, bail};
use asbuilt_protocol::{ScanPoint, ScanPointFlags};
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::{Batcher, PoseSource, ReadNotes, ScanInfo, Sink};

/// A PTX scan header.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PtxScan {
    pub columns: u64,
    pub rows: u64,
    /// `p_world = pose · p_scanner`.
    pub pose: Isometry3<f64>,
}

/// The next non-empty line as numbers; `None` at the end of the file.
fn numbers(
    reader: &mut impl BufRead,
    line_no: &mut u64,
    path: &Path,
    what: &str,
) -> Result<Option<Vec<f64>>> {
    let mut buf = String::new();
    loop {
        buf.clear();
        if reader.read_line(&mut buf)? == 0 {
            return Ok(None);
        }
        *line_no += 1;
        if buf.trim().is_empty() {
            continue;
        }
        let v: Result<Vec<f64>, _> = buf.split_whitespace().map(str::parse::<f64>).collect();
        return match v {
            Ok(v) => Ok(Some(v)),
            Err(_) => bail!(
                "{} line {}: expected {what}, got {:?}",
                path.display(),
                line_no,
                buf.trim()
            ),
        };
    }
}

/// Reads one header (10 lines); `None` at the end of the file.
fn read_header(
    reader: &mut impl BufRead,
    line_no: &mut u64,
    path: &Path,
) -> Result<Option<(PtxScan, u64)>> {
    let Some(cols) = numbers(reader, line_no, path, "the column count")? else {
        return Ok(None);
    };
    let header_line = *line_no;
    let rows = numbers(reader, line_no, path, "the row count")?
        .context("the file ends inside a PTX header")?;
    let mut vecs = Vec::new();
    for what in [
        "the scanner position",
        "the scanner X axis",
        "the scanner Y axis",
        "the scanner Z axis",
    ] {
        let v =
            numbers(reader, line_no, path, what)?.context("the file ends inside a PTX header")?;
        if v.len() != 3 {
            bail!(
                "{} line {}: expected {what} as 3 numbers",
                path.display(),
                line_no
            );
        }
        vecs.push(Vector3::new(v[0], v[1], v[2]));
    }
    let mut m = [[0.0; 4]; 4];
    for row in &mut m {
        let v = numbers(reader, line_no, path, "a row of the 4 × 4 transform")?
            .context("the file ends inside a PTX header")?;
        if v.len() != 4 {
            bail!(
                "{} line {}: expected 4 numbers of the transform",
                path.display(),
                line_no
            );
        }
        row.copy_from_slice(&v);
    }
    let count = |v: &[f64], what: &str| -> Result<u64> {
        match v {
            [c] if *c >= 0.0 && c.fract() == 0.0 => Ok(*c as u64),
            _ => bail!(
                "{} line {header_line}: the {what} must be one whole number",
                path.display()
            ),
        }
    };
    let (columns, rows) = (count(&cols, "column count")?, count(&rows, "row count")?);
    // Both uses multiply them: a count no file can hold must not overflow there.
    if columns.checked_mul(rows).is_none() {
        bail!(
            "{} line {header_line}: {columns} × {rows} points is more than any file holds",
            path.display()
        );
    }
    // Row-vector convention: p_world = p · M, so R is the transpose of M's upper 3 × 3.
    let r = Matrix3::new(
        m[0][0], m[1][0], m[2][0], m[0][1], m[1][1], m[2][1], m[0][2], m[1][2], m[2][2],
    );
    let t = Vector3::new(m[3][0], m[3][1], m[3][2]);
    if (r.transpose() * r - Matrix3::identity()).abs().max() > 1e-5
        || (r.determinant() - 1.0).abs() > 1e-5
    {
        bail!(
            "{} scan at line {header_line}: the header's transform is not a rotation (its 3 × 3 \
             part must be orthonormal with determinant 1)",
            path.display()
        );
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Ok(Some((
        PtxScan {
            columns,
            rows,
            pose: Isometry3::from_parts(Translation3::from(t), rot),
        },
        header_line,
    )))
}

pub fn scans(path: &Path) -> Result<Vec<ScanInfo>> {
    let mut reader = BufReader::new(File::open(path)?);
    let mut line_no = 0u64;
    let mut out = Vec::new();
    loop {
        let offset = reader.stream_position()?;
        let first_line = line_no;
        let Some((scan, _)) = read_header(&mut reader, &mut line_no, path)? else {
            break;
        };
        let n = scan.columns * scan.rows;
        // Skip the points without keeping them.
        let mut skipped = 0u64;
        let mut buf = Vec::new();
        while skipped < n {
            buf.clear();
            if reader.read_until(b'\n', &mut buf)? == 0 {
                bail!(
                    "{} scan {}: the header promises {} points ({} × {}) but the file ends after {skipped}",
                    path.display(),
                    out.len(),
                    n,
                    scan.columns,
                    scan.rows
                );
            }
            line_no += 1;
            skipped += 1;
        }
        out.push(ScanInfo {
            index: out.len(),
            name: format!("scan {}", out.len()),
            points: Some(n),
            pose: Some((scan.pose, PoseSource::PtxHeader)),
            offset,
            first_line,
        });
    }
    if out.is_empty() {
        bail!("{} holds no PTX scan", path.display());
    }
    Ok(out)
}

pub fn stream(path: &Path, info: &ScanInfo, chunk: usize, sink: &mut Sink) -> Result<ReadNotes> {
    let mut file = File::open(path)?;
    file.seek(SeekFrom::Start(info.offset))?;
    let mut reader = BufReader::with_capacity(1 << 20, file);
    // Line numbers in the notes are the file's: the scan's header starts after `first_line`.
    let mut line_no = info.first_line;
    let (scan, _) =
        read_header(&mut reader, &mut line_no, path)?.context("the PTX header is gone")?;
    let mut notes = ReadNotes::default();
    let mut out = Batcher::new(chunk, sink);
    let mut line = String::new();
    for _ in 0..scan.columns * scan.rows {
        line.clear();
        if reader.read_line(&mut line)? == 0 {
            bail!("{} {}: the file ends early", path.display(), info.name);
        }
        line_no += 1;
        let mut it = line.split_whitespace().map(str::parse::<f32>);
        let (x, y, z, i) = match (it.next(), it.next(), it.next(), it.next()) {
            (Some(Ok(x)), Some(Ok(y)), Some(Ok(z)), i) => (x, y, z, i.and_then(Result::ok)),
            _ => {
                notes.malformed(line_no);
                continue;
            }
        };
        let mut p = ScanPoint::new(x, y, z);
        p.intensity = i.unwrap_or(0.0);
        if x == 0.0 && y == 0.0 && z == 0.0 {
            p.flags = ScanPointFlags(ScanPointFlags::INVALID);
            notes.invalid += 1;
        }
        out.push(p)?;
    }
    out.finish()?;
    Ok(notes)
}
