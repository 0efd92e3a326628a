//! Pure, synchronous geometry and statistics for asbuilt, shared by the agent and the offline
//! tools. No file I/O (design and scan files are `asbuilt-io`'s, in `core/io`); no logging.

#![warn(missing_docs)]

pub mod c2m;
pub mod design;
pub mod frames;
pub mod station;
pub mod stats;

pub use c2m::{C2mIndex, C2mParams, Closest, Cursor, Surface};
pub use design::{Design, DesignError, MeshReport, Units};
pub mod c2c;
pub mod calibration;
pub mod cells;
pub mod cloud;
pub mod colour;
pub mod corrections;
pub mod coverage;
pub mod findings;
pub mod flatness;
pub mod layers;
pub mod m3c2;
mod order;
pub mod printed;
pub mod probes;
pub mod profiler;
pub mod sampling;
pub mod scan_layer;
mod simd;
#[cfg(test)]
mod test_points;
pub mod verdict;
