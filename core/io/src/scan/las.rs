//! LAS and LAZ through the `las` crate. Points are in the file's (often georeferenced) frame;
//! they are read relative to the header's bounds centre, which the pose restores.

use std::path::Path;

use super::error::{Result, ScanError, bail};
use asbuilt_protocol::ScanPoint;
use nalgebra::{Isometry3, Vector3};

use super::{Batcher, PoseSource, ReadNotes, ScanInfo, Sink};

/// The reader, after the checks on the raw header that the `las` and `laz` crates do not make,
/// and the file's size.
fn open(path: &Path) -> Result<(las::Reader, u64)> {
    let mut raw = Raw::open(path)?;
    check_evlrs(path, &mut raw)?;
    check_laz_chunk_table(path, &mut raw)?;
    let reader = contain(path, || las::Reader::from_path(path))?.map_err(|e| {
        ScanError::Content(format!("cannot read {} as LAS/LAZ: {e}", path.display()))
    })?;
    check_point_count(path, reader.header(), &raw)?;
    Ok((reader, raw.size))
}

/// The file, its size and the first bytes of its header (up to a LAS 1.4 header's 375), read
/// once for the checks.
struct Raw {
    file: std::fs::File,
    size: u64,
    head: Vec<u8>,
}

impl Raw {
    fn open(path: &Path) -> Result<Self> {
        use std::io::Read;
        let file = std::fs::File::open(path)
            .map_err(|e| ScanError::Content(format!("cannot open {}: {e}", path.display())))?;
        let size = file.metadata()?.len();
        let mut head = Vec::with_capacity(375);
        (&file).take(375).read_to_end(&mut head)?;
        Ok(Self { file, size, head })
    }

    /// The first `n` header bytes of a LAS file; `None` for another file or a shorter one.
    fn las_header(&self, n: usize) -> Option<&[u8]> {
        (self.head.len() >= n && self.head.starts_with(b"LASF")).then(|| &self.head[..n])
    }
}

/// Most points a compressed byte can hold: LAZ makes real scans 5 to 10 times smaller and a
/// cloud of one repeated point a few hundred times.
const LAZ_POINTS_PER_BYTE: u64 = 1000;

/// A header that claims more points than the file's point data can hold is damage: the LAZ
/// decoder would go on making points from nothing (two billion from an 830-byte file).
fn check_point_count(path: &Path, header: &las::Header, raw: &Raw) -> Result<()> {
    let claimed = header.number_of_points();
    let Some(head) = raw.las_header(100) else {
        return Ok(());
    };
    let data = raw
        .size
        .saturating_sub(u64::from(u32::from_le_bytes(head[96..100].try_into()?)));
    let record = u64::from(header.point_format().len()).max(1);
    let room = if header.point_format().is_compressed {
        data.saturating_mul(LAZ_POINTS_PER_BYTE)
    } else {
        data / record
    };
    if claimed > room {
        bail!(
            "{}: the header claims {claimed} points, more than its {data} bytes of point data can \
             hold; the file is damaged or cut short",
            path.display()
        );
    }
    Ok(())
}

/// Runs a call into the LAS/LAZ decoder, which panics on some corrupt compressed data, as an
/// error naming the file.
fn contain<T>(path: &Path, f: impl FnOnce() -> T) -> Result<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|_| {
        ScanError::Content(format!(
            "{}: the LAZ decoder failed on corrupt compressed data; the file is damaged",
            path.display()
        ))
    })
}

/// The `las` crate sizes an extended VLR's buffer from its 64-bit length before it reads it
/// (7.8 EB from one corrupt length). Checks every extended VLR of a LAS 1.4 header against
/// the file's size first.
fn check_evlrs(path: &Path, raw: &mut Raw) -> Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    let damaged =
        |what: String| ScanError::Content(format!("{}: damaged LAS file: {what}", path.display()));
    let size = raw.size;
    let Some(header) = raw.las_header(247).filter(|h| h[25] >= 4) else {
        return Ok(());
    };
    let mut at = u64::from_le_bytes(header[235..243].try_into()?);
    let count = u32::from_le_bytes(header[243..247].try_into()?);
    // An extended VLR's own header: reserved, user id, record id, length, description.
    const EVLR_HEADER: u64 = 2 + 16 + 2 + 8 + 32;
    for i in 0..count {
        if at.saturating_add(EVLR_HEADER) > size {
            return Err(damaged(format!(
                "extended VLR {} of {count} would start at byte {at}, beyond the end ({size} bytes)",
                i + 1
            )));
        }
        let mut len = [0u8; 8];
        raw.file.seek(SeekFrom::Start(at + 20))?;
        raw.file.read_exact(&mut len)?;
        let len = u64::from_le_bytes(len);
        let end = (at + EVLR_HEADER).saturating_add(len);
        if end > size {
            return Err(damaged(format!(
                "extended VLR {} claims {len} bytes, beyond the end of the file ({size} bytes)",
                i + 1
            )));
        }
        at = end;
    }
    Ok(())
}

/// The `laz` crate reserves memory for as many chunks as a LAZ file's chunk table claims (up
/// to 64 GB from one corrupt count) before it reads one. Checks the count against the bytes
/// the chunks could occupy first. Files that are not LAZ, or too short to tell, are left to
/// the reader's own errors.
fn check_laz_chunk_table(path: &Path, raw: &mut Raw) -> Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    let damaged =
        |what: String| ScanError::Content(format!("{}: damaged LAZ file: {what}", path.display()));
    let size = raw.size;
    // Point data format with bit 7 (or 6) set: compressed.
    let Some(header) = raw.las_header(105).filter(|h| h[104] & 0xc0 != 0) else {
        return Ok(());
    };
    let data_start = u64::from(u32::from_le_bytes(header[96..100].try_into()?));
    let f = &mut raw.file;
    let mut read_i64 = |at: SeekFrom| -> Option<i64> {
        let mut b = [0u8; 8];
        f.seek(at).ok()?;
        f.read_exact(&mut b).ok()?;
        Some(i64::from_le_bytes(b))
    };
    let Some(mut table) = read_i64(SeekFrom::Start(data_start)) else {
        return Ok(());
    };
    if table <= data_start as i64 {
        // The writer could not seek back: the offset is at the end of the file.
        match read_i64(SeekFrom::End(-8)) {
            Some(t) if t > data_start as i64 => table = t,
            _ => return Ok(()),
        }
    }
    let table = table as u64;
    if table.saturating_add(8) > size {
        return Err(damaged(format!(
            "its chunk table is said to start at byte {table}, beyond the end ({size} bytes)"
        )));
    }
    let mut counts = [0u8; 8];
    f.seek(SeekFrom::Start(table))?;
    f.read_exact(&mut counts)?;
    let chunks = u64::from(u32::from_le_bytes(counts[4..8].try_into()?));
    // Every chunk holds at least one byte of compressed points.
    let room = table.saturating_sub(data_start + 8);
    if chunks > room {
        return Err(damaged(format!(
            "its chunk table lists {chunks} chunks in {room} bytes of points"
        )));
    }
    Ok(())
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
    let (reader, _) = open(path)?;
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

pub fn stream(path: &Path, _info: &ScanInfo, chunk: usize, sink: &mut Sink) -> Result<ReadNotes> {
    let (mut reader, size) = open(path)?;
    let o = origin(reader.header());
    let mut data = las::PointDataBuilder::new()
        .for_header(reader.header())
        .build();
    let mut out = Batcher::new(chunk, sink);
    // The decoder's buffer is points × record length: a corrupt record length must not make it
    // larger than the file.
    let record = u64::from(reader.header().point_format().len()).max(1);
    let batch = (chunk as u64).min((size / record).max(1));
    loop {
        let n = contain(path, || reader.fill_points(batch, &mut data))?.map_err(|e| {
            ScanError::Content(format!("cannot read the points of {}: {e}", path.display()))
        })?;
        if n == 0 {
            break;
        }
        for p in data.points() {
            let p =
                p.map_err(|e| ScanError::Content(format!("{}: bad point: {e}", path.display())))?;
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
