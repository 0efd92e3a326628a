//! The HTML report: one self-contained page (inline CSS and SVG, no script, no network). It
//! opens with the summary a site manager reads (what is out of tolerance, where, since when,
//! what changed), then each scan layer's verdicts and deviation maps, the layer history, and
//! the stations with their histograms.

use std::fmt::Write;

use rayon::prelude::*;

use crate::maps::{MapKind, ScanLayerMaps, Side};
use crate::markup::esc;
use asbuilt_core::verdict::Verdict;

use crate::{Assessment, Item, Report, ScanLayerVerdicts, Section};

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

const STYLE: &str = "body{font-family:system-ui,sans-serif;margin:2em;color:#222;max-width:1400px}\
table{border-collapse:collapse;margin:.5em 0}td,th{padding:.25em .6em;border-bottom:1px solid #ddd;\
text-align:right}td:first-child,th:first-child{text-align:left}td.text{text-align:left}\
.fail{color:#c00;font-weight:bold}.warn{color:#b60;font-weight:bold}.pass{color:#282}\
.inconclusive{color:#62a;font-weight:bold}.not_judged{color:#777;font-style:italic}\
.verdict.inconclusive{background:#62a;color:#fff}.verdict.not_judged{background:#999;color:#fff}\
.verdict{display:inline-block;padding:.1em .6em;border-radius:.3em;color:#fff;font-weight:bold}\
.verdict.fail{background:#c00;color:#fff}.verdict.warn{background:#d80;color:#fff}\
.verdict.pass{background:#282;color:#fff}section.summary{border:2px solid #888;padding:.5em 1em;\
margin:1em 0}section.summary li{margin:.2em 0}figure{display:inline-block;margin:.3em .8em .3em 0;\
vertical-align:top}figcaption{font-size:.85em;color:#444}.maps{margin:.5em 0 1.5em}";

/// The whole page: the summary first, then each scan layer (latest first) with its verdicts
/// and maps, the layer history, the stations, the warnings.
pub fn page(r: &Report, source: &str) -> String {
    let tol = r.parameters.tolerance_m;
    let mut body = String::new();
    let _ = write!(
        body,
        "<h1>asbuilt inspection report</h1><p>{source}. Design {design} ({units}, {tri} \
         triangles). Tolerance ±{tolmm:.1} mm, maximum distance {maxmm:.1} mm. asbuilt {ver}.</p>",
        source = esc(source),
        design = esc(&r.design.path),
        units = esc(&r.design.units),
        tri = r.design.triangles,
        tolmm = tol * 1e3,
        maxmm = r.parameters.max_distance_m * 1e3,
        ver = r.asbuilt_version,
    );
    if let Some(a) = &r.assessment {
        body.push_str(&summary(a));
    }
    if let Some(f) = &r.flatness {
        body.push_str(&f.html());
    }
    if let Some(d) = &r.dimensions {
        body.push_str(&d.html());
    }
    body.push_str(&legend(tol));
    // The faces' worst gaps are marked on the maps of the scan layer judged.
    let flat_items = r
        .flatness
        .as_ref()
        .map(|f| f.map_items())
        .unwrap_or_default();
    let judged = |h: Option<f64>| {
        r.flatness
            .as_ref()
            .is_some_and(|f| f.printed_height_m.map(f64::to_bits) == h.map(f64::to_bits))
    };
    if let Some(a) = &r.assessment {
        for s in a.scan_layers.iter().rev() {
            let maps = r.maps.iter().find(|m| {
                m.job == s.job
                    && match s.printed_height {
                        Some(h) => m.printed_height.to_bits() == h.to_bits(),
                        None => !m.printed_height.is_finite(),
                    }
            });
            let extra: &[Item] = if judged(s.printed_height) {
                &flat_items
            } else {
                &[]
            };
            body.push_str(&scan_layer(s, maps, extra));
        }
        body.push_str(&crate::history::charts(a));
        body.push_str(&crate::history::corrections(
            &r.corrections,
            a.limits.top_height_m,
        ));
    }
    // Maps of scan layers without findings (C2M only).
    if r.assessment
        .as_ref()
        .is_none_or(|a| a.scan_layers.is_empty())
    {
        for m in &r.maps {
            body.push_str(&maps_html(m, &flat_items));
        }
    }
    body.push_str(&stations(r));
    let warnings = items(&r.warnings);
    format!(
        "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"/>\
         <title>asbuilt report</title><style>{STYLE}</style></head><body>{body}\
         <h2>Warnings</h2><ul>{warnings}</ul></body></html>\n"
    )
}

/// The `<li>` items of a list of texts, escaped.
fn items(texts: &[String]) -> String {
    texts
        .iter()
        .map(|t| format!("<li>{}</li>", esc(t)))
        .collect()
}

fn badge(verdict: Verdict) -> String {
    format!(
        "<span class=\"verdict {verdict}\">{}</span>",
        verdict.shout()
    )
}

fn summary(a: &Assessment) -> String {
    let lines = items(&a.summary);
    format!(
        "<section class=\"summary\" id=\"summary\"><h2>Summary {}</h2><ul>{lines}</ul>\
         <p>Limits: width ±{:.1} mm, top height ±{:.1} mm, position {:.1} mm, surface ±{:.1} mm, \
         missing area {:.0} cm², creep ±{:.1} mm; warn beyond {:.0} % of a limit{}.</p></section>",
        badge(a.verdict),
        a.limits.width_m * 1e3,
        a.limits.top_height_m * 1e3,
        a.limits.position_m * 1e3,
        a.limits.surface_m * 1e3,
        a.limits.missing_area_m2 * 1e4,
        a.limits.creep_m * 1e3,
        a.limits.warn_fraction * 100.0,
        if a.limits.ranges.is_empty() {
            String::new()
        } else {
            format!("; per layers: {}", esc(&a.limits.ranges.join(", ")))
        }
    )
}

/// The colour scale, once for every map.
fn legend(tolerance: f64) -> String {
    let t = tolerance * 1e3;
    let stops: String = (0..=10)
        .map(|i| {
            let d = tolerance * (f64::from(i) / 5.0 - 1.0);
            let [r, g, b] = asbuilt_core::colour::deviation_colour(d, tolerance);
            format!(
                "<stop offset=\"{}%\" stop-color=\"rgb({r},{g},{b})\"/>",
                i * 10
            )
        })
        .collect();
    format!(
        "<p><svg class=\"legend\" width=\"560\" height=\"34\" viewBox=\"0 0 560 34\" role=\"img\" \
         aria-label=\"colour scale\"><defs><linearGradient id=\"scale\">{stops}</linearGradient>\
         </defs><rect x=\"0\" y=\"0\" width=\"240\" height=\"14\" fill=\"url(#scale)\" \
         stroke=\"#888\"/><text x=\"0\" y=\"27\" font-size=\"10\">−{t:.1} mm missing</text>\
         <text x=\"120\" y=\"27\" font-size=\"10\" text-anchor=\"middle\">on design</text>\
         <text x=\"240\" y=\"27\" font-size=\"10\" text-anchor=\"end\">+{t:.1} mm excess</text>\
         <rect x=\"270\" y=\"0\" width=\"14\" height=\"14\" fill=\"rgb(0,0,255)\"/>\
         <text x=\"288\" y=\"11\" font-size=\"10\">missing material (a finding)</text>\
         <rect x=\"430\" y=\"0\" width=\"14\" height=\"14\" fill=\"rgb(222,222,222)\" \
         stroke=\"#888\"/><text x=\"448\" y=\"11\" font-size=\"10\">not judged</text>\
         <text x=\"448\" y=\"24\" font-size=\"8\">near an edge, out of view</text></svg>\
         </p><p>Maps: the part from each side and from above, coloured by signed deviation, \
         saturated at the tolerance; the dashed line is the printed height. Only what the findings \
         judged is coloured: a design sample they leave out (within reach of a sharp edge, on a \
         face no station saw, a missing patch smaller than counts) is grey. Numbered call-outs \
         are the findings of the table above each map; a bar beside a map marks a layer band.</p>"
    )
}

fn scan_layer(s: &ScanLayerVerdicts, maps: Option<&ScanLayerMaps>, extra: &[Item]) -> String {
    let mut out = format!(
        "<section class=\"scan-layer\" data-layer=\"{}\"><h2>{} {}</h2>\
         <p>{} station(s). {} finding(s) fail, {} inconclusive, {} warn, {} pass.{}</p>",
        s.layer,
        s.title(),
        badge(s.verdict),
        s.stations,
        s.counts.fail,
        s.counts.inconclusive,
        s.counts.warn,
        s.counts.pass,
        if s.counts.inconclusive > 0 {
            " An inconclusive finding lies within its uncertainty U of its limit: neither \
             proven in nor out. Most of its U is the stations' poses (about 1 mm each): a \
             station with a better known pose (a calibration), or one more station on that \
             side, settles it."
        } else {
            ""
        }
    );
    out.push_str(&layer_strip(s));
    if !s.items.is_empty() {
        let rows: String = s
            .items
            .iter()
            .map(|it| {
                format!(
                    "<tr class=\"item\" data-label=\"{l}\"><td>{l}</td><td class=\"text\">{}</td>\
                     <td class=\"{v}\">{V}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                    esc(&it.text),
                    it.limit_text(),
                    it.since + 1,
                    it.change,
                    l = it.label,
                    v = it.verdict,
                    V = it.verdict.as_str().to_uppercase()
                )
            })
            .collect();
        let _ = write!(
            out,
            "<table class=\"items\"><tr><th>#</th><th>finding</th><th>verdict</th><th>limit</th>\
             <th>since (layers)</th><th>since last scan</th></tr>{rows}</table>"
        );
    }
    if !s.resolved.is_empty() {
        let list = items(&s.resolved);
        let _ = write!(
            out,
            "<details><summary>{} resolved since the last scan</summary><ul>{list}</ul></details>",
            s.resolved.len()
        );
    }
    if let Some(m) = maps {
        let items: Vec<Item> = s.items.iter().chain(extra).cloned().collect();
        out.push_str(&maps_html(m, &items));
    }
    out.push_str("</section>");
    out
}

/// Every layer band seen, bed first, coloured by its verdict: where the part stands at a glance.
fn layer_strip(s: &ScanLayerVerdicts) -> String {
    if s.layers.is_empty() {
        return String::new();
    }
    let cell = (900.0 / s.layers.len() as f64).clamp(4.0, 24.0);
    let w = cell * s.layers.len() as f64;
    let mut svg = format!(
        "<p>Layer bands, from the bed (0) up:</p><svg class=\"layer-strip\" width=\"{w:.0}\" \
         height=\"30\" viewBox=\"0 0 {w:.0} 30\" role=\"img\" aria-label=\"verdict per layer band\">"
    );
    for (k, l) in s.layers.iter().enumerate() {
        let fill = match l.verdict {
            Verdict::Fail => "#c00",
            Verdict::Inconclusive => "#62a",
            Verdict::Warn => "#d80",
            Verdict::Pass => "#4a8",
            Verdict::NotJudged => "#999",
        };
        let _ = write!(
            svg,
            "<rect x=\"{:.1}\" y=\"0\" width=\"{:.1}\" height=\"16\" fill=\"{fill}\" \
             stroke=\"#fff\" data-layer=\"{}\" data-verdict=\"{}\"><title>layer {}: {}</title>\
             </rect>",
            k as f64 * cell,
            cell,
            l.layer,
            l.verdict,
            l.layer,
            l.verdict
        );
        if l.layer % 5 == 0 {
            let _ = write!(
                svg,
                "<text x=\"{:.1}\" y=\"28\" font-size=\"9\">{}</text>",
                k as f64 * cell,
                l.layer
            );
        }
    }
    svg.push_str("</svg>");
    svg
}

/// A scan layer's maps: the points' C2M, then the samples' M3C2, each from every side.
fn maps_html(m: &ScanLayerMaps, items: &[Item]) -> String {
    let mut out = String::new();
    for (kind, title) in [
        (MapKind::Points, "C2M of the points"),
        (
            MapKind::Samples,
            "M3C2 of the design samples, with missing material",
        ),
    ] {
        // The sides' PNGs are encoded in parallel: the page's one long serial step otherwise.
        let figures: String = Side::ALL
            .into_par_iter()
            .filter_map(|side| {
                let svg = m.svg(kind, side, items)?;
                Some(format!(
                    "<figure><figcaption>{}</figcaption>{svg}</figure>",
                    side.title()
                ))
            })
            .collect();
        if !figures.is_empty() {
            let _ = write!(
                out,
                "<div class=\"maps\" data-kind=\"{}\"><h3>{title}</h3>{figures}</div>",
                kind.name()
            );
        }
    }
    out
}

/// The stations: each one's verdict on its measurement, its numbers and its histogram.
fn stations(r: &Report) -> String {
    let tol = r.parameters.tolerance_m;
    let verdict_of = |i: usize| {
        let a = r.assessment.as_ref()?;
        a.stations.get(i).or(if i == r.stations.len() {
            a.overall.as_ref()
        } else {
            None
        })
    };
    let mut rows = String::new();
    let mut cards = String::new();
    for (i, s) in r
        .stations
        .iter()
        .chain(std::iter::once(&r.overall))
        .enumerate()
    {
        let v = verdict_of(i);
        let [mean, std, median, p95] = s.distances.mm_columns("–");
        let _ = write!(
            rows,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>\
             <td>{}</td><td>{}</td><td>{}</td><td class=\"{}\">{}</td><td class=\"text\">{}</td>\
             </tr>",
            esc(&s.id),
            s.points,
            s.rejected,
            s.distances.no_match,
            mean,
            std,
            median,
            p95,
            s.distances
                .in_tolerance_percent()
                .map_or("–".into(), |p| format!("{p:.1}")),
            v.map_or("", |v| v.verdict.as_str()),
            v.map_or_else(String::new, |v| v.verdict.as_str().to_uppercase()),
            v.map_or_else(String::new, |v| esc(&v.reason)),
        );
        let _ = write!(
            cards,
            "<figure><figcaption>{}</figcaption>{}</figure>",
            esc(&s.id),
            histogram(s, tol)
        );
    }
    format!(
        "<h2>Stations</h2><p>A station's verdict is about its measurement: it fails when its \
         typical point is off the design (a wrong pose, the wrong part), and warns when local \
         deviations or points far from the design call for the findings. Distances in \
         millimetres; positive is excess material.</p>\
         <table class=\"stations\"><tr><th>station</th><th>points</th><th>rejected</th>\
         <th>no match</th><th>mean</th><th>std</th><th>|d| median</th><th>|d| 95 %</th>\
         <th>in tolerance %</th><th>verdict</th><th>why</th></tr>{rows}</table>\
         <h3>Histograms</h3><p>Signed deviation, green within the tolerance (dashed lines), red \
         excess, blue missing material.</p>{cards}"
    )
}
