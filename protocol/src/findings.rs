//! Findings a crew can act on, sent after each station's report: per-layer width, shift and top
//! height, areas out of tolerance and missing material, each with its position. They cover
//! every station of the scan layer so far (the stations sharing the station's printed height).
//!
//! The findings are variable in size, so on iceoryx2 they travel as their postcard encoding in
//! a byte slice behind a [`FindingsHeader`]; the same bytes are the MCAP record.

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::SurveyVerdict;
use crate::message::Message;

/// Layer bands a [`StationFindings`] holds at most.
pub const MAX_LAYER_ROWS: usize = 256;
/// Regions, and missing areas, a [`StationFindings`] holds at most, largest first.
pub const MAX_REGIONS: usize = 64;
/// Upper bound of an encoded [`StationFindings`], bytes.
pub const MAX_FINDINGS_BYTES: usize = 64 * 1024;

/// The user header of a findings sample; the encoded [`StationFindings`] follow as bytes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.FindingsHeader.v1")]
#[repr(C)]
pub struct FindingsHeader {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// Zero; keeps the layout free of padding.
    pub _reserved: u16,
    /// The station whose report the findings follow.
    pub station: u32,
    /// The job (one print) the station belongs to.
    pub job: u64,
    /// The last printed layer of the scan layer the findings cover.
    pub layer: u32,
    /// Length of the encoded findings that follow.
    pub bytes: u32,
}
crate::message::message!(FindingsHeader, "asbuilt.FindingsHeader.v1", 1);

impl Default for FindingsHeader {
    fn default() -> Self {
        Self {
            version: Self::VERSION,
            _reserved: 0,
            station: 0,
            job: 0,
            layer: 0,
            bytes: 0,
        }
    }
}

/// One layer band's side faces. Metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LayerFinding {
    /// The band's layer, 0-based from the bed.
    pub layer: u32,
    /// The band's bottom in the design frame.
    pub z_min: f64,
    /// The band's top in the design frame.
    pub z_max: f64,
    /// Design samples on the band's sides that had an M3C2 distance.
    pub samples: u32,
    /// Mean M3C2 distance on the band's sides.
    pub mean: f64,
    /// As built minus design; NaN where the stations saw too little to tell width from shift.
    pub width_deviation: f64,
    /// Shift of the band in x and y; NaN as above.
    pub shift: [f64; 2],
    /// The width deviation's expanded uncertainty (k = 2): the fit's and the stations' poses';
    /// NaN with the width.
    pub width_uncertainty: f64,
    /// The shift's (its length's) expanded uncertainty (k = 2); NaN with the shift.
    pub shift_uncertainty: f64,
    /// The width's expanded uncertainty from its fit alone, without the poses' share: what a
    /// width relative to the scan layer's other bands keeps (the poses widen them alike).
    pub width_fit_uncertainty: f64,
    /// The width held to the crew's limit for the band by the decision rule.
    pub width_verdict: SurveyVerdict,
    /// The shift held to the crew's limit for the band by the decision rule.
    pub shift_verdict: SurveyVerdict,
}

impl LayerFinding {
    /// The width deviation, when the sides seen could tell it from a shift.
    pub fn width(&self) -> Option<f64> {
        self.width_deviation
            .is_finite()
            .then_some(self.width_deviation)
    }

    /// The shift in x and y, when the sides seen could tell it from a width.
    pub fn shift_xy(&self) -> Option<[f64; 2]> {
        self.shift
            .iter()
            .all(|v| v.is_finite())
            .then_some(self.shift)
    }
}

/// Which way a region departs from the design.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum RegionKind {
    /// Material outside the design.
    Excess,
    /// The surface lies inside the design.
    Deficit,
    /// No material where a station should have seen some.
    Missing,
}

impl RegionKind {
    /// The kind as reports spell it: `excess`, `deficit`, `missing`.
    pub fn as_str(self) -> &'static str {
        match self {
            RegionKind::Excess => "excess",
            RegionKind::Deficit => "deficit",
            RegionKind::Missing => "missing",
        }
    }
}

/// A connected area of the design. Positions in the design frame, metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RegionFinding {
    /// Excess, deficit or missing material.
    pub kind: RegionKind,
    /// Design samples in the region.
    pub samples: u32,
    /// The design surface the region covers, square metres.
    pub area_m2: f64,
    /// The mean position of the region's samples.
    pub centroid: [f64; 3],
    /// The lower corner of the region's bounding box.
    pub min: [f64; 3],
    /// The upper corner of the region's bounding box.
    pub max: [f64; 3],
    /// Largest |deviation| with its sign; NaN for missing material.
    pub peak: f64,
    /// Where the peak deviation was measured.
    pub peak_at: [f64; 3],
    /// The peak's expanded uncertainty (k = 2): its cylinder's mean and the stations' poses;
    /// NaN for missing material.
    pub peak_uncertainty: f64,
    /// The area's expanded uncertainty (k = 2), m²: its edge known to a sample's spacing.
    pub area_uncertainty: f64,
    /// The peak (the area, for missing material) held to the crew's limit by the decision
    /// rule.
    pub verdict: SurveyVerdict,
    /// Mean signed deviation over the region; NaN for missing material.
    pub mean: f64,
    /// First and last layer band; `u32::MAX` when the layer height is unknown.
    pub layers: [u32; 2],
}

/// What the agent found over one scan layer's stations so far.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StationFindings {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// The job (one print) the station belongs to.
    pub job: u64,
    /// The station whose report these follow.
    pub station: u32,
    /// The last printed layer of this scan layer, 0-based.
    pub layer: u32,
    /// NaN when not printing.
    pub printed_height: f64,
    /// The tolerance the regions were judged with, metres.
    pub tolerance: f64,
    /// Stations of this scan layer that went into the findings.
    pub stations: u32,
    /// Top of the print minus the printed height; NaN when the top was not seen.
    pub top_height_deviation: f64,
    /// Design samples on the top that had an M3C2 distance.
    pub top_samples: u32,
    /// The top height deviation's expanded uncertainty (k = 2); NaN with it.
    pub top_uncertainty: f64,
    /// The top held to the crew's limit by the decision rule.
    pub top_verdict: SurveyVerdict,
    /// The layer bands' side faces, from the bed up.
    pub layers: heapless::Vec<LayerFinding, MAX_LAYER_ROWS>,
    /// Areas out of tolerance, largest first.
    pub regions: heapless::Vec<RegionFinding, MAX_REGIONS>,
    /// Missing material, largest first.
    pub missing: heapless::Vec<RegionFinding, MAX_REGIONS>,
    /// Regions or missing areas left out because the lists were full.
    pub truncated: u32,
}
crate::message::message!(StationFindings, "asbuilt.StationFindings.v2", 2, oldest 2);

impl StationFindings {
    /// Empty findings for a station: no layers, no regions, nothing seen of the top.
    pub fn new(job: u64, station: u32) -> Self {
        Self {
            version: Self::VERSION,
            job,
            station,
            layer: 0,
            printed_height: f64::NAN,
            tolerance: 0.0,
            stations: 0,
            top_height_deviation: f64::NAN,
            top_samples: 0,
            top_uncertainty: f64::NAN,
            top_verdict: SurveyVerdict::NotJudged,
            layers: heapless::Vec::new(),
            regions: heapless::Vec::new(),
            missing: heapless::Vec::new(),
            truncated: 0,
        }
    }

    /// Layer rows whose width or shift is beyond the tolerance.
    pub fn layers_out_of_tolerance(&self) -> impl Iterator<Item = &LayerFinding> {
        let t = self.tolerance;
        self.layers
            .iter()
            .filter(move |r| r.width_deviation.abs() > t || r.shift[0].hypot(r.shift[1]) > t)
    }

    /// The worst verdict of the findings (`NotJudged` before they were judged, or with
    /// nothing to judge).
    pub fn verdict(&self) -> SurveyVerdict {
        self.layers
            .iter()
            .flat_map(|r| [r.width_verdict, r.shift_verdict])
            .chain([self.top_verdict])
            .chain(self.regions.iter().chain(&self.missing).map(|r| r.verdict))
            .max()
            .unwrap_or(SurveyVerdict::NotJudged)
    }

    /// Everything a crew should look at: layers out of tolerance, a top out of tolerance,
    /// regions and missing material.
    pub fn count(&self) -> usize {
        self.layers_out_of_tolerance().count()
            + usize::from(self.top_height_deviation.abs() > self.tolerance)
            + self.regions.len()
            + self.missing.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec;

    #[test]
    fn full_findings_fit_the_byte_bound_and_round_trip() {
        let mut f = StationFindings::new(3, 4);
        let row = LayerFinding {
            layer: 1,
            z_min: 0.0,
            z_max: 0.02,
            samples: 10,
            mean: 0.001,
            width_deviation: f64::NAN,
            shift: [0.0, 0.0],
            width_uncertainty: f64::NAN,
            shift_uncertainty: 0.001,
            width_fit_uncertainty: f64::NAN,
            width_verdict: SurveyVerdict::NotJudged,
            shift_verdict: SurveyVerdict::Pass,
        };
        let region = RegionFinding {
            kind: RegionKind::Missing,
            samples: 5,
            area_m2: 0.01,
            centroid: [1.0; 3],
            min: [0.0; 3],
            max: [2.0; 3],
            peak: f64::NAN,
            peak_at: [1.0; 3],
            peak_uncertainty: f64::NAN,
            area_uncertainty: 0.001,
            verdict: SurveyVerdict::Fail,
            mean: f64::NAN,
            layers: [1, 2],
        };
        while f.layers.push(row).is_ok() {}
        while f.regions.push(region).is_ok() {}
        while f.missing.push(region).is_ok() {}
        let bytes = codec::encode(&f);
        assert!(bytes.len() <= MAX_FINDINGS_BYTES, "{}", bytes.len());
        let back: StationFindings = codec::decode(&bytes).unwrap();
        assert_eq!(back.layers.len(), MAX_LAYER_ROWS);
        assert_eq!(back.regions[0].kind, RegionKind::Missing);
        assert!(back.layers[0].width_deviation.is_nan());
    }
}
