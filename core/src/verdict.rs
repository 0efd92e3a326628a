//! Verdicts: pass, warn or fail, against the limits a crew sets per kind of deviation and,
//! where the part asks for it, per range of layers.
//!
//! A value fails beyond its limit and warns beyond `warn_fraction` of it. Missing material is
//! never a pass: a reported missing area warns, and fails beyond its area limit. Where ranges
//! overlap, the last one given wins for the layers it covers; a finding that spans layers with
//! different limits is held to the strictest of them.

use std::fmt;
use std::str::FromStr;

/// How a value stands against its limit, worst last. Serialised as [`Verdict::as_str`] spells it.
///
/// `NotJudged` sorts first, so that the worst of several verdicts ignores what was not judged
/// and is `NotJudged` only when nothing was. `Inconclusive` (ISO 14253-1: neither conformance nor
/// non-conformance proven within the measurement's uncertainty) sorts between `Warn` and `Fail`:
/// nobody can sign it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize),
    serde(rename_all = "snake_case")
)]
pub enum Verdict {
    /// Nothing was measured well enough to judge.
    NotJudged,
    /// Within the warning fraction of the limit.
    Pass,
    /// Beyond the warning fraction, within the limit.
    Warn,
    /// Within the measurement's uncertainty of the limit: neither pass nor fail is proven.
    Inconclusive,
    /// Beyond the limit.
    Fail,
}

impl Verdict {
    /// `not_judged`, `pass`, `warn`, `inconclusive` or `fail`.
    pub fn as_str(self) -> &'static str {
        match self {
            Verdict::NotJudged => "not_judged",
            Verdict::Pass => "pass",
            Verdict::Warn => "warn",
            Verdict::Inconclusive => "inconclusive",
            Verdict::Fail => "fail",
        }
    }

    /// For people: `NOT JUDGED`, `PASS`, ...
    pub fn shout(self) -> String {
        self.as_str().replace('_', " ").to_uppercase()
    }
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How a measured value and its expanded uncertainty are turned into a verdict.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(rename_all = "kebab-case")
)]
pub enum DecisionRule {
    /// ISO 14253-1:2017 (guarded acceptance and rejection): conformance is proven when the
    /// value plus its expanded uncertainty U is within the limit, non-conformance when the
    /// value less U is beyond it; anything between is inconclusive.
    #[default]
    #[cfg_attr(feature = "serde", serde(rename = "iso14253-1"))]
    Iso14253_1,
    /// Simple acceptance (ILAC-G8:09/2019 §4.2.1): the value alone against the limit, U only
    /// reported.
    Simple,
}

impl DecisionRule {
    /// As `--decision-rule` and agent.toml spell it.
    pub fn as_str(self) -> &'static str {
        match self {
            DecisionRule::Iso14253_1 => "iso14253-1",
            DecisionRule::Simple => "simple",
        }
    }

    /// For people, in a report's summary.
    pub fn describe(self) -> &'static str {
        match self {
            DecisionRule::Iso14253_1 => {
                "ISO 14253-1 decision rule: a pass proves conformance (value + U within the \
                 limit), a fail proves non-conformance (value - U beyond it), anything between \
                 is inconclusive; U is the expanded uncertainty (k = 2)"
            }
            DecisionRule::Simple => {
                "simple acceptance (ILAC-G8): the value alone against the limit; U is reported, \
                 not used"
            }
        }
    }

    /// The verdict of a magnitude `value` (its sign ignored) measured with expanded uncertainty
    /// `u` against `limit`; `NotJudged` when the value is not finite.
    pub fn decide(self, value: f64, u: f64, limit: f64) -> Verdict {
        let v = value.abs();
        if !v.is_finite() {
            return Verdict::NotJudged;
        }
        // An unknown uncertainty proves nothing either way.
        let u = if u.is_finite() {
            u.max(0.0)
        } else {
            f64::INFINITY
        };
        match self {
            DecisionRule::Simple if v <= limit => Verdict::Pass,
            DecisionRule::Simple => Verdict::Fail,
            DecisionRule::Iso14253_1 if v + u <= limit => Verdict::Pass,
            DecisionRule::Iso14253_1 if v - u > limit => Verdict::Fail,
            DecisionRule::Iso14253_1 => Verdict::Inconclusive,
        }
    }
}

/// A decision rule that is not one of `iso14253-1`, `simple`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("decision rule {0:?}: give iso14253-1 (guarded, the default) or simple")]
pub struct UnknownDecisionRule(pub String);

impl FromStr for DecisionRule {
    type Err = UnknownDecisionRule;
    fn from_str(s: &str) -> Result<Self, UnknownDecisionRule> {
        match s
            .trim()
            .to_ascii_lowercase()
            .replace(['_', ' '], "-")
            .as_str()
        {
            "iso14253-1" | "iso-14253-1" => Ok(DecisionRule::Iso14253_1),
            "simple" => Ok(DecisionRule::Simple),
            _ => Err(UnknownDecisionRule(s.to_string())),
        }
    }
}

impl fmt::Display for DecisionRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What a limit bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LimitKind {
    /// |width deviation| of a layer band, metres.
    Width,
    /// |top of the print − printed height|, metres.
    TopHeight,
    /// |shift| of a layer band in the plan, metres.
    Position,
    /// |peak deviation| of an area of the surface, metres.
    Surface,
    /// Area of missing material, m².
    MissingArea,
    /// |change of a layer band's width| since the first scan layer that saw it, metres
    /// (creep, sag: printed concrete deforms under the layers above).
    Creep,
}

impl LimitKind {
    /// Every kind, in report order.
    pub const ALL: [LimitKind; 6] = [
        LimitKind::Width,
        LimitKind::TopHeight,
        LimitKind::Position,
        LimitKind::Surface,
        LimitKind::MissingArea,
        LimitKind::Creep,
    ];

    /// The name in agent.toml's `[tolerances]` and in `--limit`.
    pub fn as_str(self) -> &'static str {
        match self {
            LimitKind::Width => "width",
            LimitKind::TopHeight => "top_height",
            LimitKind::Position => "position",
            LimitKind::Surface => "surface",
            LimitKind::MissingArea => "missing_area",
            LimitKind::Creep => "creep",
        }
    }

    /// Whether the limit is an area (m²) rather than a length (m).
    pub fn is_area(self) -> bool {
        self == LimitKind::MissingArea
    }
}

/// A limit that cannot be used: what was given and what is wrong with it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LimitError {
    /// Not one of [`LimitKind::ALL`].
    #[error("unknown kind {0:?}: use one of {kinds}", kinds = LimitKind::ALL.map(LimitKind::as_str).join(", "))]
    UnknownKind(String),
    /// Not `KIND=VALUE[@FIRST-LAST]`.
    #[error("{0:?}: expected KIND=VALUE or KIND=VALUE@FIRST-LAST")]
    Syntax(String),
    /// A layer that is not a number.
    #[error("layer {0:?} is not a layer number (0 is the first layer)")]
    NotALayer(String),
    /// A range whose first layer is above its last.
    #[error("layers {first}-{last}: the first is above the last")]
    LayersReversed {
        /// The first layer given.
        first: u32,
        /// The last layer given.
        last: u32,
    },
    /// An amount that is not a number in a known unit.
    #[error("{given:?} is not {}", if *area { "an area (m², or with cm2)" } else { "a length (metres, or with mm)" })]
    NotAnAmount {
        /// The amount given.
        given: String,
        /// Whether an area was expected.
        area: bool,
    },
    /// An amount of zero or less, or not finite.
    #[error("{0:?} must be positive")]
    NotPositive(String),
    /// A `KIND=VALUE@LAYERS` limit with a bad part.
    #[error("{given:?}: {source}")]
    InLimit {
        /// The limit as given.
        given: String,
        /// What is wrong in it.
        #[source]
        source: Box<LimitError>,
    },
    /// A job's limit of a kind that is zero or less, or not finite.
    #[error("the {} limit must be positive, not {value}", kind.as_str())]
    KindNotPositive {
        /// The kind.
        kind: LimitKind,
        /// Its limit.
        value: f64,
    },
    /// A warn fraction outside (0, 1].
    #[error("warn_fraction must be in (0, 1], not {0}")]
    WarnFraction(f64),
}

impl FromStr for LimitKind {
    type Err = LimitError;
    fn from_str(s: &str) -> Result<Self, LimitError> {
        let s = s.trim().replace('-', "_");
        LimitKind::ALL
            .into_iter()
            .find(|k| k.as_str() == s)
            .ok_or(LimitError::UnknownKind(s))
    }
}

/// One kind's limit over the layer bands `first..=last`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LayerLimit {
    /// The kind limited.
    pub kind: LimitKind,
    /// The limit, metres (m² for missing area).
    pub value: f64,
    /// The first layer band, from 0.
    pub first: u32,
    /// The last layer band, inclusive.
    pub last: u32,
}

/// `KIND=VALUE` or `KIND=VALUE@A-B` (layers A to B, or `@A` for one layer). Lengths in metres or
/// with `mm`/`cm`/`m`; the missing area in m² or with `cm2`/`m2`.
impl FromStr for LayerLimit {
    type Err = LimitError;
    fn from_str(s: &str) -> Result<Self, LimitError> {
        let (kind, rest) = s
            .split_once('=')
            .ok_or_else(|| LimitError::Syntax(s.to_string()))?;
        let kind: LimitKind = kind.parse()?;
        let (value, layers) = match rest.split_once('@') {
            Some((v, l)) => (v, Some(l)),
            None => (rest, None),
        };
        let in_limit = |e| LimitError::InLimit {
            given: s.to_string(),
            source: Box::new(e),
        };
        let value = parse_amount(value.trim(), kind.is_area()).map_err(in_limit)?;
        let (first, last) = match layers {
            None => (0, u32::MAX),
            Some(l) => parse_layers(l).map_err(in_limit)?,
        };
        Ok(LayerLimit {
            kind,
            value,
            first,
            last,
        })
    }
}

fn parse_layers(l: &str) -> Result<(u32, u32), LimitError> {
    let number = |t: &str| {
        t.trim()
            .parse::<u32>()
            .map_err(|_| LimitError::NotALayer(t.to_string()))
    };
    let (a, b) = match l.split_once('-') {
        Some((a, b)) => (number(a)?, number(b)?),
        None => (number(l)?, number(l)?),
    };
    if a > b {
        return Err(LimitError::LayersReversed { first: a, last: b });
    }
    Ok((a, b))
}

/// A positive amount with an optional unit.
fn parse_amount(v: &str, area: bool) -> Result<f64, LimitError> {
    let units: &[(&str, f64)] = if area {
        &[
            ("cm2", 1e-4),
            ("cm²", 1e-4),
            ("mm2", 1e-6),
            ("mm²", 1e-6),
            ("m2", 1.0),
            ("m²", 1.0),
        ]
    } else {
        &[("mm", 1e-3), ("cm", 1e-2), ("m", 1.0)]
    };
    let (number, scale) = units
        .iter()
        .find_map(|(u, s)| v.strip_suffix(u).map(|n| (n, *s)))
        .unwrap_or((v, 1.0));
    let x: f64 = number.trim().parse().map_err(|_| LimitError::NotAnAmount {
        given: v.to_string(),
        area,
    })?;
    let x = x * scale;
    if x.is_finite() && x > 0.0 {
        Ok(x)
    } else {
        Err(LimitError::NotPositive(v.to_string()))
    }
}

impl From<Verdict> for asbuilt_protocol::SurveyVerdict {
    fn from(v: Verdict) -> Self {
        use asbuilt_protocol::SurveyVerdict as S;
        match v {
            Verdict::NotJudged => S::NotJudged,
            Verdict::Pass => S::Pass,
            Verdict::Warn => S::Warn,
            Verdict::Inconclusive => S::Inconclusive,
            Verdict::Fail => S::Fail,
        }
    }
}

/// The coverage factor of every expanded uncertainty U reported (k = 2: about 95 % for a
/// normal distribution).
pub const COVERAGE_FACTOR: f64 = 2.0;

/// The limits of a job.
#[derive(Debug, Clone, PartialEq)]
pub struct Limits {
    /// |width deviation| of a layer band, metres.
    pub width: f64,
    /// |top of the print − printed height|, metres.
    pub top_height: f64,
    /// |shift| of a layer band in the plan, metres.
    pub position: f64,
    /// |peak deviation| of an area of the surface, metres.
    pub surface: f64,
    /// Area of missing material, m².
    pub missing_area_m2: f64,
    /// |change of a layer band's width| since the first scan layer that saw it, metres.
    pub creep: f64,
    /// A value beyond this fraction of its limit warns.
    pub warn_fraction: f64,
    /// Per range of layers, in the order given: later ranges win.
    pub ranges: Vec<LayerLimit>,
    /// How a measured value and its U are held to a limit.
    pub rule: DecisionRule,
}

/// Missing areas larger than this fail unless the crew says otherwise, m² (20 cm², a hand's
/// width of wall).
pub const DEFAULT_MISSING_AREA_M2: f64 = 0.002;
/// Values beyond this fraction of their limit warn unless the crew says otherwise.
pub const DEFAULT_WARN_FRACTION: f64 = 0.75;

impl Limits {
    /// Every length limit at the job's tolerance.
    pub fn from_tolerance(tolerance: f64) -> Self {
        Self {
            width: tolerance,
            top_height: tolerance,
            position: tolerance,
            surface: tolerance,
            missing_area_m2: DEFAULT_MISSING_AREA_M2,
            creep: tolerance,
            warn_fraction: DEFAULT_WARN_FRACTION,
            ranges: Vec::new(),
            rule: DecisionRule::default(),
        }
    }

    /// Sets a kind's limit for the whole part, or adds a range.
    pub fn set(&mut self, l: LayerLimit) {
        if l.first == 0 && l.last == u32::MAX {
            *self.whole_part_mut(l.kind) = l.value;
        } else {
            self.ranges.push(l);
        }
    }

    fn whole_part_mut(&mut self, kind: LimitKind) -> &mut f64 {
        match kind {
            LimitKind::Width => &mut self.width,
            LimitKind::TopHeight => &mut self.top_height,
            LimitKind::Position => &mut self.position,
            LimitKind::Surface => &mut self.surface,
            LimitKind::MissingArea => &mut self.missing_area_m2,
            LimitKind::Creep => &mut self.creep,
        }
    }

    /// The limit for the whole part.
    pub fn whole_part(&self, kind: LimitKind) -> f64 {
        match kind {
            LimitKind::Width => self.width,
            LimitKind::TopHeight => self.top_height,
            LimitKind::Position => self.position,
            LimitKind::Surface => self.surface,
            LimitKind::MissingArea => self.missing_area_m2,
            LimitKind::Creep => self.creep,
        }
    }

    /// The limit of `kind` at one layer band.
    pub fn at_layer(&self, kind: LimitKind, layer: u32) -> f64 {
        self.ranges
            .iter()
            .rev()
            .find(|r| r.kind == kind && (r.first..=r.last).contains(&layer))
            .map_or_else(|| self.whole_part(kind), |r| r.value)
    }

    /// The strictest limit of `kind` over the layer bands `layers` (inclusive); the whole
    /// part's when they are unknown.
    pub fn over(&self, kind: LimitKind, layers: Option<(u32, u32)>) -> f64 {
        let Some((a, b)) = layers else {
            return self.whole_part(kind);
        };
        let mut limit = self.at_layer(kind, a);
        // Only where a range begins or ends inside a..=b can the limit change.
        for r in self.ranges.iter().filter(|r| r.kind == kind) {
            for l in [r.first, r.last] {
                if (a..=b).contains(&l) {
                    limit = limit.min(self.at_layer(kind, l));
                }
            }
        }
        limit
    }

    /// The verdict of `value` (a magnitude; its sign is ignored), measured with expanded
    /// uncertainty `u`, against `limit` by the limits' [`DecisionRule`]; a pass beyond the warn
    /// fraction of the limit warns. A missing area is never a pass: material is missing.
    pub fn judge_value(&self, kind: LimitKind, value: f64, u: f64, limit: f64) -> Verdict {
        let v = value.abs();
        match self.rule.decide(v, u, limit) {
            Verdict::Pass if kind == LimitKind::MissingArea || v > self.warn_fraction * limit => {
                Verdict::Warn
            }
            verdict => verdict,
        }
    }

    /// The verdict of `value` measured with `u` over `layers`, with the limit it was held to.
    pub fn judge(
        &self,
        kind: LimitKind,
        (value, u): (f64, f64),
        layers: Option<(u32, u32)>,
    ) -> (Verdict, f64) {
        let limit = self.over(kind, layers);
        (self.judge_value(kind, value, u, limit), limit)
    }

    /// Problems that make the limits meaningless.
    pub fn check(&self) -> Result<(), LimitError> {
        for kind in LimitKind::ALL {
            let v = self.whole_part(kind);
            if !(v.is_finite() && v > 0.0) {
                return Err(LimitError::KindNotPositive { kind, value: v });
            }
        }
        if !(self.warn_fraction > 0.0 && self.warn_fraction <= 1.0) {
            return Err(LimitError::WarnFraction(self.warn_fraction));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limits_parse_with_units_and_layer_ranges() {
        let l: LayerLimit = "width=12mm@2-4".parse().unwrap();
        assert_eq!(l.kind, LimitKind::Width);
        assert!((l.value - 0.012).abs() < 1e-15);
        assert_eq!((l.first, l.last), (2, 4));
        let l: LayerLimit = "missing-area=30cm2".parse().unwrap();
        assert_eq!(l.kind, LimitKind::MissingArea);
        assert!((l.value - 0.003).abs() < 1e-15);
        assert_eq!((l.first, l.last), (0, u32::MAX));
        let l: LayerLimit = "top_height=0.004@7".parse().unwrap();
        assert_eq!((l.first, l.last, l.value), (7, 7, 0.004));
        for bad in [
            "width",
            "depth=5mm",
            "width=-1mm",
            "width=5mm@4-2",
            "width=5 parsecs",
            "width=NaN",
        ] {
            assert!(bad.parse::<LayerLimit>().is_err(), "{bad}");
        }
        let e = "depth=5mm".parse::<LayerLimit>().unwrap_err();
        assert!(e.to_string().contains("width, top_height"), "{e}");
    }

    #[test]
    fn later_ranges_win_and_a_span_is_held_to_its_strictest_layer() {
        let mut l = Limits::from_tolerance(0.005);
        l.set("width=12mm@2-4".parse().unwrap());
        l.set("width=3mm@4-6".parse().unwrap());
        assert_eq!(l.at_layer(LimitKind::Width, 1), 0.005);
        assert_eq!(l.at_layer(LimitKind::Width, 3), 0.012);
        assert_eq!(l.at_layer(LimitKind::Width, 4), 0.003);
        assert_eq!(l.at_layer(LimitKind::Position, 3), 0.005);
        assert_eq!(l.over(LimitKind::Width, Some((2, 3))), 0.012);
        assert_eq!(l.over(LimitKind::Width, Some((0, 9))), 0.003);
        assert_eq!(l.over(LimitKind::Width, Some((1, 2))), 0.005);
        assert_eq!(l.over(LimitKind::Width, None), 0.005);
        l.set("width=6mm".parse().unwrap());
        assert_eq!(l.at_layer(LimitKind::Width, 1), 0.006);
    }

    #[test]
    fn verdicts_warn_beyond_the_fraction_and_fail_beyond_the_limit() {
        let mut l = Limits::from_tolerance(0.004);
        let w = LimitKind::Width;
        // ISO 14253-1 (the default): U = 0.5 mm moves the pass and fail zones in.
        assert_eq!(l.judge_value(w, 0.0029, 0.0005, 0.004), Verdict::Pass);
        assert_eq!(l.judge_value(w, 0.0031, 0.0005, 0.004), Verdict::Warn);
        assert_eq!(
            l.judge_value(w, 0.0039, 0.0005, 0.004),
            Verdict::Inconclusive
        );
        assert_eq!(
            l.judge_value(w, -0.0041, 0.0005, 0.004),
            Verdict::Inconclusive
        );
        assert_eq!(l.judge_value(w, -0.0046, 0.0005, 0.004), Verdict::Fail);
        assert_eq!(l.judge_value(w, f64::NAN, 0.0, 0.004), Verdict::NotJudged);
        // An unknown U proves nothing either way.
        assert_eq!(
            l.judge_value(w, 0.001, f64::NAN, 0.004),
            Verdict::Inconclusive
        );
        let m = LimitKind::MissingArea;
        assert_eq!(l.judge_value(m, 0.0001, 0.0001, 0.002), Verdict::Warn);
        assert_eq!(
            l.judge_value(m, 0.0021, 0.0002, 0.002),
            Verdict::Inconclusive
        );
        assert_eq!(l.judge_value(m, 0.0025, 0.0002, 0.002), Verdict::Fail);
        // The simple rule: the value alone.
        l.rule = DecisionRule::Simple;
        assert_eq!(l.judge_value(w, 0.0029, 0.01, 0.004), Verdict::Pass);
        assert_eq!(l.judge_value(w, -0.0031, 0.01, 0.004), Verdict::Warn);
        assert_eq!(l.judge_value(w, 0.004, 0.01, 0.004), Verdict::Warn);
        assert_eq!(l.judge_value(w, -0.0041, 0.0, 0.004), Verdict::Fail);
        assert_eq!(l.judge_value(m, 0.0001, 0.0, 0.002), Verdict::Warn);
        assert_eq!(l.judge_value(m, 0.0021, 0.0, 0.002), Verdict::Fail);
        assert!(Verdict::Fail > Verdict::Warn && Verdict::Warn > Verdict::Pass);
        assert!(Verdict::Fail > Verdict::Inconclusive && Verdict::Inconclusive > Verdict::Warn);
        assert!(Verdict::NotJudged < Verdict::Pass);
        assert!(l.check().is_ok());
        let mut bad = l.clone();
        bad.warn_fraction = 1.5;
        assert!(bad.check().is_err());
    }

    #[test]
    fn the_decision_rules_at_and_around_the_limit() {
        let iso = DecisionRule::Iso14253_1;
        // 2.9 mm and 3.1 mm against 3 mm, measured with U = 1 mm: neither is proven.
        assert_eq!(iso.decide(0.0029, 0.001, 0.003), Verdict::Inconclusive);
        assert_eq!(iso.decide(-0.0031, 0.001, 0.003), Verdict::Inconclusive);
        assert_eq!(iso.decide(0.0019, 0.001, 0.003), Verdict::Pass);
        assert_eq!(iso.decide(0.0041, 0.001, 0.003), Verdict::Fail);
        assert_eq!(iso.decide(0.001, f64::NAN, 0.003), Verdict::Inconclusive);
        assert_eq!(iso.decide(f64::NAN, 0.0, 0.003), Verdict::NotJudged);
        let simple = DecisionRule::Simple;
        assert_eq!(simple.decide(0.0029, 0.001, 0.003), Verdict::Pass);
        assert_eq!(simple.decide(0.0031, 0.001, 0.003), Verdict::Fail);
        assert_eq!("ISO14253-1".parse::<DecisionRule>(), Ok(iso));
        assert_eq!("simple".parse::<DecisionRule>(), Ok(simple));
        let e = "guarded".parse::<DecisionRule>().unwrap_err().to_string();
        assert!(e.contains("iso14253-1") && e.contains("guarded"), "{e}");
        assert_eq!(DecisionRule::default(), iso);
    }
}
