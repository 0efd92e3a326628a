//! The layer history's charts: how each layer band's width and shift moved from one scan layer
//! to the next, and the top's height at every scan layer. A band that widens as the layers
//! above load it (creep, sag) shows as lines that part where the others stay together.

use std::fmt::Write;

use asbuilt_core::verdict::Verdict;

use crate::Assessment;
use crate::markup::{Margins, esc};

/// One line of a chart.
struct Series {
    name: String,
    colour: String,
    points: Vec<(f64, f64)>,
}

/// A chart's size, and the room around its plot for the axes and the legend, pixels.
const W: f64 = 620.0;
const H: f64 = 220.0;
const MARGINS: Margins = Margins::new(50.0, 10.0, 150.0, 34.0);

/// A line chart with dashed limits at ±`limit` (mm), `class` naming what it shows.
fn chart(class: &str, series: &[Series], x_label: &str, y_label: &str, limit: f64) -> String {
    let Margins {
        left: l,
        top: t,
        right: r,
        bottom: b,
    } = MARGINS;
    let all = series.iter().flat_map(|s| s.points.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, -limit, limit);
    for &(x, y) in all {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !x0.is_finite() {
        return String::new();
    }
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    let pad = 0.08 * (y1 - y0).max(1e-9);
    let (y0, y1) = (y0 - pad, y1 + pad);
    let sx = |x: f64| l + (x - x0) / (x1 - x0) * (W - l - r);
    let sy = |y: f64| t + (y1 - y) / (y1 - y0) * (H - t - b);
    let mut svg = format!(
        "<svg class=\"chart {class}\" width=\"{W}\" height=\"{H}\" viewBox=\"0 0 {W} {H}\" \
         role=\"img\" aria-label=\"{}\"><rect x=\"{l}\" y=\"{t}\" width=\"{}\" height=\"{}\" \
         fill=\"none\" stroke=\"#bbb\"/>",
        esc(y_label),
        W - l - r,
        H - t - b
    );
    for y in [-limit, 0.0, limit] {
        let _ = write!(
            svg,
            "<line x1=\"{l}\" y1=\"{v:.1}\" x2=\"{:.1}\" y2=\"{v:.1}\" stroke=\"{}\" \
             stroke-dasharray=\"{}\"/><text x=\"{:.1}\" y=\"{:.1}\" font-size=\"10\" \
             text-anchor=\"end\">{y:+.1}</text>",
            W - r,
            if y == 0.0 { "#999" } else { "#c00" },
            if y == 0.0 { "1,0" } else { "4,3" },
            l - 4.0,
            sy(y) + 3.5,
            v = sy(y)
        );
    }
    for x in ticks(x0, x1) {
        let _ = write!(
            svg,
            "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"10\" text-anchor=\"middle\">{x}</text>",
            sx(x),
            H - b + 14.0
        );
    }
    let _ = write!(
        svg,
        "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"10\" text-anchor=\"middle\">{}</text>\
         <text x=\"4\" y=\"{:.1}\" font-size=\"10\">{}</text>",
        0.5 * (l + W - r),
        H - 4.0,
        esc(x_label),
        t + 8.0,
        esc(y_label)
    );
    for (k, s) in series.iter().enumerate() {
        let pts: Vec<String> = s
            .points
            .iter()
            .map(|&(x, y)| format!("{:.1},{:.1}", sx(x), sy(y)))
            .collect();
        let _ = write!(
            svg,
            "<polyline class=\"series\" data-name=\"{n}\" points=\"{}\" fill=\"none\" \
             stroke=\"{c}\" stroke-width=\"1.5\"/>",
            pts.join(" "),
            n = esc(&s.name),
            c = s.colour
        );
        for &(x, y) in &s.points {
            let _ = write!(
                svg,
                "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"2\" fill=\"{}\"/>",
                sx(x),
                sy(y),
                s.colour
            );
        }
        legend_entry(&mut svg, k, s);
    }
    svg.push_str("</svg>");
    svg
}

/// Series `k`'s line and name in the legend right of the plot.
fn legend_entry(svg: &mut String, k: usize, s: &Series) {
    let x = W - MARGINS.right;
    let y = MARGINS.top + 12.0 * k as f64 + 8.0;
    let _ = write!(
        svg,
        "<line x1=\"{:.1}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"{c}\" \
         stroke-width=\"2\"/><text x=\"{:.1}\" y=\"{:.1}\" font-size=\"10\">{}</text>",
        x + 10.0,
        x + 26.0,
        x + 30.0,
        y + 3.5,
        esc(&s.name),
        c = s.colour
    );
}

/// About five whole-number ticks over `a..=b`.
fn ticks(a: f64, b: f64) -> Vec<f64> {
    let span = b - a;
    let step = [1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0]
        .into_iter()
        .find(|s| span / s <= 8.0)
        .unwrap_or(200.0);
    let mut t = (a / step).ceil() * step;
    let mut out = Vec::new();
    while t <= b + 1e-9 {
        out.push(t);
        t += step;
    }
    out
}

/// Older scan layers lighter, the latest darkest.
fn shade(k: usize, n: usize) -> String {
    let f = if n <= 1 {
        1.0
    } else {
        k as f64 / (n - 1) as f64
    };
    let c = |light: f64, dark: f64| (light + (dark - light) * f).round() as u8;
    format!(
        "rgb({},{},{})",
        c(170.0, 20.0),
        c(200.0, 60.0),
        c(235.0, 140.0)
    )
}

/// The charts of the layer history, in millimetres.
pub fn charts(a: &Assessment) -> String {
    if a.layer_history.is_empty() {
        return String::new();
    }
    let mut scans: Vec<u32> = a
        .layer_history
        .iter()
        .flat_map(|h| h.scans.iter().map(|s| s.scan_layer))
        .collect();
    scans.sort_unstable();
    scans.dedup();
    let per_scan = |value: &dyn Fn(&crate::LayerScan) -> Option<f64>| -> Vec<Series> {
        scans
            .iter()
            .enumerate()
            .map(|(k, &scan)| Series {
                name: format!("after {} layers", scan + 1),
                colour: shade(k, scans.len()),
                points: a
                    .layer_history
                    .iter()
                    .filter_map(|h| {
                        let s = h.scans.iter().find(|s| s.scan_layer == scan)?;
                        Some((f64::from(h.layer), value(s)? * 1e3))
                    })
                    .collect(),
            })
            .filter(|s| !s.points.is_empty())
            .collect()
    };
    let width = per_scan(&|s| s.width);
    let relative = per_scan(&|s| s.width_relative);
    let shift = per_scan(&|s| s.shift.map(|[x, y]| x.hypot(y)));
    let top = vec![Series {
        name: "top".into(),
        colour: "#333".into(),
        points: a
            .layer_history
            .iter()
            .flat_map(|h| h.scans.iter())
            .filter_map(|s| Some((f64::from(s.scan_layer + 1), s.top? * 1e3)))
            .collect(),
    }];
    let l = &a.limits;
    let changed: String = a
        .layer_history
        .iter()
        .filter(|h| h.creep_verdict.is_some_and(|v| v != Verdict::Pass))
        .map(|h| {
            let v = h.creep_verdict.unwrap_or(Verdict::Pass);
            format!(
                "<tr><td>{}</td><td>{:.3}–{:.3}</td><td>{}</td><td class=\"{v}\">{}</td></tr>",
                h.layer,
                h.z_min,
                h.z_max,
                h.width_change
                    .map_or("–".into(), |c| format!("{:+.1}", c * 1e3)),
                v.as_str().to_uppercase()
            )
        })
        .collect();
    let changed = if changed.is_empty() {
        "<p>No layer band's width changed beyond the creep limit's warning.</p>".to_string()
    } else {
        format!(
            "<table class=\"creep\"><tr><th>layer</th><th>z (m)</th><th>width change mm</th>\
             <th>verdict</th></tr>{changed}</table>"
        )
    };
    format!(
        "<section class=\"history\"><h2>Layer history</h2><p>Every layer band in every scan \
         layer that saw it, from 0 at the bed. The relative width takes out what the stations' \
         pose errors do to every band of a scan layer alike; a band whose relative width grows \
         from one scan layer to the next is creeping or sagging under the layers above.</p>\
         <figure><figcaption>Width deviation per layer band (mm)</figcaption>{}</figure>\
         <figure><figcaption>Relative width per layer band (mm)</figcaption>{}</figure>\
         <figure><figcaption>Shift per layer band (mm)</figcaption>{}</figure>\
         <figure><figcaption>Top of the print minus the printed height (mm)</figcaption>{}\
         </figure>{changed}</section>",
        chart("width", &width, "layer band", "mm", l.width_m * 1e3),
        chart(
            "relative-width",
            &relative,
            "layer band",
            "mm",
            l.creep_m * 1e3
        ),
        chart("shift", &shift, "layer band", "mm", l.position_m * 1e3),
        chart("top", &top, "layers printed", "mm", l.top_height_m * 1e3),
    )
}

/// The advice after each scan layer beside what followed it: the top's error and the width of
/// the latest bands at the next scan layer (the evidence the next advice rests on), and a chart
/// of the advice over the print. Empty without advice.
pub fn corrections(cs: &[asbuilt_protocol::LayerCorrection], top_limit_m: f64) -> String {
    if cs.is_empty() {
        return String::new();
    }
    let mm = |v: f64| {
        if v.is_finite() {
            format!("{:+.2}", v * 1e3)
        } else {
            "–".into()
        }
    };
    let rows: String = cs
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let next = cs.get(k + 1);
            let z = if c.first_layers > 0 && c.z_first != c.z_then {
                format!(
                    "{} for {} layers, then {}",
                    mm(c.z_first),
                    c.first_layers,
                    mm(c.z_then)
                )
            } else {
                mm(c.z_then)
            };
            format!(
                "<tr class=\"advice\" data-layer=\"{}\"><td>{}</td><td>{}</td><td>{}</td>\
                 <td>{}</td><td>{z}</td><td>{:.3}</td><td>{} / {}</td><td>{}</td><td>{}</td></tr>",
                c.layer,
                c.layer + 1,
                mm(c.top.value),
                mm(c.width.value),
                c.from_layer + 1,
                c.flow,
                mm(c.path_offset[0]),
                mm(c.path_offset[1]),
                next.map_or("–".into(), |n| mm(n.top.value)),
                next.map_or("–".into(), |n| mm(n.width.value)),
            )
        })
        .collect();
    let x = |c: &asbuilt_protocol::LayerCorrection| f64::from(c.layer + 1);
    let series =
        |name: &str, colour: &str, v: &dyn Fn(&asbuilt_protocol::LayerCorrection) -> f64| Series {
            name: name.into(),
            colour: colour.into(),
            points: cs
                .iter()
                .filter(|c| v(c).is_finite())
                .map(|c| (x(c), v(c)))
                .collect(),
        };
    let chart_series = [
        series("top measured mm", "#333", &|c| c.top.value * 1e3),
        series("z first layers mm", "#c40", &|c| c.z_first * 1e3),
        series("z then mm", "#e90", &|c| c.z_then * 1e3),
        series("flow − 1 %", "#07a", &|c| (c.flow - 1.0) * 1e2),
        series("path mm", "#6a3", &|c| {
            c.path_offset[0].hypot(c.path_offset[1]) * 1e3
        }),
    ];
    format!(
        "<section class=\"corrections\"><h2>Corrections advised</h2><p>After each scan layer \
         (its last station), the agent's advice for the layers still to print: a z offset per \
         layer (the drift fed forward, and the top's error taken back over the first layers), a \
         flow factor (from the latest bands' width against the scan layer's median band) and a \
         path offset. The cell decides whether to apply it; what followed is what the next scan \
         layer measured.</p><figure><figcaption>Advice and the top's error, by layers printed\
         </figcaption>{}</figure><table class=\"advice\"><tr><th>after layers</th><th>top mm</th>\
         <th>latest bands' width mm</th><th>from layer</th><th>z mm a layer</th><th>flow</th>\
         <th>path x / y mm</th><th>then: top mm</th><th>then: width mm</th></tr>{rows}</table>\
         </section>",
        chart(
            "advice",
            &chart_series,
            "layers printed",
            "mm, %",
            top_limit_m * 1e3
        ),
    )
}
