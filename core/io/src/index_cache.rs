//! A design with its C2M index, kept in a file between runs of the agent, so that a restart
//! takes them up instead of reading and indexing the design again (a million-triangle design
//! takes seconds to index, which a restart after a crash cannot spare).
//!
//! The file is the agent's own cache, not an exchange format: it holds the index as this build
//! lays it out, and is used only by the build that wrote it, for the same design bytes, units
//! and index parameters. Anything else is a miss, and the caller indexes the design as on a
//! first start. Layout: a header (magic, format, key, payload length, payload SHA-256) and the
//! postcard encoding of the design and its index. The checksum is verified before a byte is
//! decoded, so a torn or damaged file is a miss, never a wrong index.

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use asbuilt_core::{C2mIndex, C2mParams, Design, Units};
use sha2::{Digest, Sha256};

const MAGIC: &[u8; 16] = b"asbuilt-index\n\0\0";
/// Bumped when the header changes; the payload's layout is tied to the build by the key.
const FORMAT: u32 = 1;
const HEADER: usize = 16 + 4 + 32 + 8 + 32;

/// Why a cache file was not used. Every case leaves the caller to index the design itself.
#[derive(Debug, thiserror::Error)]
pub enum CacheMiss {
    /// No cache file yet (a first start).
    #[error("no index cache at {0} yet")]
    Absent(PathBuf),
    /// The file is for another design, other units or parameters, or another build.
    #[error("the index cache at {0} is for another design, parameters or build")]
    Stale(PathBuf),
    /// The file cannot be read, is cut short or fails its checksum.
    #[error("the index cache at {path} is damaged ({what}); it is written again")]
    Damaged {
        /// The cache file.
        path: PathBuf,
        /// What was wrong with it.
        what: String,
    },
}

/// Where a design's index is cached, and the key that a cached file must carry.
#[derive(Debug, Clone)]
pub struct IndexCache {
    path: PathBuf,
    key: [u8; 32],
}

impl IndexCache {
    /// The cache at `path` for the design file's `bytes`, read in `units` and indexed with
    /// `params` by this very build (the running executable's size and time stamp).
    pub fn new(path: PathBuf, design_bytes: &[u8], units: Units, params: &C2mParams) -> Self {
        let mut h = Sha256::new();
        h.update(FORMAT.to_le_bytes());
        h.update(env!("CARGO_PKG_VERSION").as_bytes());
        h.update(build_identity());
        h.update(units.scale().to_bits().to_le_bytes());
        h.update(params.max_distance.to_bits().to_le_bytes());
        h.update(params.cell_size.map_or(0, f64::to_bits).to_le_bytes());
        h.update((design_bytes.len() as u64).to_le_bytes());
        h.update(design_bytes);
        Self {
            path,
            key: h.finalize().into(),
        }
    }

    /// The cache file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The design and its index as cached, when the file is this key's and whole.
    pub fn load(&self) -> Result<(Design, C2mIndex), CacheMiss> {
        let damaged = |what: String| CacheMiss::Damaged {
            path: self.path.clone(),
            what,
        };
        let mut file = match File::open(&self.path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(CacheMiss::Absent(self.path.clone()));
            }
            Err(e) => return Err(damaged(e.to_string())),
        };
        let size = file.metadata().map_err(|e| damaged(e.to_string()))?.len();
        let mut header = [0u8; HEADER];
        file.read_exact(&mut header)
            .map_err(|_| damaged(format!("{size} bytes, shorter than its header")))?;
        let (magic, rest) = header.split_at(16);
        let (format, rest) = rest.split_at(4);
        let (key, rest) = rest.split_at(32);
        let (len, sum) = rest.split_at(8);
        if magic != MAGIC {
            return Err(damaged("not an asbuilt index cache".into()));
        }
        if format != FORMAT.to_le_bytes() || key != self.key {
            return Err(CacheMiss::Stale(self.path.clone()));
        }
        let len = u64::from_le_bytes(len.try_into().expect("8 bytes"));
        // The payload's length is checked against the file before anything is allocated.
        if size != HEADER as u64 + len {
            return Err(damaged(format!(
                "{size} bytes where its header promises {}",
                HEADER as u64 + len
            )));
        }
        let mut payload = Vec::with_capacity(len as usize);
        file.read_to_end(&mut payload)
            .map_err(|e| damaged(e.to_string()))?;
        if Sha256::digest(&payload).as_slice() != sum {
            return Err(damaged("its checksum does not match".into()));
        }
        postcard::from_bytes(&payload).map_err(|e| damaged(e.to_string()))
    }

    /// Writes the design and its index for this key, through a file beside the cache that is
    /// renamed over it once whole, so a crash mid-write leaves the old cache or none. Returns
    /// the bytes written.
    pub fn store(&self, design: &Design, index: &C2mIndex) -> Result<u64, std::io::Error> {
        let tmp = self.path.with_extension("writing");
        let result = self.write(&tmp, design, index);
        match result {
            Ok(len) => std::fs::rename(&tmp, &self.path).map(|()| len),
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                Err(e)
            }
        }
    }

    fn write(&self, tmp: &Path, design: &Design, index: &C2mIndex) -> std::io::Result<u64> {
        let mut file = File::create(tmp)?;
        file.write_all(&[0; HEADER])?;
        // Streamed through the hash: the payload is never held whole beside the index.
        let mut out = Hashing {
            inner: BufWriter::with_capacity(1 << 20, file),
            hash: Sha256::new(),
            len: 0,
        };
        postcard::to_io(&(design, index), &mut out).map_err(std::io::Error::other)?;
        let Hashing { inner, hash, len } = out;
        let mut file = inner.into_inner().map_err(|e| e.into_error())?;
        let sum = hash.finalize();
        file.seek(SeekFrom::Start(0))?;
        file.write_all(MAGIC)?;
        file.write_all(&FORMAT.to_le_bytes())?;
        file.write_all(&self.key)?;
        file.write_all(&len.to_le_bytes())?;
        file.write_all(&sum)?;
        file.sync_all()?;
        Ok(HEADER as u64 + len)
    }
}

/// The running executable's size and modification time: the index's layout is its build's.
fn build_identity() -> Vec<u8> {
    let meta = std::env::current_exe().and_then(std::fs::metadata);
    let mut id = Vec::new();
    if let Ok(m) = meta {
        id.extend(m.len().to_le_bytes());
        if let Ok(t) = m.modified()
            && let Ok(d) = t.duration_since(std::time::UNIX_EPOCH)
        {
            id.extend(d.as_nanos().to_le_bytes());
        }
    }
    id
}

struct Hashing<W> {
    inner: W,
    hash: Sha256,
    len: u64,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash.update(&buf[..n]);
        self.len += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use asbuilt_core::Cursor;
    use asbuilt_core::design::shapes::twisted_column;
    use nalgebra::Vector3;

    fn column() -> (Design, Vec<u8>) {
        let d = twisted_column(0.15, 0.1, 0.4, 45.0, 60, 40);
        // The key hashes the design file; any bytes stand for it here.
        let bytes = format!("{:?}", d.triangles).into_bytes();
        (d, bytes)
    }

    #[test]
    fn a_stored_index_loads_and_answers_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let (design, bytes) = column();
        let params = C2mParams::within(0.01);
        let index = C2mIndex::build(&design, params).unwrap();
        let cache = IndexCache::new(
            dir.path().join("design.index"),
            &bytes,
            Units::Metres,
            &params,
        );
        assert!(matches!(cache.load(), Err(CacheMiss::Absent(_))));
        let written = cache.store(&design, &index).unwrap();
        assert_eq!(written, std::fs::metadata(cache.path()).unwrap().len());
        let (d2, i2) = cache.load().unwrap();
        assert_eq!(d2.vertices, design.vertices);
        assert_eq!(d2.triangles, design.triangles);
        assert_eq!(d2.report, design.report);
        let (mut c1, mut c2) = (Cursor::default(), Cursor::default());
        let mut n = 0;
        for (i, v) in design.vertices.iter().enumerate() {
            // Around every vertex, inside the band and beyond it.
            let t = i as f64;
            let p = v + Vector3::new((t * 0.37).sin(), (t * 0.11).cos(), (t * 0.7).sin()) * 0.012;
            let (a, b) = (index.query(&p, &mut c1), i2.query(&p, &mut c2));
            assert_eq!(format!("{a:?}"), format!("{b:?}"), "point {p}");
            n += usize::from(a.is_some());
        }
        assert!(n > design.vertices.len() / 2, "{n} matched");
        let (x, y) = (index.stats(), i2.stats());
        assert_eq!(
            (x.cells, x.candidates, x.bvh_cells),
            (y.cells, y.candidates, y.bvh_cells)
        );
        assert_eq!(x.cell_size.to_bits(), y.cell_size.to_bits());
    }

    #[test]
    fn another_design_or_parameters_are_stale_and_damage_is_found() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("design.index");
        let (design, bytes) = column();
        let params = C2mParams::within(0.01);
        let index = C2mIndex::build(&design, params).unwrap();
        IndexCache::new(path.clone(), &bytes, Units::Metres, &params)
            .store(&design, &index)
            .unwrap();
        let stale = [
            IndexCache::new(path.clone(), b"other", Units::Metres, &params),
            IndexCache::new(path.clone(), &bytes, Units::Millimetres, &params),
            IndexCache::new(
                path.clone(),
                &bytes,
                Units::Metres,
                &C2mParams::within(0.02),
            ),
        ];
        for cache in stale {
            assert!(matches!(cache.load(), Err(CacheMiss::Stale(_))));
        }
        let cache = IndexCache::new(path.clone(), &bytes, Units::Metres, &params);
        let whole = std::fs::read(&path).unwrap();
        // Cut short, one bit flipped in the payload, or not a cache at all.
        let mut flipped = whole.clone();
        flipped[HEADER + whole.len() / 3] ^= 4;
        for bad in [&whole[..whole.len() - 7], &flipped[..], b"not an index"] {
            std::fs::write(&path, bad).unwrap();
            let miss = cache.load().err().unwrap();
            assert!(matches!(miss, CacheMiss::Damaged { .. }), "{miss}");
        }
    }
}
