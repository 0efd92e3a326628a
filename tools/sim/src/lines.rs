//! The cell's messages as the lines `asbuilt sim` and `asbuilt demo` print while a job runs: a
//! station's report, a scan layer's findings, the advice and what the printer does with it.

use asbuilt_protocol::{LayerCorrection, StationFindings, StationReport, StationStatus};

use crate::{PlannedStation, SimJob, SimOutcome};

/// The station attempts that did not end complete, in one line: "2 interruption(s): L016-S4
/// attempt 1 (reported Interrupted), …".
pub fn interruptions_line(plan: &[PlannedStation], o: &SimOutcome) -> String {
    let items: Vec<String> = o
        .retries
        .iter()
        .map(|(station, attempt, why)| {
            let name = plan
                .iter()
                .find(|p| p.index == *station)
                .map_or_else(|| format!("station {station}"), |p| p.name.clone());
            format!("{name} attempt {attempt} ({why})")
        })
        .collect();
    format!("{} interruption(s): {}", items.len(), items.join(", "))
}

/// One line for a station report, as `sim` and `demo` print it.
pub fn report_line(r: &StationReport) -> String {
    format!(
        "  {:<10} layer {:>3} {:?}: {:>8} points, median |d| {:.2} mm, p95 {:.2} mm, {:.1} % in \
         tolerance",
        r.name.as_str(),
        r.layer + 1,
        r.status().unwrap_or(StationStatus::Incomplete),
        r.points_received,
        r.stats.median_abs * 1e3,
        r.stats.p95_abs * 1e3,
        100.0 * r.stats.within as f64 / r.stats.count.max(1) as f64
    )
}

/// One line for the layers the closed-loop printer prints next, and the advice it applies.
pub fn printing_line(layers: (u32, u32), advice: Option<&LayerCorrection>) -> String {
    let what = match advice {
        None => "as designed (no advice came)".to_string(),
        Some(c) if c.is_neutral() => "as designed (advice: nothing to correct)".to_string(),
        Some(c) => advice_text(c),
    };
    format!(
        "  printing layers {}–{}: {what}",
        layers.0 + 1,
        layers.1 + 1
    )
}

/// Advice in a few words: the z offsets, the flow and the path.
pub fn advice_text(c: &LayerCorrection) -> String {
    let mut items = Vec::new();
    if c.z_first != 0.0 || c.z_then != 0.0 {
        if c.first_layers > 0 && c.z_first != c.z_then {
            items.push(format!(
                "z {:+.2} mm a layer for {} layers, then {:+.2}",
                c.z_first * 1e3,
                c.first_layers,
                c.z_then * 1e3
            ));
        } else {
            items.push(format!("z {:+.2} mm a layer", c.z_then * 1e3));
        }
    }
    if c.flow != 1.0 {
        items.push(format!("flow ×{:.3}", c.flow));
    }
    if c.path_offset != [0.0, 0.0] {
        items.push(format!(
            "path ({:+.1}, {:+.1}) mm",
            c.path_offset[0] * 1e3,
            c.path_offset[1] * 1e3
        ));
    }
    if items.is_empty() {
        "nothing to correct".into()
    } else {
        format!("advised {}", items.join(", "))
    }
}

/// One line for a scan layer's findings, as `sim` and `demo` print it.
pub fn findings_line(f: &StationFindings) -> String {
    let mut items = Vec::new();
    if f.top_height_deviation.abs() > f.tolerance {
        items.push(format!("top {:+.1} mm", f.top_height_deviation * 1e3));
    }
    for l in f.layers_out_of_tolerance() {
        let w = l.width_deviation;
        let s = l.shift[0].hypot(l.shift[1]);
        items.push(if w.abs() > f.tolerance {
            format!("layer {} width {:+.1} mm", l.layer, w * 1e3)
        } else {
            format!("layer {} shifted {:.1} mm", l.layer, s * 1e3)
        });
    }
    for g in f.missing.iter() {
        items.push(format!(
            "missing {:.0} cm² at ({:.2}, {:.2}, {:.2})",
            g.area_m2 * 1e4,
            g.centroid[0],
            g.centroid[1],
            g.centroid[2]
        ));
    }
    for g in f.regions.iter() {
        items.push(format!(
            "{} {:+.1} mm at ({:.2}, {:.2}, {:.2})",
            g.kind.as_str(),
            g.peak * 1e3,
            g.centroid[0],
            g.centroid[1],
            g.centroid[2]
        ));
    }
    // A line, not a table: the largest few; report.json and report.html have them all.
    const SHOWN: usize = 8;
    let more = items.len().saturating_sub(SHOWN);
    items.truncate(SHOWN);
    if more > 0 {
        items.push(format!("{more} more in the report"));
    }
    format!(
        "  findings after {} station(s) of layer {}: {}",
        f.stations,
        f.layer + 1,
        if items.is_empty() {
            "none beyond the tolerance".to_string()
        } else {
            items.join("; ")
        }
    )
}

/// What was injected and what the agent found, scan layer by scan layer (every tenth layer of
/// a profiler's print, whose every layer is in the report), as `demo` ends with it.
pub fn truth_and_findings(job: &SimJob, o: &SimOutcome) -> Vec<String> {
    let by_layer = o.findings_by_layer();
    let shown: Vec<u32> = match job.profiler {
        Some(_) => {
            let n = job.plan().len() as u32;
            (1..=n).filter(|k| k % 10 == 0 || *k == n).collect()
        }
        None => job.scan_after.clone(),
    };
    let mut lines = Vec::new();
    for k in shown {
        lines.push(format!("  after layer {k}:"));
        for t in job.defects.iter().filter_map(|d| d.truth(&job.part, k)) {
            lines.push(format!(
                "    injected {:<16} {:+.1} mm at ({:.2}, {:.2}, {:.2}), layers {}–{}",
                t.kind,
                t.magnitude * 1e3,
                t.position.x,
                t.position.y,
                t.position.z,
                t.layers.0,
                t.layers.1
            ));
        }
        lines.push(match by_layer.iter().find(|f| f.layer + 1 == k) {
            Some(f) => format!("  {}", findings_line(f).trim_start()),
            None => "    no findings came back for this layer".into(),
        });
        if job.closed_loop {
            let built = crate::built_layers(&job.part, &job.defects, k, &o.settings);
            if let Ok(Some(top)) = built.map(|b| b.last().copied()) {
                let advice = o
                    .corrections
                    .iter()
                    .filter(|c| c.layer + 1 == k)
                    .max_by_key(|c| c.station);
                lines.push(format!(
                    "    closed loop: top as built {:+.1} mm; {}",
                    top.top_error_m * 1e3,
                    advice.map_or("no advice came".into(), advice_text)
                ));
            }
        }
    }
    lines
}

/// The job in one line, as `sim` and `demo` start with it: the part, what scans it and how
/// fast it sends.
pub fn job_line(job: &SimJob) -> String {
    let plan = job.plan();
    let rate = job.rate.map_or("max".to_string(), |r| match job.profiler {
        Some(_) => "real time".to_string(),
        None => format!("{:.1} M points/s", r / 1e6),
    });
    let scans = match &job.profiler {
        Some(m) => format!(
            "a line profiler on the nozzle, every layer a pass ({} passes; {} points a profile \
             at {:.0} Hz, poses at {:.0} Hz)",
            plan.len(),
            m.points,
            m.rate_hz,
            m.pose_rate_hz
        ),
        None => format!(
            "{} station(s) after layers {:?}",
            plan.len(),
            job.scan_after
        ),
    };
    format!(
        "simulating the {} ({} layers of {:.0} mm): {scans}, {} defect(s), rate {rate}",
        job.part.name,
        job.part.layers(),
        job.part.layer_height * 1e3,
        job.defects.len(),
    )
}
