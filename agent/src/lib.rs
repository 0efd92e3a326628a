//! The asbuilt edge agent: it serves scan chunks, poses and station events over iceoryx2, turns
//! every chunk into deviations as it arrives, and closes each station with a report.
//!
//! Layers, from the outside in: [`daemon`] runs the event loop over the cell's services
//! ([`asbuilt_protocol::ipc`]), with `fanout` sending results to the cell, the recorder and
//! the view, and recording what comes in; [`lifecycle`]
//! decides what each message means for its station, with [`sequence`] doing the chunk
//! bookkeeping, and [`findings`] turning each scan layer's stations into findings a crew can act
//! on; [`recorder`] writes everything to MCAP on a thread of its own; the geometry is
//! `asbuilt-core`'s.

#![warn(missing_docs)]

pub mod attempts;
pub mod config;
pub mod daemon;
pub mod design;
mod error;
mod fanout;
pub mod findings;
pub mod lifecycle;
pub mod log;
pub mod recorder;
pub mod replay;
pub mod resume;
pub mod sequence;
pub mod survey;

pub use config::AgentConfig;
pub use sequence::{ChunkVerdict, SequenceTracker};
