//! The HTML report: one self-contained page (inline CSS and SVG, no script, no network) with a
//! table of stations, pass or fail against the tolerance, and a histogram per station.
//!
//! A station passes when the 95th percentile of |d| is within the tolerance and every point
//! found the design (no no-match points).

use std::fmt::Write;

use crate::{Report, Section};

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn mm(v: Option<f64>) -> String {
    v.map(|v| format!("{:.3}", v * 1e3))
        .unwrap_or_else(|| "–".into())
}

/// Millimetres of a value that may be NaN (not measured).
fn mmf(v: f64) -> String {
    mm(Some(v).filter(|v| v.is_finite()))
}

pub fn passes(s: &Section, tolerance: f64) -> bool {
    s.matched > 0 && s.no_match == 0 && s.p95_abs.is_some_and(|p| p <= tolerance)
}

/// A bar per histogram bin, tolerance lines at ±tolerance.
fn histogram(s: &Section, tolerance: f64) -> String {
    let h = &s.histogram;
    let (w, ht) = (320.0, 90.0);
    let max = h.bins.iter().copied().max().unwrap_or(0).max(1) as f64;
    let n = h.bins.len().max(1) as f64;
    let bw = w / n;
    let mut svg = format!(
        "<svg width=\"{w}\" height=\"{}\" viewBox=\"0 0 {w} {}\" role=\"img\" \
         aria-label=\"histogram of signed deviation\">",
        ht + 14.0,
        ht + 14.0
    );
    for (i, &c) in h.bins.iter().enumerate() {
        let bh = ht * c as f64 / max;
        let centre = h.low + (i as f64 + 0.5) * (h.high - h.low) / n;
        let colour = if centre.abs() <= tolerance {
            "#4a8"
        } else if centre > 0.0 {
            "#d64"
        } else {
            "#47c"
        };
        let _ = write!(
            svg,
            "<rect x=\"{:.2}\" y=\"{:.2}\" width=\"{:.2}\" height=\"{:.2}\" fill=\"{colour}\"/>",
            i as f64 * bw,
            ht - bh,
            (bw - 0.5).max(0.5),
            bh
        );
    }
    for t in [-tolerance, tolerance] {
        let x = (t - h.low) / (h.high - h.low) * w;
        let _ = write!(
            svg,
            "<line x1=\"{x:.1}\" y1=\"0\" x2=\"{x:.1}\" y2=\"{ht}\" stroke=\"#333\" \
             stroke-dasharray=\"3,2\"/>"
        );
    }
    let _ = write!(
        svg,
        "<text x=\"0\" y=\"{}\" font-size=\"10\">{:.1} mm</text>\
         <text x=\"{}\" y=\"{}\" font-size=\"10\" text-anchor=\"end\">+{:.1} mm</text></svg>",
        ht + 12.0,
        h.low * 1e3,
        w,
        ht + 12.0,
        h.high * 1e3
    );
    svg
}

pub fn page(r: &Report, source: &str) -> String {
    let tol = r.parameters.tolerance_m;
    let mut rows = String::new();
    let mut cards = String::new();
    for s in r.stations.iter().chain(std::iter::once(&r.overall)) {
        let ok = passes(s, tol);
        let _ = write!(
            rows,
            "<tr class=\"{}\"><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>\
             <td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            if ok { "pass" } else { "fail" },
            esc(&s.id),
            s.points,
            s.rejected,
            s.no_match,
            mm(s.mean),
            mm(s.std),
            mm(s.median_abs),
            mm(s.p95_abs),
            s.in_tolerance_percent()
                .map_or("–".into(), |p| format!("{p:.1}")),
            if ok { "pass" } else { "FAIL" }
        );
        let _ = write!(
            cards,
            "<figure><figcaption>{}: {}</figcaption>{}</figure>",
            esc(&s.id),
            if ok { "pass" } else { "fail" },
            histogram(s, tol)
        );
    }
    let findings = findings_html(&r.findings);
    let warnings: String = r
        .warnings
        .iter()
        .map(|w| format!("<li>{}</li>", esc(w)))
        .collect();
    format!(
        "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>asbuilt report</title><style>\
         body{{font-family:system-ui,sans-serif;margin:2em;color:#222}}\
         table{{border-collapse:collapse}}td,th{{padding:.3em .7em;border-bottom:1px solid #ddd;\
         text-align:right}}td:first-child,th:first-child{{text-align:left}}\
         tr.fail td:last-child{{color:#c22;font-weight:bold}}tr.pass td:last-child{{color:#282}}\
         figure{{display:inline-block;margin:.5em 1em .5em 0}}figcaption{{font-size:.9em}}\
         </style></head><body>\
         <h1>asbuilt inspection report</h1>\
         <p>Recording {source}. Design {design} ({units}, {tri} triangles). Tolerance ±{tolmm:.1} mm, \
         maximum distance {maxmm:.1} mm. asbuilt {ver}.</p>\
         <p>A station passes when 95 % of its points are within the tolerance and none is farther \
         than the maximum distance. Distances in millimetres; positive is excess material.</p>\
         <table><tr><th>station</th><th>points</th><th>rejected</th><th>no match</th><th>mean</th>\
         <th>std</th><th>|d| median</th><th>|d| 95 %</th><th>in tolerance %</th><th>verdict</th>\
         </tr>{rows}</table><h2>Histograms</h2><p>Signed deviation, green within the tolerance \
         (dashed lines), red excess, blue missing material.</p>{cards}{findings}\
         <h2>Warnings</h2><ul>{warnings}</ul></body></html>\n",
        source = esc(source),
        design = esc(&r.design.path),
        units = esc(&r.design.units),
        tri = r.design.triangles,
        tolmm = tol * 1e3,
        maxmm = r.parameters.max_distance_m * 1e3,
        ver = r.asbuilt_version,
    )
}

/// The agent's findings per scan layer: what a crew should look at, with positions.
fn findings_html(all: &[asbuilt_protocol::StationFindings]) -> String {
    if all.is_empty() {
        return String::new();
    }
    let mut out = String::from(
        "<h2>Findings</h2><p>Per scan layer, over all its stations: design-referenced M3C2 and \
         coverage. Positions in the design frame, metres; deviations in millimetres.</p>",
    );
    let f3 = |p: [f64; 3]| format!("{:.3}, {:.3}, {:.3}", p[0], p[1], p[2]);
    for f in all {
        let t = f.tolerance;
        let _ = write!(
            out,
            "<h3>After {} layers (printed {:.3} m, {} station(s))</h3><p>Top height deviation: \
             {}. Layers below are numbered from 0 at the bed.</p>",
            f.layer + 1,
            f.printed_height,
            f.stations,
            if f.top_height_deviation.is_finite() {
                format!(
                    "{:+.1} mm{}",
                    f.top_height_deviation * 1e3,
                    if f.top_height_deviation.abs() > t {
                        " (out of tolerance)"
                    } else {
                        ""
                    }
                )
            } else {
                "top not seen".into()
            }
        );
        let rows: String = f
            .layers_out_of_tolerance()
            .map(|l| {
                format!(
                    "<tr class=\"fail\"><td>{}</td><td>{:.3}–{:.3}</td><td>{}</td><td>{}, {}</td>\
                     <td>FAIL</td></tr>",
                    l.layer,
                    l.z_min,
                    l.z_max,
                    mmf(l.width_deviation),
                    mmf(l.shift[0]),
                    mmf(l.shift[1])
                )
            })
            .collect();
        if !rows.is_empty() {
            let _ = write!(
                out,
                "<table><tr><th>layer</th><th>z (m)</th><th>width</th><th>shift x, y</th>\
                 <th>verdict</th></tr>{rows}</table>"
            );
        }
        let regions: String = f
            .regions
            .iter()
            .chain(f.missing.iter())
            .map(|g| {
                format!(
                    "<tr class=\"fail\"><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.0}</td>\
                     <td>{}</td><td>FAIL</td></tr>",
                    g.kind.as_str(),
                    f3(g.centroid),
                    f3(g.min),
                    f3(g.max),
                    g.area_m2 * 1e4,
                    mmf(g.peak)
                )
            })
            .collect();
        if regions.is_empty() && f.count() == 0 {
            out.push_str("<p>No findings beyond the tolerance.</p>");
        } else if !regions.is_empty() {
            let _ = write!(
                out,
                "<table><tr><th>kind</th><th>centre</th><th>from</th><th>to</th><th>area cm²</th>\
                 <th>peak</th><th>verdict</th></tr>{regions}</table>"
            );
        }
    }
    out
}
