//! What `asbuilt inspect` shows once all its stations are in: the design samples found
//! missing, M3C2's core points, the job's findings (or why there are none) and each layer
//! band's means.

use asbuilt_protocol::StationFindings;
use asbuilt_report::{BandMethods, SuiteTotals};

use crate::{BandMeans, View, Viewer};

impl From<&BandMethods> for BandMeans {
    fn from(row: &BandMethods) -> Self {
        let mean = |s: &Option<asbuilt_report::BandStats>| s.as_ref().map(|s| s.mean);
        Self {
            layer: row.layer,
            z: [row.z_min, row.z_max],
            c2m: mean(&row.c2m),
            c2c: mean(&row.c2c),
            m3c2: mean(&row.m3c2),
        }
    }
}

impl Viewer {
    /// The job-level layers of a survey, after its stations: `totals` of its suite and the
    /// findings drawn from them.
    pub fn show_totals(&self, totals: &SuiteTotals, findings: &[StationFindings]) {
        for (path, samples) in [
            ("missing", &totals.missing_view),
            ("m3c2", &totals.m3c2_view),
        ] {
            if !samples.is_empty() {
                self.show(View::Samples {
                    path: path.into(),
                    positions: samples.iter().map(|s| s.0).collect(),
                    values: samples.iter().map(|s| s.1).collect(),
                    significant: (path == "m3c2").then(|| samples.iter().map(|s| s.2).collect()),
                });
            }
        }
        for f in findings {
            self.show(View::Findings {
                index: f.station,
                findings: Box::new(f.clone()),
            });
        }
        if findings.is_empty() {
            self.show(View::NoFindings {
                why: "No findings: they need the design's samples in view of a station and M3C2 \
                      (the report judges the job by all points together)."
                    .into(),
            });
        }
        let bands: Vec<BandMeans> = totals
            .layers
            .iter()
            .flatten()
            .map(BandMeans::from)
            .collect();
        if !bands.is_empty() {
            self.show(View::Bands(bands));
        }
    }
}
