//! The printer's answer to the advice: what it applied to a layer it printed. The advice is the
//! agent's and the cell decides (`correction.rs`); the agent learns from this message what was
//! decided, and estimates the process from what was printed, not from what it advised.

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::message::Message;

/// What the printer applied to one layer, sent once the layer is printed (cell to agent).
/// Nominal is a zero z offset, flow 1 and no path offset; a layer printed without advice is
/// sent as nominal, or not at all (the agent then assumes nominal and says so).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.LayerApplied.v1")]
#[repr(C)]
pub struct LayerApplied {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// Zero; keeps the layout free of padding.
    pub _reserved: u16,
    /// The layer printed, from 0.
    pub layer: u32,
    /// The job (one print) the layer belongs to.
    pub job: u64,
    /// When the layer was printed, nanoseconds since the Unix epoch.
    pub timestamp_ns: u64,
    /// The layer of the advice followed (its `LayerCorrection::layer`), or [`u32::MAX`] when
    /// the layer was printed without advice.
    pub advice_layer: u32,
    /// Zero; keeps the layout free of padding.
    pub _reserved2: u32,
    /// Metres the layer was printed thicker than nominal (negative: thinner).
    pub z_offset: f64,
    /// The flow the layer was printed at, as a factor on the nominal.
    pub flow: f64,
    /// Metres the layer's path was moved by, x and y, design frame.
    pub path_offset: [f64; 2],
}

crate::message::message!(LayerApplied, "asbuilt.LayerApplied.v1", 1);

impl LayerApplied {
    /// Layer `layer` of `job` printed as designed, without advice.
    pub fn nominal(job: u64, layer: u32) -> Self {
        Self {
            version: Self::VERSION,
            _reserved: 0,
            layer,
            job,
            timestamp_ns: 0,
            advice_layer: u32::MAX,
            _reserved2: 0,
            z_offset: 0.0,
            flow: 1.0,
            path_offset: [0.0; 2],
        }
    }

    /// Whether the values are usable: finite, and a positive flow.
    pub fn is_valid(&self) -> bool {
        self.z_offset.is_finite()
            && self.flow.is_finite()
            && self.flow > 0.0
            && self.path_offset.iter().all(|v| v.is_finite())
    }
}
