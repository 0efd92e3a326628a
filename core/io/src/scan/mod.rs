//! Scan files in, point clouds out: what scanners export and what CloudCompare opens.
//!
//! Every reader streams: [`ScanFile::stream`] hands out chunks of at most the asked size, so a
//! 20 M-point file never sits in memory. A file may hold several scans (E57, PTX), each with its
//! own pose; [`ScanInfo::pose`] says where a scan's pose came from, so a station needs no pose of
//! its own in `stations.toml`.
//!
//! Points are `ScanPoint`s: f32 in the scan's own frame. Files written in a world frame (LAS,
//! georeferenced PLY/XYZ are not: they carry no pose) are read relative to a local origin that the
//! pose restores, so f32 keeps its precision far from the origin.

mod e57;
mod las;
mod ply;
mod ptx;
pub mod ros2;
pub mod write;
mod xyz;

use std::path::{Path, PathBuf};

pub(crate) mod error;

use asbuilt_protocol::ScanPoint;
pub use error::{ScanError, SinkError};
use nalgebra::Isometry3;

use crate::IoError;

/// Scan file formats, by extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// ASTM E57 (`.e57`): several scans, each with its pose.
    E57,
    /// ASPRS LAS or LAZ (`.las`, `.laz`): one cloud in a world frame.
    Las,
    /// Leica PTX (`.ptx`): several scans, each with its header's transform.
    Ptx,
    /// PLY (`.ply`): one cloud, no pose.
    Ply,
    /// Text, one point a line (`.xyz`, `.txt`, `.pts`, `.asc`, `.csv`).
    Xyz,
    /// A ROS 2 bag (MCAP or SQLite): clouds placed by its transform tree; opened with
    /// [`ScanFile::of_ros2`], never by extension.
    Ros2,
}

impl Format {
    /// The scan format a file name's extension says.
    pub fn from_path(path: &Path) -> Result<Self, IoError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        Ok(match ext.as_str() {
            "e57" => Format::E57,
            "las" | "laz" => Format::Las,
            "ptx" => Format::Ptx,
            "ply" => Format::Ply,
            "xyz" | "txt" | "pts" | "asc" | "csv" => Format::Xyz,
            _ => {
                return Err(IoError::UnknownFormat {
                    path: path.to_path_buf(),
                    kind: "scan",
                    extension: ext,
                    expected: ".e57, .las/.laz, .ptx, .ply or .xyz/.pts/.txt",
                });
            }
        })
    }
}

/// Where a scan's pose came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseSource {
    /// The E57 point cloud's `pose` element.
    E57,
    /// The PTX scan header's 4 × 4 matrix.
    PtxHeader,
    /// Coordinates already in the file's frame, read relative to a local origin.
    FileFrame,
    /// A ROS 2 bag's transform tree at the station's first cloud's stamp.
    Ros2Tf,
}

impl PoseSource {
    /// Where the pose came from, as a station line says it.
    pub fn describe(self) -> &'static str {
        match self {
            PoseSource::E57 => "the E57 scan pose",
            PoseSource::PtxHeader => "the PTX header's transform",
            PoseSource::FileFrame => "the file's own frame (points already registered)",
            PoseSource::Ros2Tf => "the bag's transform tree at the cloud's stamp",
        }
    }
}

/// One scan inside a file.
#[derive(Debug, Clone)]
pub struct ScanInfo {
    /// The scan's position in the file, from 0.
    pub index: usize,
    /// The scan's name in the file, or one made from the file's name.
    pub name: String,
    /// Points the file declares for this scan, if it declares them.
    pub points: Option<u64>,
    /// `p_file = pose · p_scan`, when the file says where the scan was taken.
    pub pose: Option<(Isometry3<f64>, PoseSource)>,
    /// Where the scan starts in the file (PTX: the byte offset of its header, and the lines
    /// before it).
    offset: u64,
    first_line: u64,
}

/// What a reader had to leave out or flag, besides the points it handed out.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct ReadNotes {
    /// Lines (text formats) that could not be read as a point, left out.
    pub malformed_lines: u64,
    /// The first of those lines, 1-based.
    pub first_malformed_line: Option<u64>,
    /// Points the scanner marked invalid (no return); handed out flagged, never dropped.
    pub invalid: u64,
}

impl ReadNotes {
    fn malformed(&mut self, line: u64) {
        self.malformed_lines += 1;
        self.first_malformed_line.get_or_insert(line);
    }
}

/// A scan file opened for reading: its format and the scans it holds, read point by point
/// only when streamed.
pub struct ScanFile {
    /// The file as given.
    pub path: PathBuf,
    /// The format its extension says.
    pub format: Format,
    /// The scans it holds, in file order.
    pub scans: Vec<ScanInfo>,
    /// The bag behind a [`Format::Ros2`] file.
    pub(crate) bag: Option<std::sync::Arc<ros2::Ros2Bag>>,
}

/// A reader's error, with the file it is about.
fn naming(path: &Path, cause: ScanError) -> IoError {
    IoError::Scan {
        path: path.to_path_buf(),
        cause,
    }
}

/// Where a reader hands each chunk of points; an error it returns ends the read.
pub type Sink<'s> = dyn FnMut(&[ScanPoint]) -> Result<(), SinkError> + 's;

/// The chunk size used when a caller has no reason to pick another.
pub const DEFAULT_CHUNK: usize = 1 << 16;

impl ScanFile {
    /// Reads the file's headers: which scans it holds, their sizes and poses.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        IoError::require_file(path, "scan")?;
        let format = Format::from_path(path)?;
        let scans = match format {
            Format::E57 => e57::scans(path),
            Format::Las => las::scans(path),
            Format::Ptx => ptx::scans(path),
            Format::Ply => ply::scans(path),
            Format::Xyz => Ok(xyz::scans(path)),
            Format::Ros2 => Err(ScanError::Content(
                "a ROS 2 bag is read with its options (--ros2)".into(),
            )),
        }
        .map_err(|e| naming(path, e))?;
        Ok(Self {
            path: path.to_path_buf(),
            format,
            scans,
            bag: None,
        })
    }

    /// A ROS 2 bag at `path`, opened already: its stations are the scans.
    pub fn of_ros2(path: &Path, bag: std::sync::Arc<ros2::Ros2Bag>) -> Self {
        Self {
            path: path.to_path_buf(),
            format: Format::Ros2,
            scans: bag.scans(),
            bag: Some(bag),
        }
    }

    /// Hands scan `index`'s points to `sink` in chunks of at most `chunk` points. An error of
    /// the sink ends the read and comes back as the reader's.
    pub fn stream(
        &self,
        index: usize,
        chunk: usize,
        sink: &mut Sink,
    ) -> Result<ReadNotes, IoError> {
        let chunk = chunk.max(1);
        let Some(info) = self.scans.get(index) else {
            return Err(naming(
                &self.path,
                ScanError::Content(format!(
                    "{} holds {} scan(s); there is no scan {index}",
                    self.path.display(),
                    self.scans.len()
                )),
            ));
        };
        match self.format {
            Format::E57 => e57::stream(&self.path, info, chunk, sink),
            Format::Las => las::stream(&self.path, info, chunk, sink),
            Format::Ptx => ptx::stream(&self.path, info, chunk, sink),
            Format::Ply => ply::stream(&self.path, chunk, sink),
            Format::Xyz => xyz::stream(&self.path, chunk, sink),
            Format::Ros2 => match &self.bag {
                Some(bag) => bag.stream(index, chunk, sink),
                None => Err(ScanError::Content(
                    "a ROS 2 bag opened without its reader".into(),
                )),
            },
        }
        .map_err(|e| naming(&self.path, e))
    }

    /// [`ScanFile::stream`] with the parsing on a thread of its own, `ahead` chunks ahead of
    /// `sink`: the file is read while the chunk before is used, instead of leaving a core idle
    /// in turn. Same chunks in the same order; memory `ahead + 2` chunks.
    pub fn stream_ahead(
        &self,
        index: usize,
        chunk: usize,
        ahead: usize,
        sink: &mut Sink,
    ) -> Result<ReadNotes, IoError> {
        let (full_tx, full_rx) = std::sync::mpsc::sync_channel::<Vec<ScanPoint>>(ahead);
        // Chunks the sink is done with go back to the reader, so no chunk is allocated twice.
        let (empty_tx, empty_rx) = std::sync::mpsc::channel::<Vec<ScanPoint>>();
        std::thread::scope(|scope| {
            let reader = scope.spawn(move || {
                self.stream(index, chunk, &mut |points| {
                    let mut v = empty_rx.try_recv().unwrap_or_default();
                    v.clear();
                    v.extend_from_slice(points);
                    // The receiver is gone only when the sink failed: stop reading.
                    full_tx
                        .send(v)
                        .map_err(|_| ScanError::Content("the reading was stopped".into()).into())
                })
            });
            let mut failed = None;
            for points in full_rx.iter() {
                if let Err(e) = sink(&points) {
                    failed = Some(e);
                    break;
                }
                // Nobody listens once the reader is done.
                let _ = empty_tx.send(points);
            }
            // Dropping the receiver (after a failure) makes the reader's next send fail.
            drop(full_rx);
            let read = reader.join().map_err(|_| {
                naming(
                    &self.path,
                    ScanError::Content("the reader stopped unexpectedly".into()),
                )
            });
            match failed {
                Some(e) => Err(naming(&self.path, ScanError::Sink(e))),
                None => read?,
            }
        })
    }

    /// A ROS 2 bag read with `options` (see [`ros2`]): its stations as scans. What was found is
    /// said on stderr.
    pub fn open_ros2(path: &Path, options: &ros2::Ros2Options) -> Result<Self, IoError> {
        let bag = ros2::Ros2Bag::open(path, options).map_err(|cause| naming(path, cause))?;
        eprintln!("ROS 2 bag {}: {}", path.display(), bag.describe());
        Ok(Self::of_ros2(path, std::sync::Arc::new(bag)))
    }

    /// The valid points of one scan in its frame at f64, in memory, and what the reader left
    /// out: for sphere targets and reference clouds, not for scans to inspect.
    pub fn valid_points(
        &self,
        index: usize,
    ) -> Result<(Vec<nalgebra::Point3<f64>>, ReadNotes), IoError> {
        let mut out = Vec::new();
        let notes = self.stream(index, DEFAULT_CHUNK, &mut |chunk| {
            out.extend(
                chunk
                    .iter()
                    .filter(|p| !p.flags.is_invalid() && p.xyz.iter().all(|v| v.is_finite()))
                    .map(|p| {
                        nalgebra::Point3::new(p.xyz[0] as f64, p.xyz[1] as f64, p.xyz[2] as f64)
                    }),
            );
            Ok(())
        })?;
        Ok((out, notes))
    }

    /// Every point of one scan in memory: for small files and tests.
    pub fn read_all(&self, index: usize) -> Result<(Vec<ScanPoint>, ReadNotes), IoError> {
        let mut all = Vec::new();
        let notes = self.stream(index, DEFAULT_CHUNK, &mut |c| {
            all.extend_from_slice(c);
            Ok(())
        })?;
        Ok((all, notes))
    }
}

/// A reference cloud in the file's frame at f64: every valid point of every scan, placed by the
/// scan's pose when the file holds one. In memory: for reference clouds, not for scans.
pub fn read_cloud(path: &Path) -> Result<(Vec<nalgebra::Point3<f64>>, ReadNotes), IoError> {
    let file = ScanFile::open(path)?;
    let mut out = Vec::new();
    let mut notes = ReadNotes::default();
    for info in &file.scans {
        let pose = info.pose.map(|p| p.0).unwrap_or_else(Isometry3::identity);
        let (points, n) = file.valid_points(info.index)?;
        out.extend(points.into_iter().map(|p| pose * p));
        notes.malformed_lines += n.malformed_lines;
        notes.invalid += n.invalid;
        if notes.first_malformed_line.is_none() {
            notes.first_malformed_line = n.first_malformed_line;
        }
    }
    if out.is_empty() {
        return Err(naming(
            path,
            ScanError::Content(format!("cloud {} has no valid point", path.display())),
        ));
    }
    Ok((out, notes))
}

/// A single-scan file's scan name: its file name without the extension.
fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// A chunk buffer that hands itself to `sink` whenever it is full.
struct Batcher<'a> {
    buf: Vec<ScanPoint>,
    chunk: usize,
    sink: &'a mut Sink<'a>,
}

impl<'a> Batcher<'a> {
    fn new(chunk: usize, sink: &'a mut Sink<'a>) -> Self {
        Self {
            buf: Vec::with_capacity(chunk),
            chunk,
            sink,
        }
    }

    #[inline]
    fn push(&mut self, p: ScanPoint) -> error::Result<()> {
        self.buf.push(p);
        if self.buf.len() == self.chunk {
            (self.sink)(&self.buf)?;
            self.buf.clear();
        }
        Ok(())
    }

    fn finish(mut self) -> error::Result<()> {
        if !self.buf.is_empty() {
            (self.sink)(&self.buf)?;
            self.buf.clear();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
