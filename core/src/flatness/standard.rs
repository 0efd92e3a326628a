//! The flatness limits of the standards a site judges walls by, as a gap under a straightedge
//! at a span.

/// A flatness standard and its row or class.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FlatnessStandard {
    /// DIN 18202 Table 3, rows 5 (unfinished walls), 6 (finished walls) and 7 (row 6 with
    /// higher requirements).
    Din18202 {
        /// The row, 5 to 7.
        row: u8,
    },
    /// ACI 117, formed surfaces on a 5 ft straightedge, classes A to D.
    Aci117 {
        /// The class, `A` to `D`.
        class: char,
    },
}

/// DIN 18202 Table 3's spans (the distance between the measuring points), metres.
const DIN_SPANS: [f64; 5] = [0.1, 1.0, 4.0, 10.0, 15.0];
/// Its limits for rows 5, 6 and 7 at those spans, millimetres.
const DIN_ROWS: [(u8, [f64; 5]); 3] = [
    (5, [5.0, 10.0, 15.0, 25.0, 30.0]),
    (6, [3.0, 5.0, 10.0, 20.0, 25.0]),
    (7, [2.0, 3.0, 8.0, 15.0, 20.0]),
];
/// ACI 117's straightedge: 5 ft.
const ACI_SPAN: f64 = 1.524;
/// Its limits per class: 1/8, 1/4, 1/2 and 1 inch, in metres.
const ACI_CLASSES: [(char, f64); 4] = [
    ('A', 0.003175),
    ('B', 0.00635),
    ('C', 0.0127),
    ('D', 0.0254),
];

/// The values `--flatness` accepts, for an error message.
pub const ACCEPTED: &str = "din18202:5, din18202:6, din18202:7, aci117:A, aci117:B, aci117:C, \
                            aci117:D";

/// A standard that is not one of [`ACCEPTED`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("flatness {given:?}: give one of {ACCEPTED}")]
pub struct UnknownStandard {
    /// What was given.
    pub given: String,
}

impl std::str::FromStr for FlatnessStandard {
    type Err = UnknownStandard;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || UnknownStandard {
            given: s.to_string(),
        };
        let (name, which) = s.split_once(':').ok_or_else(bad)?;
        match name.to_ascii_lowercase().as_str() {
            "din18202" => {
                let row: u8 = which.parse().map_err(|_| bad())?;
                DIN_ROWS
                    .iter()
                    .any(|r| r.0 == row)
                    .then_some(FlatnessStandard::Din18202 { row })
                    .ok_or_else(bad)
            }
            "aci117" => {
                let class = which
                    .chars()
                    .next()
                    .filter(|_| which.len() == 1)
                    .ok_or_else(bad)?
                    .to_ascii_uppercase();
                ACI_CLASSES
                    .iter()
                    .any(|c| c.0 == class)
                    .then_some(FlatnessStandard::Aci117 { class })
                    .ok_or_else(bad)
            }
            _ => Err(bad()),
        }
    }
}

impl std::fmt::Display for FlatnessStandard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FlatnessStandard::Din18202 { row } => write!(f, "DIN 18202 Table 3 row {row}"),
            FlatnessStandard::Aci117 { class } => write!(f, "ACI 117 class {class}"),
        }
    }
}

impl FlatnessStandard {
    /// As `--flatness` takes it: `din18202:6`, `aci117:B`.
    pub fn key(&self) -> String {
        match self {
            FlatnessStandard::Din18202 { row } => format!("din18202:{row}"),
            FlatnessStandard::Aci117 { class } => format!("aci117:{class}"),
        }
    }

    /// The spans it is judged at, metres.
    pub fn spans(&self) -> Vec<f64> {
        match self {
            FlatnessStandard::Din18202 { .. } => DIN_SPANS.to_vec(),
            FlatnessStandard::Aci117 { .. } => vec![ACI_SPAN],
        }
    }

    /// The largest gap allowed at `span`, metres: DIN 18202 interpolates linearly between its
    /// spans (and holds its first and last value outside them).
    pub fn limit(&self, span: f64) -> f64 {
        match *self {
            FlatnessStandard::Din18202 { row } => {
                let limits = DIN_ROWS
                    .iter()
                    .find(|r| r.0 == row)
                    .map_or(DIN_ROWS[1].1, |r| r.1);
                interpolate(&DIN_SPANS, &limits, span) * 1e-3
            }
            FlatnessStandard::Aci117 { class } => ACI_CLASSES
                .iter()
                .find(|c| c.0 == class)
                .map_or(ACI_CLASSES[1].1, |c| c.1),
        }
    }
}

fn interpolate(xs: &[f64], ys: &[f64], x: f64) -> f64 {
    if x <= xs[0] {
        return ys[0];
    }
    for k in 1..xs.len() {
        if x <= xs[k] {
            let t = (x - xs[k - 1]) / (xs[k] - xs[k - 1]);
            return ys[k - 1] + t * (ys[k] - ys[k - 1]);
        }
    }
    ys[ys.len() - 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tables_rows_and_their_interpolation() {
        let din6: FlatnessStandard = "din18202:6".parse().unwrap();
        assert_eq!(din6, FlatnessStandard::Din18202 { row: 6 });
        assert!((din6.limit(0.1) - 0.003).abs() < 1e-12);
        assert!((din6.limit(1.0) - 0.005).abs() < 1e-12);
        assert!((din6.limit(2.5) - 0.0075).abs() < 1e-12);
        assert!((din6.limit(0.05) - 0.003).abs() < 1e-12);
        assert!((din6.limit(20.0) - 0.025).abs() < 1e-12);
        let aci: FlatnessStandard = "ACI117:b".parse().unwrap();
        assert!((aci.limit(1.524) - 0.25 * 0.0254).abs() < 1e-12);
        assert_eq!(aci.spans(), vec![1.524]);
        for bad in ["din18202:4", "din18202", "aci117:E", "aci117:AB", "iso:1"] {
            let e = bad.parse::<FlatnessStandard>().unwrap_err().to_string();
            assert!(e.contains("din18202:6") && e.contains(bad), "{e}");
        }
    }
}

/// The standard dimensions and plumb are judged by; DIN 18202 (Tables 1 and 2) is the one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DimensionsStandard {
    /// DIN 18202 Table 1 (lengths, widths, heights) and Table 2 (angles, as a gap).
    Din18202,
}

/// A dimensions standard that is not `din18202`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("dimensions {given:?}: give din18202 (Tables 1 and 2)")]
pub struct UnknownDimensionsStandard {
    /// What was given.
    pub given: String,
}

impl std::str::FromStr for DimensionsStandard {
    type Err = UnknownDimensionsStandard;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.eq_ignore_ascii_case("din18202") {
            Ok(DimensionsStandard::Din18202)
        } else {
            Err(UnknownDimensionsStandard {
                given: s.to_string(),
            })
        }
    }
}

impl std::fmt::Display for DimensionsStandard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("DIN 18202 Tables 1 and 2")
    }
}
