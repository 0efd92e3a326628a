//! Advice for the layers still to print, sent after each scan layer's findings: a z offset per
//! layer, a flow factor and a lateral path offset, each with the evidence it rests on.
//!
//! The advice is the agent's; the cell decides whether to apply it. It is cumulative: each
//! message replaces the one before, from its `from_layer` on, and says the whole correction
//! against the nominal print (not a change to the last advice).

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::message::Message;

/// A measured quantity a correction rests on. Metres; NaN where it was not measured.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
pub struct Evidence {
    /// The measured error (as built minus design), or the x component of a shift.
    pub value: f64,
    /// The y component of a shift; NaN for a scalar.
    pub value_y: f64,
    /// The measurement's one-sigma uncertainty.
    pub sigma: f64,
    /// Design samples behind the value.
    pub samples: u32,
    /// Layer bands behind the value (1 for the top).
    pub bands: u32,
}

impl Evidence {
    /// Nothing measured.
    pub const NONE: Evidence = Evidence {
        value: f64::NAN,
        value_y: f64::NAN,
        sigma: f64::NAN,
        samples: 0,
        bands: 0,
    };

    /// Whether anything was measured.
    pub fn is_measured(&self) -> bool {
        self.samples > 0 && self.value.is_finite()
    }
}

/// Why a value of a [`LayerCorrection`] is what it is; bits of [`LayerCorrection::flags`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CorrectionFlags(pub u32);

impl CorrectionFlags {
    /// The top's error and its change stayed inside the deadband: the z advice was held.
    pub const Z_HELD: u32 = 1 << 0;
    /// The z offset reached the largest allowed per layer and was clamped.
    pub const Z_CLAMPED: u32 = 1 << 1;
    /// The top was not seen: the z advice goes on from the earlier estimate of the drift.
    pub const Z_UNSEEN: u32 = 1 << 2;
    /// The width error stayed inside the deadband: the flow advice was held.
    pub const FLOW_HELD: u32 = 1 << 3;
    /// The flow factor reached the configured range and was clamped.
    pub const FLOW_CLAMPED: u32 = 1 << 4;
    /// No width was measured on the latest bands, or no bead width is configured: the flow
    /// advice was held.
    pub const FLOW_UNSEEN: u32 = 1 << 5;
    /// The shift stayed inside the deadband: the path advice was held.
    pub const PATH_HELD: u32 = 1 << 6;
    /// The path offset reached the largest allowed and was clamped.
    pub const PATH_CLAMPED: u32 = 1 << 7;
    /// No shift was measured on the latest bands: the path advice was held.
    pub const PATH_UNSEEN: u32 = 1 << 8;
    /// The printer did not say what it applied to some layers printed under the advice before
    /// ([`crate::LayerApplied`]): they were taken as printed as designed.
    pub const UNANSWERED: u32 = 1 << 9;

    /// Every flag with its name as reports spell it, in bit order.
    pub const NAMES: [(u32, &'static str); 10] = [
        (Self::Z_HELD, "z_held"),
        (Self::Z_CLAMPED, "z_clamped"),
        (Self::Z_UNSEEN, "z_unseen"),
        (Self::FLOW_HELD, "flow_held"),
        (Self::FLOW_CLAMPED, "flow_clamped"),
        (Self::FLOW_UNSEEN, "flow_unseen"),
        (Self::PATH_HELD, "path_held"),
        (Self::PATH_CLAMPED, "path_clamped"),
        (Self::PATH_UNSEEN, "path_unseen"),
        (Self::UNANSWERED, "unanswered"),
    ];

    /// Whether flag `bit` (one of the constants above) is set.
    pub fn contains(self, bit: u32) -> bool {
        self.0 & bit != 0
    }

    /// The names of the flags set, in bit order (bits no flag names are left out).
    pub fn names(self) -> Vec<&'static str> {
        Self::NAMES
            .iter()
            .filter(|(bit, _)| self.contains(*bit))
            .map(|(_, name)| *name)
            .collect()
    }
}

/// What the agent advises for the layers still to print, after a station's findings.
///
/// For a layer `j` from `from_layer` on: print it `z_offset(j)` metres thicker (negative:
/// thinner) than nominal, at `flow` times the nominal flow, with its path moved by
/// `path_offset` in the design frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.LayerCorrection.v1")]
#[repr(C)]
pub struct LayerCorrection {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// The attempt of the station whose findings it follows.
    pub attempt: u8,
    /// Zero; keeps the layout free of padding.
    pub _reserved: u8,
    /// The station whose findings it follows.
    pub station: u32,
    /// The job (one print).
    pub job: u64,
    /// The last printed layer of the scan layer measured, 0-based.
    pub layer: u32,
    /// The first layer the advice is for: the next one printed.
    pub from_layer: u32,
    /// Layers, from `from_layer`, that take `z_first`; later ones take `z_then`.
    pub first_layers: u32,
    /// [`CorrectionFlags`] bits.
    pub flags: u32,
    /// Metres per layer for the first `first_layers` layers: the drift fed forward plus the
    /// accumulated top error spread over them.
    pub z_first: f64,
    /// Metres per layer after those: the drift fed forward.
    pub z_then: f64,
    /// The process drift per layer the agent estimates (top height gained per layer beyond
    /// nominal, without corrections), metres.
    pub drift_per_layer: f64,
    /// Factor on the nominal flow (1: nominal).
    pub flow: f64,
    /// Metres to move the path by, x and y, design frame.
    pub path_offset: [f64; 2],
    /// The top's height error (top of the print minus the printed height).
    pub top: Evidence,
    /// The width error over the latest bands (median).
    pub width: Evidence,
    /// The shift over the latest bands (median per component).
    pub shift: Evidence,
}
crate::message::message!(LayerCorrection, "asbuilt.LayerCorrection.v1", 1);

impl Default for LayerCorrection {
    fn default() -> Self {
        Self::neutral(0, 0, 1, 0)
    }
}

impl LayerCorrection {
    /// No correction: nominal height, flow and path, from the layer after `layer`.
    pub fn neutral(job: u64, station: u32, attempt: u8, layer: u32) -> Self {
        Self {
            version: Self::VERSION,
            attempt,
            _reserved: 0,
            station,
            job,
            layer,
            from_layer: layer.saturating_add(1),
            first_layers: 0,
            flags: 0,
            z_first: 0.0,
            z_then: 0.0,
            drift_per_layer: 0.0,
            flow: 1.0,
            path_offset: [0.0; 2],
            top: Evidence::NONE,
            width: Evidence::NONE,
            shift: Evidence::NONE,
        }
    }

    /// The flags, typed.
    pub fn flags(&self) -> CorrectionFlags {
        CorrectionFlags(self.flags)
    }

    /// Metres to add to layer `j`'s height; 0 before `from_layer`.
    pub fn z_offset(&self, j: u32) -> f64 {
        if j < self.from_layer {
            0.0
        } else if j - self.from_layer < self.first_layers {
            self.z_first
        } else {
            self.z_then
        }
    }

    /// The sum of [`LayerCorrection::z_offset`] over layers `a..b`.
    pub fn z_over(&self, a: u32, b: u32) -> f64 {
        let a = a.max(self.from_layer);
        if b <= a {
            return 0.0;
        }
        let first_end = self.from_layer.saturating_add(self.first_layers);
        let first = b.min(first_end).saturating_sub(a);
        let then = (b - a) - first;
        first as f64 * self.z_first + then as f64 * self.z_then
    }

    /// Whether the advice is to print as designed.
    pub fn is_neutral(&self) -> bool {
        self.z_first == 0.0
            && self.z_then == 0.0
            && self.flow == 1.0
            && self.path_offset == [0.0, 0.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec;

    #[test]
    fn the_z_schedule_sums_as_its_layers_do_and_the_message_round_trips() {
        let mut c = LayerCorrection::neutral(7, 3, 2, 23);
        c.first_layers = 4;
        c.z_first = -0.001;
        c.z_then = -0.0005;
        assert_eq!(c.from_layer, 24);
        assert_eq!(c.z_offset(23), 0.0);
        assert_eq!(c.z_offset(27), -0.001);
        assert_eq!(c.z_offset(28), -0.0005);
        for (a, b) in [(0, 40), (20, 26), (24, 28), (26, 31), (30, 30), (31, 29)] {
            let brute: f64 = (a..b).map(|j| c.z_offset(j)).sum();
            assert!((c.z_over(a, b) - brute).abs() < 1e-15, "{a}..{b}");
        }
        assert!(!c.is_neutral());
        let back: LayerCorrection = codec::decode(&codec::encode(&c)).unwrap();
        assert_eq!(back.z_first, c.z_first);
        assert!(back.top.value.is_nan());
        assert!(LayerCorrection::neutral(1, 1, 1, 0).is_neutral());
    }

    #[test]
    fn flags_read_as_names_in_bit_order() {
        let f = CorrectionFlags(
            CorrectionFlags::PATH_UNSEEN | CorrectionFlags::Z_HELD | CorrectionFlags::FLOW_CLAMPED,
        );
        assert_eq!(f.names(), ["z_held", "flow_clamped", "path_unseen"]);
        assert!(CorrectionFlags(0).names().is_empty());
        // Every bit has one name, each name once.
        let all = CorrectionFlags::NAMES.iter().fold(0, |a, (bit, _)| a | bit);
        assert_eq!(all.count_ones() as usize, CorrectionFlags::NAMES.len());
        assert_eq!(
            CorrectionFlags(all).names().len(),
            CorrectionFlags::NAMES.len()
        );
    }
}
