//! Small binary PLY tables (one vertex element, scalar columns) that CloudCompare opens with
//! every column as a scalar field. The body is built in memory: these tables hold design
//! samples or core points, which grow with the design, never with the scan.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use anyhow::{Context, Result};

#[derive(Debug, Clone, Copy)]
pub enum Column {
    Double(&'static str),
    Float(&'static str),
}

/// Writes `rows` (one value per column, in order) as `path`. Returns the row count.
pub fn write(
    path: &Path,
    comment: &str,
    columns: &[Column],
    rows: impl Iterator<Item = Vec<f64>>,
) -> Result<u64> {
    // The count goes in the header: write the body first, then join.
    let mut body: Vec<u8> = Vec::new();
    let mut count = 0u64;
    for row in rows {
        debug_assert_eq!(row.len(), columns.len());
        for (c, v) in columns.iter().zip(row) {
            match c {
                Column::Double(_) => body.extend_from_slice(&v.to_le_bytes()),
                Column::Float(_) => body.extend_from_slice(&(v as f32).to_le_bytes()),
            }
        }
        count += 1;
    }
    let file = File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut out = BufWriter::new(file);
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment {}\nelement vertex {count}\n",
        comment.replace('\n', " ")
    )?;
    for c in columns {
        match c {
            Column::Double(n) => writeln!(out, "property double {n}")?,
            Column::Float(n) => writeln!(out, "property float {n}")?,
        }
    }
    out.write_all(b"end_header\n")?;
    out.write_all(&body)?;
    out.flush()
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(count)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{DefaultElement, Property};

    #[test]
    fn a_written_table_reads_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.ply");
        let n = write(
            &path,
            "test",
            &[Column::Double("x"), Column::Float("d")],
            (0..5).map(|i| vec![i as f64 * 0.5, -(i as f64)]),
        )
        .unwrap();
        assert_eq!(n, 5);
        let mut f = std::io::BufReader::new(File::open(&path).unwrap());
        let ply = Parser::<DefaultElement>::new().read_ply(&mut f).unwrap();
        let v = &ply.payload["vertex"];
        assert_eq!(v.len(), 5);
        assert!(matches!(v[3]["x"], Property::Double(x) if x == 1.5));
        assert!(matches!(v[3]["d"], Property::Float(d) if d == -3.0));
    }
}
