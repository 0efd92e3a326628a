//! The asbuilt edge agent. This crate will hold the iceoryx2 event loop, the station lifecycle,
//! the recorder and the viewer link (issue 4 onwards). What exists so far is the bookkeeping of
//! a station's chunk stream, which the event loop feeds and the station report reads.

pub mod sequence;

pub use sequence::{ChunkVerdict, SequenceTracker};
