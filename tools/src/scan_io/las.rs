//! LAS and LAZ through the `las` crate. Points are in the file's (often georeferenced) frame;
//! they are read relative to the header's bounds centre, which the pose restores.

use std::path::Path;

use anyhow::Result;
use asbuilt_protocol::ScanPoint;
use nalgebra::{Isometry3, Vector3};

use super::{Batcher, PoseSource, ReadNotes, ScanInfo};

fn open(path: &Path) -> Result<las::Reader> {
    las::Reader::from_path(path)
        .map_err(|e| anyhow::anyhow!("cannot read {} as LAS/LAZ: {e}", path.display()))
}

fn origin(header: &las::Header) -> Vector3<f64> {
    let b = header.bounds();
    let c = Vector3::new(
        0.5 * (b.min.x + b.max.x),
        0.5 * (b.min.y + b.max.y),
        0.5 * (b.min.z + b.max.z),
    );
    // Round so the origin reads well in a log; any point near the cloud keeps f32 precision.
    if c.iter().all(|v| v.is_finite()) {
        c.map(|v| v.round())
    } else {
        Vector3::zeros()
    }
}

pub fn scans(path: &Path) -> Result<Vec<ScanInfo>> {
    let reader = open(path)?;
    let header = reader.header();
    Ok(vec![ScanInfo {
        index: 0,
        name: super::stem(path),
        points: Some(header.number_of_points()),
        offset: 0,
        first_line: 0,
        pose: Some((
            Isometry3::translation(origin(header).x, origin(header).y, origin(header).z),
            PoseSource::FileFrame,
        )),
    }])
}

pub fn stream(
    path: &Path,
    _info: &ScanInfo,
    chunk: usize,
    sink: &mut dyn FnMut(&[ScanPoint]) -> Result<()>,
) -> Result<ReadNotes> {
    let mut reader = open(path)?;
    let o = origin(reader.header());
    let mut data = las::PointDataBuilder::new()
        .for_header(reader.header())
        .build();
    let mut out = Batcher::new(chunk, sink);
    loop {
        let n = reader
            .fill_points(chunk as u64, &mut data)
            .map_err(|e| anyhow::anyhow!("cannot read the points of {}: {e}", path.display()))?;
        if n == 0 {
            break;
        }
        for p in data.points() {
            let p = p.map_err(|e| anyhow::anyhow!("{}: bad point: {e}", path.display()))?;
            let mut sp = ScanPoint::new((p.x - o.x) as f32, (p.y - o.y) as f32, (p.z - o.z) as f32);
            sp.intensity = p.intensity as f32 / 65535.0;
            let (r, n) = (p.return_number.min(15), p.number_of_returns.min(15));
            sp.returns = r | (n << 4);
            out.push(sp)?;
        }
    }
    out.finish()?;
    Ok(ReadNotes::default())
}
