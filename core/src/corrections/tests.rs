//! The corrector against a printer simulated layer by layer.

use super::*;
use asbuilt_protocol::{LayerApplied, LayerFinding};

const H: f64 = 0.02;

/// A printer simulated per layer: process drift, width excess and shift, with the share
/// `apply` of the advice in force applied from the layer it is for, and said.
struct Printer {
    apply: f64,
    /// What it applied to each layer, as it answers the agent.
    applied: Vec<LayerApplied>,
    drift: Box<dyn Fn(u32) -> f64>,
    excess: Box<dyn Fn(u32) -> f64>,
    shift: [f64; 2],
    shift_from: u32,
    bead: f64,
    /// Per printed layer: height error gained, width error, shift.
    layers: Vec<(f64, f64, [f64; 2])>,
}

impl Printer {
    fn print_to(&mut self, printed: u32, advice: Option<&LayerCorrection>) {
        for j in self.layers.len() as u32..printed {
            let (dz, flow, path) = advice.map_or((0.0, 1.0, [0.0; 2]), |c| {
                if j >= c.from_layer {
                    let k = self.apply;
                    let p = c.path_offset;
                    (
                        c.z_offset(j) * k,
                        1.0 + (c.flow - 1.0) * k,
                        [p[0] * k, p[1] * k],
                    )
                } else {
                    (0.0, 1.0, [0.0; 2])
                }
            });
            self.applied.push(LayerApplied {
                z_offset: dz,
                flow,
                path_offset: path,
                ..LayerApplied::nominal(1, j)
            });
            let width = (self.bead + (self.excess)(j)) * flow - self.bead;
            let s = if j >= self.shift_from {
                self.shift
            } else {
                [0.0; 2]
            };
            let shift = [s[0] + path[0], s[1] + path[1]];
            self.layers.push(((self.drift)(j) + dz, width, shift));
        }
    }

    fn findings(&self, noise: f64) -> StationFindings {
        let printed = self.layers.len() as u32;
        let mut f = StationFindings::new(1, printed);
        f.layer = printed - 1;
        f.printed_height = printed as f64 * H;
        f.top_height_deviation = self.layers.iter().map(|l| l.0).sum::<f64>() + noise;
        f.top_samples = 100;
        for (j, l) in self.layers.iter().enumerate() {
            let wobble = if j % 2 == 0 { noise } else { -noise };
            f.layers
                .push(LayerFinding {
                    layer: j as u32,
                    z_min: j as f64 * H,
                    z_max: (j + 1) as f64 * H,
                    samples: 50,
                    mean: 0.0,
                    width_deviation: l.1 + wobble,
                    shift: [l.2[0] + wobble, l.2[1]],
                    width_uncertainty: 0.001,
                    shift_uncertainty: 0.001,
                    width_fit_uncertainty: 0.0005,
                    width_verdict: asbuilt_protocol::SurveyVerdict::NotJudged,
                    shift_verdict: asbuilt_protocol::SurveyVerdict::NotJudged,
                })
                .unwrap();
        }
        f
    }
}

fn printer(drift: impl Fn(u32) -> f64 + 'static, excess: impl Fn(u32) -> f64 + 'static) -> Printer {
    Printer {
        apply: 1.0,
        applied: Vec::new(),
        drift: Box::new(drift),
        excess: Box::new(excess),
        shift: [0.0; 2],
        shift_from: 0,
        bead: 0.06,
        layers: Vec::new(),
    }
}

/// Runs scans after `scans` layers, closed loop or not; the top error at each scan.
fn run(
    p: &mut Printer,
    scans: &[u32],
    limits: CorrectionLimits,
    closed: bool,
    noise: f64,
) -> Vec<(f64, LayerCorrection)> {
    let mut k = Corrector::new(limits);
    let mut out = Vec::new();
    let mut advice: Option<LayerCorrection> = None;
    for (i, &s) in scans.iter().enumerate() {
        let from = p.layers.len();
        p.print_to(s, if closed { advice.as_ref() } else { None });
        for a in &p.applied[from..] {
            assert!(k.applied(a));
        }
        let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
        let f = p.findings(sign * noise);
        let c = k.advise(&f, 1, 0.001);
        out.push((f.top_height_deviation, c));
        advice = Some(c);
    }
    out
}

fn limits() -> CorrectionLimits {
    CorrectionLimits {
        bead_width: Some(0.06),
        ..CorrectionLimits::default()
    }
}

#[test]
fn a_drift_from_mid_interval_is_stopped_at_once_and_taken_back_when_learned() {
    let scans = [8, 16, 24, 32, 40, 48];
    let drift = |j: u32| if j >= 20 { 0.0006 } else { 0.0 };
    let open = run(&mut printer(drift, |_| 0.0), &scans, limits(), false, 0.0);
    let closed = run(&mut printer(drift, |_| 0.0), &scans, limits(), true, 0.0);
    assert!((open[5].0 - 0.0168).abs() < 1e-12);
    // Seen first at 24 (+2.4 mm, 4 layers in): spread over the 8 layers since the last
    // scan, the drift is under-estimated (0.3 mm a layer), which stops the growth. At 32
    // the drift is learned, and the error is gone by 40.
    assert!((closed[2].0 - 0.0024).abs() < 1e-12);
    assert!((closed[2].1.drift_per_layer - 0.0003).abs() < 1e-12);
    assert!((closed[3].0 - 0.0024).abs() < 1e-12, "{:?}", closed[3]);
    assert!((closed[3].1.drift_per_layer - 0.0006).abs() < 1e-12);
    assert!(closed[4].0.abs() < 1e-12 && closed[5].0.abs() < 1e-12);
    assert!((closed[5].1.z_then + 0.0006).abs() < 1e-12);
}

#[test]
fn an_over_extrusion_is_taken_back_by_flow_and_restored_when_it_ends() {
    let scans = [8, 16, 24, 32, 40, 48];
    let excess = |j: u32| if (10..=35).contains(&j) { 0.006 } else { 0.0 };
    let mut p = printer(|_| 0.0, excess);
    let closed = run(&mut p, &scans, limits(), true, 0.0);
    // Seen at 16 (bands 13..15): flow 0.06 / 0.066 from layer 16 on.
    assert!((closed[1].1.flow - 0.06 / 0.066).abs() < 1e-12);
    let widths = |a: usize, b: usize| p.layers[a..b].iter().map(|l| l.1.abs()).fold(0.0, f64::max);
    assert!(widths(16, 36) < 1e-12, "{}", widths(16, 36));
    // The excess ends at 35; the next scan sees bands too narrow and the flow comes back.
    assert!((closed[4].1.flow - 1.0).abs() < 1e-12, "{:?}", closed[4].1);
    assert!(widths(40, 48) < 1e-12);
}

#[test]
fn a_shift_is_taken_back_by_the_path() {
    let mut p = printer(|_| 0.0, |_| 0.0);
    p.shift = [0.004, -0.003];
    p.shift_from = 12;
    let closed = run(&mut p, &[8, 16, 24], limits(), true, 0.0);
    assert_eq!(closed[0].1.path_offset, [0.0, 0.0]);
    assert_eq!(closed[1].1.path_offset, [-0.004, 0.003]);
    assert!(p.layers[16..].iter().all(|l| l.2[0].hypot(l.2[1]) < 1e-12));
    assert!(closed[2].1.flags().contains(CorrectionFlags::PATH_HELD));
}

#[test]
fn noise_inside_the_deadband_advises_nothing() {
    // Top and widths off by up to 0.9 mm, alternating: changes of 1.8 mm, inside √2 × 1.5.
    let scans = [8, 16, 24, 32, 40, 48];
    let closed = run(
        &mut printer(|_| 0.0, |_| 0.0),
        &scans,
        limits(),
        true,
        0.0009,
    );
    for (_, c) in &closed {
        assert!(c.is_neutral(), "{c:?}");
        let f = c.flags();
        assert!(f.contains(CorrectionFlags::Z_HELD) && f.contains(CorrectionFlags::FLOW_HELD));
    }
}

#[test]
fn advice_never_leaves_its_limits() {
    let l = CorrectionLimits {
        max_z_per_layer: 0.0005,
        flow: (0.95, 1.05),
        max_path_offset: 0.002,
        ..limits()
    };
    let mut p = printer(
        |j| 0.002 * (j % 3) as f64,
        |j| 0.03 * ((j % 5) as f64 - 2.0),
    );
    p.shift = [0.01, 0.01];
    p.shift_from = 10;
    for (_, c) in run(&mut p, &[4, 9, 13, 20, 27, 33, 40, 48], l, true, 0.001) {
        for z in [c.z_first, c.z_then] {
            assert!(z.abs() <= l.max_z_per_layer, "{c:?}");
        }
        assert!((l.flow.0..=l.flow.1).contains(&c.flow), "{c:?}");
        assert!(c.path_offset[0].hypot(c.path_offset[1]) <= l.max_path_offset + 1e-15);
    }
}

#[test]
fn a_restored_corrector_advises_as_the_one_that_never_stopped() {
    let drift = |j: u32| if j >= 5 { 0.0007 } else { 0.0 };
    let mut p = printer(drift, |j| if j > 6 { 0.004 } else { 0.0 });
    let mut a = Corrector::new(limits());
    let mut given = Vec::new();
    for s in [8, 16, 24, 32] {
        let from = p.layers.len();
        p.print_to(s, given.last());
        for l in &p.applied[from..] {
            a.applied(l);
        }
        if s < 32 {
            given.push(a.advise(&p.findings(0.0), 1, 0.001));
        }
    }
    let f = p.findings(0.0);
    // What a recording gives back: the advice and the printer's answers, in order.
    let mut b = Corrector::new(limits());
    for c in &given {
        b.restore(c);
    }
    for l in &p.applied {
        b.applied(l);
    }
    let bytes = |c: LayerCorrection| asbuilt_protocol::codec::encode(&c);
    assert_eq!(bytes(a.advise(&f, 1, 0.001)), bytes(b.advise(&f, 1, 0.001)));
}

#[test]
fn bad_limits_are_named() {
    let bad = |f: fn(&mut CorrectionLimits)| {
        let mut l = CorrectionLimits::default();
        f(&mut l);
        l.check().unwrap_err().to_string()
    };
    assert!(bad(|l| l.max_z_per_layer = 0.0).contains("max_z_per_layer"));
    assert!(bad(|l| l.flow = (1.1, 1.2)).contains("flow range"));
    assert!(bad(|l| l.deadband = f64::NAN).contains("deadband"));
    assert!(bad(|l| l.absorb_layers = 0).contains("absorb_layers"));
    assert!(CorrectionLimits::default().check().is_ok());
}

/// The column of the issue: 0.6 mm a layer of drift, scanned every 8 layers, the printer
/// applying none or half of each advice and saying what it applied.
fn partly_applied(apply: f64) -> (Printer, Vec<(f64, LayerCorrection)>) {
    let mut p = printer(|_| 0.0006, |_| 0.0);
    p.apply = apply;
    let scans: Vec<u32> = (1..=8).map(|k| 8 * k).collect();
    let out = run(&mut p, &scans, limits(), true, 0.0);
    (p, out)
}

#[test]
fn the_drift_is_estimated_from_what_the_printer_applied() {
    for apply in [0.0, 0.5, 1.0] {
        let (p, out) = partly_applied(apply);
        for (top, c) in &out {
            assert!(
                (c.drift_per_layer - 0.0006).abs() <= 0.25 * 0.0006,
                "apply {apply}: drift {:.3} mm a layer, top {:.1} mm",
                c.drift_per_layer * 1e3,
                top * 1e3
            );
            let l = limits();
            assert!(c.z_first.abs() <= l.max_z_per_layer && c.z_then.abs() <= l.max_z_per_layer);
            assert!(!c.flags().contains(CorrectionFlags::UNANSWERED));
        }
        let top: f64 = p.layers.iter().map(|l| l.0).sum();
        if apply == 0.5 {
            assert!(
                top.abs() <= 0.003,
                "half applied: the top ends {:.2} mm off",
                top * 1e3
            );
        }
        if apply == 0.0 {
            assert!(
                (top - 64.0 * 0.0006).abs() < 1e-12,
                "nothing applied, nothing changed"
            );
        }
    }
}

#[test]
fn a_printer_that_does_not_answer_is_taken_to_have_printed_as_designed() {
    // It applies nothing and says nothing: the agent assumes nothing was applied, so the
    // drift stays at what it is (before, it assumed its advice applied and the estimate of a
    // 0.5 mm drift climbed to 2.25 mm a layer).
    let mut p = printer(|_| 0.0005, |_| 0.0);
    p.apply = 0.0;
    let mut k = Corrector::new(limits());
    let mut advice: Option<LayerCorrection> = None;
    for s in (1..=8).map(|k| 8 * k) {
        p.print_to(s, advice.as_ref());
        let c = k.advise(&p.findings(0.0), 1, 0.001);
        assert!((c.drift_per_layer - 0.0005).abs() < 1e-12, "{c:?}");
        let unanswered = c.flags().contains(CorrectionFlags::UNANSWERED);
        assert_eq!(
            unanswered,
            advice.is_some(),
            "said once advice was in force"
        );
        advice = Some(c);
    }
}

#[test]
fn restored_advice_is_clamped_to_todays_limits() {
    let mut wide = LayerCorrection::neutral(1, 0, 1, 7);
    wide.z_first = -0.004;
    wide.z_then = 0.003;
    wide.flow = 1.4;
    wide.path_offset = [0.03, 0.04];
    let l = limits();
    let mut k = Corrector::new(l);
    k.restore(&wide);
    let c = k.latest().unwrap();
    assert_eq!(
        (c.z_first, c.z_then),
        (-l.max_z_per_layer, l.max_z_per_layer)
    );
    assert_eq!(c.flow, l.flow.1);
    assert!((c.path_offset[0].hypot(c.path_offset[1]) - l.max_path_offset).abs() < 1e-15);
}
