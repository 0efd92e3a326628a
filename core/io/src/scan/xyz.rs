//! Text point clouds: `x y z [intensity ...]` per line, separated by spaces, tabs, commas or
//! semicolons. Comment lines (`#`, `//`) and a leading point count (PTS) are skipped; a line
//! that cannot be read (a header such as `X Y Z`) is counted and skipped, so one bad line never
//! costs the rest of the scan. No pose: the station gives it.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

use super::error::{Context, Result, bail};
use asbuilt_protocol::ScanPoint;

use super::{Batcher, ReadNotes, ScanInfo, Sink};

pub fn scans(path: &Path) -> Vec<ScanInfo> {
    vec![ScanInfo {
        index: 0,
        name: super::stem(path),
        points: None,
        pose: None,
        offset: 0,
        first_line: 0,
    }]
}

pub fn stream(path: &Path, chunk: usize, sink: &mut Sink) -> Result<ReadNotes> {
    let file = File::open(path).with_context(|| format!("cannot open scan {}", path.display()))?;
    parse(BufReader::with_capacity(1 << 20, file), path, chunk, sink)
}

pub(super) fn parse(
    reader: impl BufRead,
    path: &Path,
    chunk: usize,
    sink: &mut Sink,
) -> Result<ReadNotes> {
    let mut notes = ReadNotes::default();
    let mut out = Batcher::new(chunk, sink);
    let mut good = 0u64;
    for (n, line) in reader.lines().enumerate() {
        let line_no = n as u64 + 1;
        let line = line.with_context(|| format!("scan {}: line {line_no}", path.display()))?;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
            continue;
        }
        let mut fields = line
            .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
            .filter(|f| !f.is_empty());
        let first = fields.next();
        let rest: Vec<&str> = fields.take(3).collect();
        if line_no == 1 && rest.is_empty() && first.is_some_and(|f| f.parse::<u64>().is_ok()) {
            continue;
        }
        let nums: Option<Vec<f32>> = first
            .into_iter()
            .chain(rest.iter().copied())
            .map(|f| f.parse().ok())
            .collect();
        match nums {
            Some(v) if v.len() >= 3 => {
                let mut p = ScanPoint::new(v[0], v[1], v[2]);
                if let Some(&i) = v.get(3) {
                    p.intensity = i;
                }
                out.push(p)?;
                good += 1;
            }
            _ => notes.malformed(line_no),
        }
    }
    out.finish()?;
    if good == 0 && notes.malformed_lines > 0 {
        bail!(
            "scan {} has no readable point: expected lines of `x y z [intensity]` in metres \
             (first bad line: {})",
            path.display(),
            notes.first_malformed_line.unwrap_or(0)
        );
    }
    Ok(notes)
}
