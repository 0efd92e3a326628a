//! Reading scan files (points in the scanner's frame, metres).

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

use anyhow::{Context, Result, bail};
use asbuilt_protocol::ScanPoint;
use nalgebra::Point3;
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};

/// What a reader had to leave out of a file, besides the points it returns.
#[derive(Debug, Default, Clone, Copy)]
pub struct ReadNotes {
    pub malformed_lines: u64,
    pub first_malformed_line: Option<u64>,
}

pub fn read_scan(path: &Path) -> Result<(Vec<ScanPoint>, ReadNotes)> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let file = File::open(path).with_context(|| format!("cannot open scan {}", path.display()))?;
    match ext.as_str() {
        "ply" => read_ply(BufReader::new(file), path).map(|p| (p, ReadNotes::default())),
        "xyz" | "txt" | "pts" | "asc" | "csv" => read_xyz(BufReader::new(file), path),
        "las" => {
            let pts = read_las(path)?;
            let out = pts
                .iter()
                .map(|p| ScanPoint::new(p.x as f32, p.y as f32, p.z as f32))
                .collect();
            Ok((out, ReadNotes::default()))
        }
        "e57" | "laz" | "ptx" => bail!(
            "scan {}: .{ext} is not read yet; convert it to PLY or XYZ (x y z [intensity], metres)",
            path.display()
        ),
        _ => bail!(
            "scan {} has an unknown extension: use .ply, .las or .xyz (x y z [intensity], metres)",
            path.display()
        ),
    }
}

fn read_ply(mut reader: impl BufRead, path: &Path) -> Result<Vec<ScanPoint>> {
    let ply = Parser::<DefaultElement>::new()
        .read_ply(&mut reader)
        .map_err(|e| anyhow::anyhow!("cannot read scan {} as PLY: {e}", path.display()))?;
    let Some(vertices) = ply.payload.get("vertex") else {
        bail!("scan {} has no `vertex` element", path.display());
    };
    let mut out = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        let coord = |k: &str| -> Result<f32> {
            v.get(k).and_then(scalar).with_context(|| {
                format!("scan {}: vertex {i} has no numeric `{k}`", path.display())
            })
        };
        let mut p = ScanPoint::new(coord("x")?, coord("y")?, coord("z")?);
        if let Some(intensity) = v.get("intensity").and_then(scalar) {
            p.intensity = intensity;
        }
        out.push(p);
    }
    Ok(out)
}

/// A reference cloud in the design frame, at full f64 precision (survey coordinates need it):
/// PLY, LAS, or text with `x y z` first on each line (a header line is skipped and counted).
pub fn read_cloud(path: &Path) -> Result<(Vec<Point3<f64>>, ReadNotes)> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let file = File::open(path).with_context(|| format!("cannot open cloud {}", path.display()))?;
    let (pts, notes) = match ext.as_str() {
        "las" => (read_las(path)?, ReadNotes::default()),
        "ply" => {
            let ply = Parser::<DefaultElement>::new()
                .read_ply(&mut BufReader::new(file))
                .map_err(|e| anyhow::anyhow!("cannot read cloud {} as PLY: {e}", path.display()))?;
            let Some(vertices) = ply.payload.get("vertex") else {
                bail!("cloud {} has no `vertex` element", path.display());
            };
            let mut out = Vec::with_capacity(vertices.len());
            for (i, v) in vertices.iter().enumerate() {
                let c = |k: &str| -> Result<f64> {
                    v.get(k)
                        .and_then(asbuilt_core::design::ply_scalar)
                        .with_context(|| {
                            format!("cloud {}: vertex {i} has no numeric `{k}`", path.display())
                        })
                };
                out.push(Point3::new(c("x")?, c("y")?, c("z")?));
            }
            (out, ReadNotes::default())
        }
        "xyz" | "txt" | "pts" | "asc" | "csv" => {
            let mut out = Vec::new();
            let mut notes = ReadNotes::default();
            for (n, line) in BufReader::new(file).lines().enumerate() {
                let line_no = n as u64 + 1;
                let line =
                    line.with_context(|| format!("cloud {}: line {line_no}", path.display()))?;
                let line = line.trim();
                if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
                    continue;
                }
                let nums: Option<Vec<f64>> = line
                    .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
                    .filter(|f| !f.is_empty())
                    .take(3)
                    .map(|f| f.parse().ok())
                    .collect();
                match nums {
                    Some(v) if v.len() == 3 => out.push(Point3::new(v[0], v[1], v[2])),
                    _ => {
                        notes.malformed_lines += 1;
                        notes.first_malformed_line.get_or_insert(line_no);
                    }
                }
            }
            (out, notes)
        }
        _ => bail!(
            "cloud {} has an unknown extension: use .ply, .las or .xyz/.txt (x y z first)",
            path.display()
        ),
    };
    let finite: Vec<Point3<f64>> = pts
        .into_iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite() && p.z.is_finite())
        .collect();
    if finite.is_empty() {
        bail!("cloud {} has no finite point", path.display());
    }
    Ok((finite, notes))
}

fn read_las(path: &Path) -> Result<Vec<Point3<f64>>> {
    let mut reader = las::Reader::from_path(path)
        .map_err(|e| anyhow::anyhow!("cannot read {} as LAS: {e}", path.display()))?;
    let data = reader
        .read_all()
        .map_err(|e| anyhow::anyhow!("cannot read the points of {}: {e}", path.display()))?;
    Ok(data
        .x()
        .zip(data.y())
        .zip(data.z())
        .map(|((x, y), z)| Point3::new(x, y, z))
        .collect())
}

/// Scan coordinates are f32 (see `ScanPoint`); every PLY scalar converts exactly to f64 first.
fn scalar(p: &Property) -> Option<f32> {
    asbuilt_core::design::ply_scalar(p).map(|v| v as f32)
}

/// `x y z [intensity ...]` per line, separated by spaces, tabs, commas or semicolons. Comment
/// lines (`#`, `//`) and a leading point count (PTS) are skipped; a line that cannot be read is
/// counted and skipped, so one bad line never costs the rest of the scan.
fn read_xyz(reader: impl BufRead, path: &Path) -> Result<(Vec<ScanPoint>, ReadNotes)> {
    let mut out = Vec::new();
    let mut notes = ReadNotes::default();
    for (n, line) in reader.lines().enumerate() {
        let line_no = n as u64 + 1;
        let line = line.with_context(|| format!("scan {}: line {line_no}", path.display()))?;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
            continue;
        }
        let fields: Vec<&str> = line
            .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
            .filter(|f| !f.is_empty())
            .collect();
        if line_no == 1 && fields.len() == 1 && fields[0].parse::<u64>().is_ok() {
            continue;
        }
        let nums: Option<Vec<f32>> = fields.iter().take(4).map(|f| f.parse().ok()).collect();
        match nums {
            Some(v) if v.len() >= 3 => {
                let mut p = ScanPoint::new(v[0], v[1], v[2]);
                if let Some(&i) = v.get(3) {
                    p.intensity = i;
                }
                out.push(p);
            }
            _ => {
                notes.malformed_lines += 1;
                notes.first_malformed_line.get_or_insert(line_no);
            }
        }
    }
    if out.is_empty() && notes.malformed_lines > 0 {
        bail!(
            "scan {} has no readable point: expected lines of `x y z [intensity]` in metres \
             (first bad line: {})",
            path.display(),
            notes.first_malformed_line.unwrap_or(0)
        );
    }
    Ok((out, notes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xyz_keeps_good_points_around_bad_lines_and_nan() {
        let text = "3\n# comment\n1 2 3\n4,5,6,0.5\nnan 0 0\nbroken line\n7 8 9\n";
        let (pts, notes) = read_xyz(text.as_bytes(), Path::new("t.xyz")).unwrap();
        assert_eq!(pts.len(), 4);
        assert!(pts[2].xyz[0].is_nan());
        assert_eq!(pts[1].intensity, 0.5);
        assert_eq!(notes.malformed_lines, 1);
        assert_eq!(notes.first_malformed_line, Some(6));
        assert!(read_xyz("a b c\n".as_bytes(), Path::new("t.xyz")).is_err());
    }
}
