//! A surveyor's judgement of a scan layer so far, sent after a station's report when
//! `[tolerances]` names a standard: the faces' flatness under a virtual straightedge (DIN 18202
//! Table 3, ACI 117) and the element's dimensions and plumb (DIN 18202 Tables 1 and 2).
//!
//! Variable in size, so on iceoryx2 it travels as its postcard encoding behind a
//! [`crate::FindingsHeader`], as the findings do; the same bytes are the MCAP record.

use serde::{Deserialize, Serialize};

use crate::message::Message;
use crate::text::FixedText;

/// Gaps, dimensions and plumb rows a [`SurfaceFindings`] holds at most.
pub const MAX_SURVEY_ROWS: usize = 128;
/// Upper bound of an encoded [`SurfaceFindings`], bytes.
pub const MAX_SURVEY_BYTES: usize = 32 * 1024;

/// How a judged quantity stands against its limit (a standard's, or the crew's for findings),
/// by the job's decision rule; worst last, so that the worst of several ignores what was not
/// judged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub enum SurveyVerdict {
    /// Nothing measured well enough to judge it.
    NotJudged,
    /// Within the limit (with the ISO 14253-1 rule: with its uncertainty added).
    Pass,
    /// A pass beyond the crew's warn fraction of the limit (findings only).
    Warn,
    /// Within its uncertainty of the limit: neither proven.
    Inconclusive,
    /// Beyond the limit (with the ISO 14253-1 rule: with its uncertainty taken off).
    Fail,
}

/// The decision rule a [`SurfaceFindings`] was judged by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum SurveyDecisionRule {
    /// ISO 14253-1: pass when value + U is within the limit, fail when value − U is beyond.
    Iso14253_1,
    /// Simple acceptance: the value alone.
    Simple,
}

/// A gap under a straightedge on one face, one way: the one that governs (`span` NaN) or the
/// deepest with its supports within one of the table's distances (`span`). Metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FlatnessRow {
    /// The face (the design's planar faces, largest first).
    pub face: u32,
    /// 0: along the layers; 1: across them.
    pub direction: u8,
    /// The verdict by the message's decision rule.
    pub verdict: SurveyVerdict,
    /// The table's distance the supports lie within; NaN for the governing gap.
    pub span: f64,
    /// The gap.
    pub gap: f64,
    /// The distance between the straightedge's supports.
    pub support_distance: f64,
    /// The standard's limit at that distance.
    pub limit: f64,
    /// The gap's expanded uncertainty (k = 2).
    pub uncertainty: f64,
    /// Where the gap is deepest, design frame.
    pub at: [f64; 3],
}

/// The largest abrupt offset on one face, one way (ACI 117: within an inch). Metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AbruptRow {
    /// The face.
    pub face: u32,
    /// 0: along the layers; 1: across them.
    pub direction: u8,
    /// The verdict by the message's decision rule.
    pub verdict: SurveyVerdict,
    /// The offset.
    pub step: f64,
    /// How far apart the two points it is measured between lie.
    pub distance: f64,
    /// The class's abrupt limit.
    pub limit: f64,
    /// The offset's expanded uncertainty (k = 2).
    pub uncertainty: f64,
    /// The lower of the two points, design frame.
    pub at: [f64; 3],
}

/// Abrupt offsets a [`SurfaceFindings`] holds at most (one per face and direction).
pub const MAX_ABRUPT_ROWS: usize = 64;

/// A dimension (0: length, 1: thickness, 2: height) or an upright face's plumb (3). Metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DimensionRow {
    /// 0 length, 1 thickness, 2 height, 3 plumb.
    pub kind: u8,
    /// The verdict by the message's decision rule.
    pub verdict: SurveyVerdict,
    /// The faces it is measured between (a plumb's face twice).
    pub faces: [u32; 2],
    /// The design's size (for plumb, the height seen).
    pub nominal: f64,
    /// As built (for plumb, the face's top less its foot, outward).
    pub measured: f64,
    /// The limit.
    pub limit: f64,
    /// The expanded uncertainty (k = 2) of `measured`.
    pub uncertainty: f64,
}

/// The judgement of a scan layer's stations so far.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SurfaceFindings {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// The job (one print).
    pub job: u64,
    /// The station whose report it follows.
    pub station: u32,
    /// The last printed layer of the scan layer, 0-based.
    pub layer: u32,
    /// NaN when not printing.
    pub printed_height: f64,
    /// The flatness standard, as `--flatness` spells it; empty when none.
    pub flatness_standard: FixedText<16>,
    /// The dimensions standard, as `--dimensions` spells it; empty when none.
    pub dimensions_standard: FixedText<16>,
    /// The deepest gap per face, direction and span.
    pub flatness: heapless::Vec<FlatnessRow, MAX_SURVEY_ROWS>,
    /// The dimensions, then each upright face's plumb.
    pub dimensions: heapless::Vec<DimensionRow, MAX_SURVEY_ROWS>,
    /// Rows left out because a list was full.
    pub truncated: u32,
    /// The decision rule the verdicts follow.
    pub decision_rule: SurveyDecisionRule,
    /// Per face and direction, the largest abrupt offset, where the standard limits them.
    pub abrupt: heapless::Vec<AbruptRow, MAX_ABRUPT_ROWS>,
    /// Faces and directions the straightedge could not be laid on (not seen, too sparse).
    pub not_judged: u32,
}
crate::message::message!(SurfaceFindings, "asbuilt.SurfaceFindings.v3", 3, oldest 3);

impl SurfaceFindings {
    /// Nothing judged yet, after station `station` of `job`.
    pub fn new(job: u64, station: u32) -> Self {
        Self {
            version: Self::VERSION,
            job,
            station,
            layer: 0,
            printed_height: f64::NAN,
            flatness_standard: FixedText::empty(),
            dimensions_standard: FixedText::empty(),
            flatness: heapless::Vec::new(),
            dimensions: heapless::Vec::new(),
            truncated: 0,
            decision_rule: SurveyDecisionRule::Iso14253_1,
            not_judged: 0,
            abrupt: heapless::Vec::new(),
        }
    }

    /// The worst verdict of what was judged; `NotJudged` when nothing was.
    pub fn verdict(&self) -> SurveyVerdict {
        self.flatness
            .iter()
            .map(|r| r.verdict)
            .chain(self.dimensions.iter().map(|r| r.verdict))
            .chain(self.abrupt.iter().map(|r| r.verdict))
            .max()
            .unwrap_or(SurveyVerdict::NotJudged)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec;

    #[test]
    fn full_lists_fit_the_byte_bound_and_round_trip() {
        let mut s = SurfaceFindings::new(2, 5);
        s.flatness_standard = FixedText::truncated("din18202:6");
        let gap = FlatnessRow {
            face: 1,
            direction: 0,
            verdict: SurveyVerdict::Fail,
            span: 1.0,
            gap: 0.0123,
            support_distance: 0.3,
            limit: 0.005,
            uncertainty: 0.0004,
            at: [-0.4, -0.09, 0.1],
        };
        let dim = DimensionRow {
            kind: 3,
            verdict: SurveyVerdict::Inconclusive,
            faces: [1, 1],
            nominal: 0.98,
            measured: 0.002,
            limit: 0.006,
            uncertainty: 0.002,
        };
        let step = AbruptRow {
            face: 1,
            direction: 1,
            verdict: SurveyVerdict::Fail,
            step: 0.005,
            distance: 0.009,
            limit: 0.003175,
            uncertainty: 0.0004,
            at: [-0.4, -0.09, 0.5],
        };
        while s.flatness.push(gap).is_ok() {}
        while s.dimensions.push(dim).is_ok() {}
        while s.abrupt.push(step).is_ok() {}
        let bytes = codec::encode(&s);
        assert!(bytes.len() <= MAX_SURVEY_BYTES, "{}", bytes.len());
        let back: SurfaceFindings = codec::decode(&bytes).unwrap();
        // Bytes, not values: the printed height is NaN.
        assert_eq!(codec::encode(&back), bytes);
        assert_eq!(back.verdict(), SurveyVerdict::Fail);
        assert_eq!(back.flatness_standard.as_str(), "din18202:6");
    }
}
