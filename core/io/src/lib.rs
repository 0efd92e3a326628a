//! Every file format asbuilt reads or writes, in one place: design meshes (STL, OBJ, PLY), read
//! from a path or from bytes (a design attached to a recording), and scans (E57, LAS/LAZ, PTX,
//! PLY, XYZ), streamed in chunks and written back out. Nothing here computes: files become
//! `asbuilt-core` designs and `asbuilt-protocol` scan points; a stations file becomes the
//! scans to inspect with their poses, and a targets file the calibration spheres' centres. The agent's cache of a design with its index
//! ([`index_cache`]) is kept here too, as the one file format that is not for exchange.
//!
//! A design file's units are declared by the caller, never guessed. Every error names the file,
//! the line or record where it can, and what to do.

#![warn(missing_docs)]

mod deviations;
mod error;
pub mod index_cache;
mod mesh;
pub mod ply;
pub mod scan;
pub mod stations;
pub mod targets;

pub use deviations::DeviationsPly;
pub use error::{IoError, error_message};
pub use mesh::{MeshFormat, read_design, read_design_bytes, read_design_file};
pub use scan::{
    DEFAULT_CHUNK, Format, PoseSource, ReadNotes, ScanFile, ScanInfo, Sink, read_cloud,
};
