//! Corrections for the layers still to print, from a scan layer's findings and the advice given
//! after the scan layers before it.
//!
//! Three loops, each closed over the scan history:
//! - **Height.** The top's error `e` grows by the process drift `d` per layer plus whatever
//!   z offset was printed. Between two scans `n` layers apart, `Δe = n·d + C`, where `C` is the
//!   sum of the offsets printed for those layers. The drift estimate takes the part of `Δe` the
//!   last estimate did not predict (`ν = Δe − n·d̂ − C`, so `d̂ += ν / n`). The advice feeds
//!   `−d̂` forward on every layer, and spreads `−e` over the next `absorb_layers` layers. A
//!   printer that applied only a share `g` of the z advised is asked for `1/g` times as much
//!   (`g` at least [`MIN_GAIN`]), within the limits.
//! - **Flow.** A band printed at flow `f` with a process excess `x` is `(b + x)·f` wide, for a
//!   nominal bead width `b`. The width error `w` measured on the bands printed under the last
//!   advice gives the flow that brings the width back: `f·b / (b + w)`.
//! - **Path.** The shift `s` measured on those bands, under the last path offset `p`, gives
//!   `p − s`.
//!
//! A scan layer's stations each carry their own pose error, a rigid offset of their points: it
//! moves the width and shift of every band of that scan layer alike (by a millimetre or more
//! with a 1 mm pose), and it changes from one scan layer to the next. So the latest bands are
//! read against the scan layer's median band: what a persistent excess or shift adds to them
//! beyond the part printed before. (An excess that covers most of the bands printed by the
//! first scan hides in that median.)
//!
//! Every value is held where its evidence is inside the deadband (the measurement's noise), and
//! clamped to its limits. A change of the top's error is a difference of two measurements, so
//! the drift estimate moves only when it is beyond √2 deadbands.
//!
//! `C`, the flow and the path offset in force are what the printer says it applied to each layer
//! ([`LayerApplied`], kept in [`PrintedLayers`]), not what was advised: the cell decides. A layer
//! it says nothing of is taken as printed as designed, and the advice says so
//! ([`CorrectionFlags::UNANSWERED`]).

use asbuilt_protocol::{CorrectionFlags, Evidence, LayerApplied, LayerCorrection, StationFindings};

use crate::stats::median;

mod applied;
pub use applied::{PrintedLayers, PrintedOver};

/// What a [`Corrector`] may advise, and from which evidence. Metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CorrectionLimits {
    /// The largest z offset advised for any one layer.
    pub max_z_per_layer: f64,
    /// The flow factor's range.
    pub flow: (f64, f64),
    /// The largest path offset advised, in the plane.
    pub max_path_offset: f64,
    /// Errors and changes within this are noise: the advice is held.
    pub deadband: f64,
    /// Layers over which an accumulated top error is taken back.
    pub absorb_layers: u32,
    /// The latest bands whose width and shift count (of those printed since the last scan).
    pub bands: u32,
    /// The nominal width of a printed layer; without it no flow is advised.
    pub bead_width: Option<f64>,
}

impl Default for CorrectionLimits {
    fn default() -> Self {
        Self {
            max_z_per_layer: 0.002,
            flow: (0.85, 1.15),
            max_path_offset: 0.02,
            deadband: 0.0015,
            absorb_layers: 4,
            bands: 3,
            bead_width: None,
        }
    }
}

/// Limits that cannot be worked with, each named.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CorrectionLimitsError {
    /// A length that must be positive and finite.
    #[error("{name} = {value}: give metres above 0")]
    Length {
        /// The setting.
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// A deadband below zero or not finite.
    #[error("deadband = {0}: give metres, 0 or more")]
    Deadband(f64),
    /// A flow range that does not hold 1.
    #[error("flow range {0}..{1}: give a range around 1, such as 0.85..1.15")]
    Flow(f64, f64),
    /// A count of layers or bands of zero.
    #[error("{0} must be at least 1")]
    Count(&'static str),
}

impl CorrectionLimits {
    /// Checks every value; the error names the first that is wrong.
    pub fn check(&self) -> Result<(), CorrectionLimitsError> {
        let positive = |name, value: f64| {
            if value > 0.0 && value.is_finite() {
                Ok(())
            } else {
                Err(CorrectionLimitsError::Length { name, value })
            }
        };
        positive("max_z_per_layer", self.max_z_per_layer)?;
        positive("max_path_offset", self.max_path_offset)?;
        if let Some(b) = self.bead_width {
            positive("bead_width", b)?;
        }
        if !(self.deadband >= 0.0 && self.deadband.is_finite()) {
            return Err(CorrectionLimitsError::Deadband(self.deadband));
        }
        let (lo, hi) = self.flow;
        if !(lo > 0.0 && lo <= 1.0 && hi >= 1.0 && hi.is_finite()) {
            return Err(CorrectionLimitsError::Flow(lo, hi));
        }
        if self.absorb_layers == 0 {
            return Err(CorrectionLimitsError::Count("absorb_layers"));
        }
        if self.bands == 0 {
            return Err(CorrectionLimitsError::Count("bands"));
        }
        Ok(())
    }
}

/// Advice over one job's scan layers: each scan layer's latest advice, and the one of the
/// scan layer before it, which the next scan layer's advice builds on. A few hundred bytes,
/// whatever the job's length.
#[derive(Debug, Clone)]
pub struct Corrector {
    limits: CorrectionLimits,
    /// The latest advice of the scan layer before the current one.
    settled: Option<LayerCorrection>,
    /// The latest advice of the current scan layer.
    current: Option<LayerCorrection>,
    /// What the printer says it applied, from the first layer an advice still builds on.
    printed: PrintedLayers,
}

impl Corrector {
    /// A corrector that has advised nothing yet.
    pub fn new(limits: CorrectionLimits) -> Self {
        Self {
            limits,
            settled: None,
            current: None,
            printed: PrintedLayers::default(),
        }
    }

    /// Its limits.
    pub fn limits(&self) -> &CorrectionLimits {
        &self.limits
    }

    /// The advice after a station's findings (`attempt`, the station's; `sigma`, its pose's
    /// one-sigma position error, which bounds how well the top's height is known). It replaces
    /// the advice of the same scan layer's earlier stations.
    pub fn advise(&mut self, f: &StationFindings, attempt: u8, sigma: f64) -> LayerCorrection {
        let base = self.base_for(f.job, f.layer);
        let c = advise(
            &self.limits,
            base.as_ref(),
            &self.printed,
            f,
            attempt,
            sigma,
        );
        self.keep(c);
        c
    }

    /// Takes what the printer says it applied to a layer; false (and nothing kept) for values
    /// that are not usable.
    pub fn applied(&mut self, a: &LayerApplied) -> bool {
        self.printed.take(a)
    }

    /// Takes up advice given before (read back from a recording), in the order it was given,
    /// clamped to today's limits (they may have been tightened since).
    pub fn restore(&mut self, c: &LayerCorrection) {
        let mut c = *c;
        let l = &self.limits;
        let m = l.max_z_per_layer;
        c.z_first = c.z_first.clamp(-m, m);
        c.z_then = c.z_then.clamp(-m, m);
        c.flow = c.flow.clamp(l.flow.0, l.flow.1);
        c.path_offset = clamp_path(c.path_offset, l.max_path_offset);
        self.keep(c);
    }

    /// The advice the next builds on, oldest first: the latest of the scan layer before the
    /// current one, and the current one's latest.
    pub fn history(&self) -> impl Iterator<Item = &LayerCorrection> {
        self.settled.iter().chain(self.current.iter())
    }

    /// Forgets everything of `job`: a new print under its number builds on nothing of the
    /// last one.
    pub fn forget_job(&mut self, job: u64) {
        self.settled = self.settled.filter(|c| c.job != job);
        self.current = self.current.filter(|c| c.job != job);
        self.printed.forget_below(job, u32::MAX);
    }

    /// The latest advice given, if any.
    pub fn latest(&self) -> Option<&LayerCorrection> {
        self.current.as_ref()
    }

    /// The advice the scan layer ending at `layer` builds on: the latest of an earlier one.
    fn base_for(&self, job: u64, layer: u32) -> Option<LayerCorrection> {
        [self.current, self.settled]
            .into_iter()
            .flatten()
            .filter(|c| c.job == job && c.layer < layer)
            .max_by_key(|c| c.layer)
    }

    fn keep(&mut self, c: LayerCorrection) {
        let Some(cur) = self.current else {
            self.current = Some(c);
            return;
        };
        if cur.job != c.job {
            // Another job: nothing of this one's history applies.
            self.settled = None;
            self.current = Some(c);
        } else if c.layer > cur.layer {
            self.settled = Some(cur);
            self.current = Some(c);
            // The next advice builds on this scan layer's or the one before: what was
            // printed before the one before is of no use any more.
            self.printed.forget_below(cur.job, cur.layer + 1);
        } else if c.layer == cur.layer {
            self.current = Some(c);
        } else if self.settled.is_some_and(|s| s.layer <= c.layer) {
            // A late station of the scan layer before.
            self.settled = Some(c);
        }
    }
}

/// The advice after findings `f`, building on `base`, the advice in force while the layers
/// since the last scan were printed.
pub fn advise(
    limits: &CorrectionLimits,
    base: Option<&LayerCorrection>,
    printed: &PrintedLayers,
    f: &StationFindings,
    attempt: u8,
    sigma: f64,
) -> LayerCorrection {
    let mut c = LayerCorrection::neutral(f.job, f.station, attempt, f.layer);
    let mut flags = 0;
    let since = base.map_or(0, |b| b.layer + 1)..f.layer + 1;
    let over = printed.over(f.job, since);
    if base.is_some() && over.unanswered > 0 {
        flags |= CorrectionFlags::UNANSWERED;
    }
    flags |= advise_height(limits, base, over.z, f, sigma, &mut c);
    let latest = latest_bands(limits, base, f);
    // The flow and path the latest bands were printed at.
    let in_force = match (latest.first(), latest.last()) {
        (Some(a), Some(b)) => printed.over(f.job, a.layer..b.layer + 1),
        _ => over,
    };
    let bands = Bands {
        limits,
        in_force,
        f,
        latest,
    };
    flags |= advise_flow(&bands, &mut c);
    flags |= advise_path(&bands, &mut c);
    c.flags = flags;
    c
}

/// The least share of the advised z offsets a printer is taken to apply: below it, asking for
/// more would only meet the limits.
pub const MIN_GAIN: f64 = 0.25;

/// The z schedule: the drift estimate updated by what the last one did not predict (`applied`:
/// the z offsets printed since the last scan), fed forward, and the top's error spread over
/// the next layers.
fn advise_height(
    limits: &CorrectionLimits,
    base: Option<&LayerCorrection>,
    applied: f64,
    f: &StationFindings,
    sigma: f64,
    c: &mut LayerCorrection,
) -> u32 {
    let printed = f.layer + 1;
    // Before the first advice: the bed, printed as designed, with no drift known.
    let (e_prev, printed_prev, drift_prev) = match base {
        Some(b) => (b.top.value, b.layer + 1, b.drift_per_layer),
        None => (0.0, 0, 0.0),
    };
    let seen = f.top_samples > 0 && f.top_height_deviation.is_finite();
    let mut flags = 0;
    let (drift, absorb) = if seen {
        let e = f.top_height_deviation;
        c.top = Evidence {
            value: e,
            value_y: f64::NAN,
            sigma,
            samples: f.top_samples,
            bands: 1,
        };
        let n = printed.saturating_sub(printed_prev).max(1);
        let drift = if e_prev.is_finite() {
            let innovation = e - e_prev - n as f64 * drift_prev - applied;
            if innovation.abs() > std::f64::consts::SQRT_2 * limits.deadband {
                drift_prev + innovation / n as f64
            } else {
                drift_prev
            }
        } else {
            // The last scan did not see the top: the change since then is unknown.
            drift_prev
        };
        let absorb = if e.abs() > limits.deadband {
            -e / limits.absorb_layers as f64
        } else {
            0.0
        };
        if drift == drift_prev && absorb == 0.0 {
            flags |= CorrectionFlags::Z_HELD;
        }
        (drift, absorb)
    } else {
        flags |= CorrectionFlags::Z_UNSEEN;
        (drift_prev, 0.0)
    };
    c.drift_per_layer = drift;
    let m = limits.max_z_per_layer;
    // A printer that applied part of the z offsets advised (its own choice: it is advice) is
    // asked for that much more, within the limits, so that what it applies takes the error
    // back; a half-applying printer would otherwise hold the top 8 layers' drift high.
    let advised = base.map_or(0.0, |b| b.z_over(printed_prev, printed));
    let gain = if advised.abs() > limits.deadband {
        (applied / advised).clamp(MIN_GAIN, 1.0)
    } else {
        1.0
    };
    let (first, then) = ((-drift + absorb) / gain, -drift / gain);
    if first.abs() > m || then.abs() > m {
        flags |= CorrectionFlags::Z_CLAMPED;
    }
    // `+ 0.0` turns a −0 (no drift, negated) into 0.
    c.z_first = first.clamp(-m, m) + 0.0;
    c.z_then = then.clamp(-m, m) + 0.0;
    c.first_layers = if absorb != 0.0 {
        limits.absorb_layers
    } else {
        0
    };
    if c.first_layers == 0 {
        c.z_first = c.z_then;
    }
    flags
}

/// The layer bands the flow and path advice read: the latest `bands` of those printed since the
/// last advice (under it).
fn latest_bands<'f>(
    limits: &CorrectionLimits,
    base: Option<&LayerCorrection>,
    f: &'f StationFindings,
) -> Vec<&'f asbuilt_protocol::LayerFinding> {
    let printed = f.layer + 1;
    let since = base.map_or(0, |b| b.from_layer);
    let lo = since.max(printed.saturating_sub(limits.bands));
    f.layers
        .iter()
        .filter(|r| (lo..printed).contains(&r.layer))
        .collect()
}

/// What the flow and path advice read: the findings' layer bands, the latest of them, and
/// what they were printed at.
struct Bands<'f> {
    limits: &'f CorrectionLimits,
    in_force: PrintedOver,
    f: &'f StationFindings,
    /// See [`latest_bands`].
    latest: Vec<&'f asbuilt_protocol::LayerFinding>,
}

/// The flow that brings the latest bands' width, against the scan layer's median band, back
/// to the bead's.
fn advise_flow(b: &Bands<'_>, c: &mut LayerCorrection) -> u32 {
    let (limits, f, bands) = (b.limits, b.f, &b.latest);
    let flow_prev = b.in_force.flow;
    c.flow = flow_prev;
    let Some(reference) = median(f.layers.iter().filter_map(|r| r.width())) else {
        return CorrectionFlags::FLOW_UNSEEN;
    };
    let widths: Vec<f64> = bands
        .iter()
        .filter_map(|r| r.width())
        .map(|w| w - reference)
        .collect();
    let samples = bands
        .iter()
        .filter(|r| r.width().is_some())
        .map(|r| r.samples)
        .sum();
    let Some(w) = median(widths.clone()) else {
        return CorrectionFlags::FLOW_UNSEEN;
    };
    c.width = Evidence {
        value: w,
        value_y: f64::NAN,
        sigma: spread(&widths),
        samples,
        bands: widths.len() as u32,
    };
    let Some(bead) = limits.bead_width else {
        return CorrectionFlags::FLOW_UNSEEN;
    };
    if w.abs() <= limits.deadband {
        return CorrectionFlags::FLOW_HELD;
    }
    let (lo, hi) = limits.flow;
    // A band narrower than nothing is not a width: take the least flow.
    let wanted = if bead + w > 0.0 {
        flow_prev * bead / (bead + w)
    } else {
        lo
    };
    c.flow = wanted.clamp(lo, hi);
    if c.flow != wanted {
        CorrectionFlags::FLOW_CLAMPED
    } else {
        0
    }
}

/// The path offset that takes the latest bands' shift, against the scan layer's median band,
/// back.
fn advise_path(b: &Bands<'_>, c: &mut LayerCorrection) -> u32 {
    let (limits, f, bands) = (b.limits, b.f, &b.latest);
    let path_prev = b.in_force.path;
    c.path_offset = path_prev;
    let all: Vec<[f64; 2]> = f.layers.iter().filter_map(|r| r.shift_xy()).collect();
    let (Some(rx), Some(ry)) = (
        median(all.iter().map(|s| s[0])),
        median(all.iter().map(|s| s[1])),
    ) else {
        return CorrectionFlags::PATH_UNSEEN;
    };
    let shifts: Vec<[f64; 2]> = bands
        .iter()
        .filter_map(|r| r.shift_xy())
        .map(|s| [s[0] - rx, s[1] - ry])
        .collect();
    let (Some(sx), Some(sy)) = (
        median(shifts.iter().map(|s| s[0])),
        median(shifts.iter().map(|s| s[1])),
    ) else {
        return CorrectionFlags::PATH_UNSEEN;
    };
    let norms: Vec<f64> = shifts.iter().map(|s| s[0].hypot(s[1])).collect();
    c.shift = Evidence {
        value: sx,
        value_y: sy,
        sigma: spread(&norms),
        samples: bands
            .iter()
            .filter(|r| r.shift_xy().is_some())
            .map(|r| r.samples)
            .sum(),
        bands: shifts.len() as u32,
    };
    if sx.hypot(sy) <= limits.deadband {
        return CorrectionFlags::PATH_HELD;
    }
    let p = [path_prev[0] - sx, path_prev[1] - sy];
    c.path_offset = clamp_path(p, limits.max_path_offset);
    if c.path_offset != p {
        CorrectionFlags::PATH_CLAMPED
    } else {
        0
    }
}

/// `p` scaled back to length `m` when it is longer.
fn clamp_path(p: [f64; 2], m: f64) -> [f64; 2] {
    let norm = p[0].hypot(p[1]);
    if norm > m {
        [p[0] * m / norm, p[1] * m / norm]
    } else {
        p
    }
}

/// The sample standard deviation (m3c2's running statistics); NaN below two values.
fn spread(v: &[f64]) -> f64 {
    let mut r = crate::m3c2::Running::default();
    for &x in v {
        r.push(x);
    }
    r.std().unwrap_or(f64::NAN)
}

#[cfg(test)]
mod tests;
