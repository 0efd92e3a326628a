//! A scan layer's findings in the view: judged as the report judges them (the same verdicts,
//! the same numbers), drawn as one numbered marker per warning or failure with its text in the
//! findings table and on hover, boxes around the areas, and each band's history. Everything is
//! logged to the same entities each scan layer, so the part shows the findings of the scan
//! layer at the time cursor only.

use asbuilt_core::verdict::{Limits, Verdict};
use asbuilt_protocol::{RegionKind, StationFindings};
use asbuilt_report::{Item, ScanLayerVerdicts};
use nalgebra::Point3;

use crate::paint::Painter;

/// The current job's findings, each scan layer's latest: what its verdicts are judged from.
/// As many as the job has scan layers (the design's height over the layers between scans, every
/// layer with a line profiler), each kept encoded: the message's fixed capacity is 42 kB, its
/// rows in use a few hundred bytes.
pub(crate) struct ScanLayers {
    limits: Limits,
    job: Option<u64>,
    /// By scan layer: its number and its findings, encoded.
    layers: Vec<(u32, Vec<u8>)>,
}

impl ScanLayers {
    pub(crate) fn new(limits: Limits) -> Self {
        Self {
            limits,
            job: None,
            layers: Vec::new(),
        }
    }

    /// Takes `f` (in place of an earlier one of its scan layer; a new job starts afresh) and
    /// returns its verdicts, judged with the scan layers before it as the report judges them.
    pub(crate) fn judge(&mut self, f: &StationFindings) -> ScanLayerVerdicts {
        if self.job != Some(f.job) {
            self.job = Some(f.job);
            self.layers.clear();
        }
        let encoded = (f.layer, asbuilt_protocol::codec::encode(f));
        match self.layers.binary_search_by_key(&f.layer, |l| l.0) {
            Ok(i) => self.layers[i] = encoded,
            Err(i) => self.layers.insert(i, encoded),
        }
        // Decoded as this build encoded them; one that would not is left out, not guessed.
        let decoded: Vec<StationFindings> = self
            .layers
            .iter()
            .take_while(|l| l.0 < f.layer)
            .filter_map(|l| asbuilt_protocol::codec::decode(&l.1).ok())
            .collect();
        let upto: Vec<&StationFindings> = decoded.iter().chain([f]).collect();
        let (mut verdicts, _) = asbuilt_report::job_verdicts(&upto, &self.limits);
        verdicts
            .pop()
            .expect("the scan layer just taken is among those judged")
    }
}

fn verdict_colour(v: Verdict) -> rerun::Color {
    match v {
        Verdict::Fail => rerun::Color::from_rgb(215, 25, 28),
        Verdict::Warn => rerun::Color::from_rgb(245, 160, 0),
        Verdict::Inconclusive => rerun::Color::from_rgb(140, 80, 200),
        Verdict::Pass | Verdict::NotJudged => rerun::Color::from_rgb(120, 120, 120),
    }
}

impl Painter {
    /// A scan layer's findings: markers, areas, table and the bands' history, at the station
    /// that completed it and its scan layer.
    pub(crate) fn findings(
        &mut self,
        index: u32,
        f: &StationFindings,
    ) -> Result<(), rerun::RecordingStreamError> {
        // A scan layer's findings come again as each of its stations completes: the history
        // takes a scan layer's last, once a later one begins (or the view closes), so its
        // series draw one value per scan layer, not each station's partial one.
        if let Some((at, done)) = self
            .pending_history
            .take_if(|(_, p)| (p.job, p.layer) != (f.job, f.layer))
        {
            self.history(at, &done)?;
        }
        self.pending_history = Some((index, f.clone()));
        self.at(index, f.layer);
        let verdicts = self.scan_layers.judge(f);
        self.markers(&verdicts)?;
        self.areas(f)?;
        self.rec.log(
            "findings/table",
            &rerun::TextDocument::new(table(f, &verdicts))
                .with_media_type(rerun::MediaType::markdown()),
        )?;
        self.profile(f)
    }

    /// The history the last scan layer still holds back, when the view closes.
    pub(crate) fn flush_history(&mut self) -> Result<(), rerun::RecordingStreamError> {
        match self.pending_history.take() {
            Some((at, f)) => self.history(at, &f),
            None => Ok(()),
        }
    }

    /// One marker per warning or failure, numbered as in the report: an area's at its centroid,
    /// a layer band's on the ruler at the part's corner at the band's height (side by side when
    /// a band has several). An empty list clears the previous scan layer's.
    fn markers(&mut self, v: &ScanLayerVerdicts) -> Result<(), rerun::RecordingStreamError> {
        let (lo, hi) = self.bounds.unwrap_or((Point3::origin(), Point3::origin()));
        let pad = 0.05 * (hi - lo).amax().max(0.1);
        let ruler = [lo.x - pad, lo.y - pad];
        // Markers closer than this would hide each other's numbers: on the ruler they stand
        // side by side (neighbouring bands are a layer apart), elsewhere one above the other.
        let gap = 0.6 * pad;
        let mut columns: Vec<Vec<f64>> = Vec::new();
        let (mut positions, mut colours, mut labels, mut texts) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for it in &v.items {
            let p = match it.at {
                // Findings at one place (a deficit where material is missing) stack upwards,
                // so each number shows; the hover text keeps the exact place.
                Some(at) => {
                    let mut p = self.local(&Point3::from(at));
                    let clear = |p: &[f32; 3], placed: &[[f32; 3]]| {
                        placed.iter().all(|q| {
                            let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
                            f64::from(d[0].hypot(d[1]).hypot(d[2])) >= gap
                        })
                    };
                    // At most as many steps as markers (a place that is not a number never
                    // clears).
                    for _ in 0..positions.len() {
                        if clear(&p, &positions) {
                            break;
                        }
                        p[2] += gap as f32;
                    }
                    p
                }
                None => {
                    let z = 0.5 * (it.z[0] + it.z[1]) - self.origin.z;
                    let free = |c: &Vec<f64>| c.iter().all(|&o| (o - z).abs() >= gap);
                    let k = match columns.iter().position(free) {
                        Some(k) => k,
                        None => {
                            columns.push(Vec::new());
                            columns.len() - 1
                        }
                    };
                    columns[k].push(z);
                    let x = ruler[0] - gap * k as f64;
                    [x as f32, ruler[1] as f32, z as f32]
                }
            };
            positions.push(p);
            colours.push(verdict_colour(it.verdict));
            labels.push(it.label.clone());
            texts.push(hover(it));
        }
        self.rec.log(
            "findings/markers",
            &rerun::Points3D::new(positions)
                .with_colors(colours)
                .with_radii([rerun::Radius::new_ui_points(7.0)])
                .with_labels(labels)
                .with_show_labels(true),
        )?;
        self.rec.log(
            "findings/markers",
            &rerun::AnyValues::default()
                .with_component::<rerun::components::Text>("finding", texts),
        )?;
        // The ruler stands only where a band's finding is on it.
        let (zlo, zhi) = (lo.z as f32, hi.z as f32);
        let [x, y] = ruler.map(|c| c as f32);
        let strips: Vec<[[f32; 3]; 2]> = if columns.is_empty() {
            Vec::new()
        } else {
            vec![[[x, y, zlo], [x, y, zhi]]]
        };
        self.rec.log(
            "findings/ruler",
            &rerun::LineStrips3D::new(strips).with_colors([rerun::Color::from_rgb(110, 110, 110)]),
        )
    }

    /// Out-of-tolerance regions as outlines (red excess, blue deficit), missing material as
    /// amber patches; unlabelled, the markers carry the numbers.
    fn areas(&mut self, f: &StationFindings) -> Result<(), rerun::RecordingStreamError> {
        for (what, list, fill) in [
            ("regions", &f.regions[..], rerun::FillMode::MajorWireframe),
            ("missing", &f.missing[..], rerun::FillMode::Solid),
        ] {
            let (mut centres, mut halves, mut colours) = (Vec::new(), Vec::new(), Vec::new());
            for r in list {
                let (lo, hi) = (Point3::from(r.min), Point3::from(r.max));
                centres.push(self.local(&nalgebra::center(&lo, &hi)));
                let h = (hi - lo) * 0.5;
                // A flat region still gets a visible box.
                halves.push([h.x, h.y, h.z].map(|v| v.max(0.002) as f32));
                colours.push(match r.kind {
                    RegionKind::Excess => rerun::Color::from_rgb(230, 40, 40),
                    RegionKind::Deficit => rerun::Color::from_rgb(40, 70, 230),
                    RegionKind::Missing => rerun::Color::from_unmultiplied_rgba(255, 190, 0, 110),
                });
            }
            let boxes = rerun::Boxes3D::from_centers_and_half_sizes(centres, halves)
                .with_colors(colours)
                .with_fill_mode(fill);
            self.rec.log(format!("findings/areas/{what}"), &boxes)?;
        }
        Ok(())
    }

    /// Each band's width, relative width and shift, and the top height, one series per band
    /// against the scan layer (station `index` completed it).
    fn history(
        &mut self,
        index: u32,
        f: &StationFindings,
    ) -> Result<(), rerun::RecordingStreamError> {
        self.at(index, f.layer);
        if f.top_height_deviation.is_finite() {
            self.rec.log(
                "history/top_mm",
                &rerun::Scalars::new([f.top_height_deviation * 1e3]),
            )?;
        }
        // The scan layer's median band width: what its stations' pose errors do to every band
        // alike. A band's width less it is the relative width the report's creep follows.
        let median = asbuilt_core::stats::median(f.layers.iter().filter_map(|r| r.width()));
        for row in &f.layers {
            let band = format!("band_{:03}", row.layer);
            if let Some(w) = row.width() {
                self.rec.log(
                    format!("history/width_mm/{band}"),
                    &rerun::Scalars::new([w * 1e3]),
                )?;
                if let Some(m) = median {
                    self.rec.log(
                        format!("history/relative_width_mm/{band}"),
                        &rerun::Scalars::new([(w - m) * 1e3]),
                    )?;
                }
            }
            if row.shift.iter().all(|v| v.is_finite()) {
                let shift = row.shift[0].hypot(row.shift[1]);
                self.rec.log(
                    format!("history/shift_mm/{band}"),
                    &rerun::Scalars::new([shift * 1e3]),
                )?;
            }
        }
        Ok(())
    }

    /// The scan layer's profile of its bands' mean M3C2 distance, the latest at the cursor.
    fn profile(&mut self, f: &StationFindings) -> Result<(), rerun::RecordingStreamError> {
        let (bands, means): (Vec<i64>, Vec<f64>) = f
            .layers
            .iter()
            .filter(|r| r.samples > 0 && r.mean.is_finite())
            .map(|r| (i64::from(r.layer), r.mean * 1e3))
            .unzip();
        self.rec.log(
            "layers/m3c2_mean_mm",
            &rerun::BarChart::new(means.as_slice()).with_abscissa(bands.as_slice()),
        )
    }
}

/// What hovering a marker tells: its number, what it is, its verdict against its limit.
fn hover(it: &Item) -> String {
    format!(
        "{}: {} — {} (limit {}), {} since scan layer {}",
        it.label,
        it.text,
        it.verdict.as_str().to_uppercase(),
        it.limit_text(),
        it.change,
        it.since
    )
}

/// The scan layer's findings as a markdown table, numbered as the markers and the report.
fn table(f: &StationFindings, v: &ScanLayerVerdicts) -> String {
    let mut s = format!(
        "# {} — {}\n\n{} station(s); top height {}; tolerance ±{:.1} mm.\n\n",
        v.title(),
        v.verdict.as_str().to_uppercase(),
        f.stations,
        if f.top_height_deviation.is_finite() {
            format!("{:+.1} mm", f.top_height_deviation * 1e3)
        } else {
            "not seen".into()
        },
        f.tolerance * 1e3
    );
    if v.items.is_empty() {
        s += "Nothing beyond the warning level.\n";
    } else {
        s += "| # | verdict | finding | limit | since |\n| --- | --- | --- | --- | --- |\n";
        for it in &v.items {
            s += &format!(
                "| {} | {} | {} | {} | scan layer {} ({}) |\n",
                it.label,
                it.verdict.as_str(),
                it.text,
                it.limit_text(),
                it.since,
                it.change
            );
        }
    }
    if f.truncated > 0 {
        s += &format!(
            "\n{} more areas not listed (the findings keep the largest).\n",
            f.truncated
        );
    }
    if !v.resolved.is_empty() {
        s += "\nNo longer seen since the scan layer before: ";
        s += &v.resolved.join("; ");
        s += ".\n";
    }
    s
}
