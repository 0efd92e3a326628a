//! The limits of the standards a site judges by: DIN 18202:2019-07 Tables 1 (dimensions), 2
//! (angles, as a gap) and 3 (flatness, a gap under a straightedge at the distance between its
//! supports), and ACI 117-10 (formed surfaces, 5 ft straightedge).
//!
//! DIN 18202's values are the same in its 2013-04 and 2019-07 editions (the 2019 revision kept
//! the tables and reworked how measuring points are chosen).

/// The edition the tables are taken from, for reports.
pub const DIN_18202_EDITION: &str = "DIN 18202:2019-07";

/// A flatness standard and its row or class.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FlatnessStandard {
    /// DIN 18202 Table 3: rows 1 to 4 are floors and the tops of slabs, 5 unfinished walls and
    /// soffits, 6 finished walls, 7 row 6 with higher requirements.
    Din18202 {
        /// The row, 1 to 7.
        row: u8,
    },
    /// ACI 117, formed surfaces on a 5 ft straightedge, classes A to D.
    Aci117 {
        /// The class, `A` to `D`.
        class: char,
    },
}

/// DIN 18202 Table 3's distances between the measuring points (the straightedge's supports),
/// metres.
pub const DIN_SPANS: [f64; 5] = [0.1, 1.0, 4.0, 10.0, 15.0];
/// DIN 18202:2019-07 Table 3, rows 1 to 7: the largest gap (Stichmaß) at those distances,
/// millimetres.
pub const DIN_ROWS: [(u8, [f64; 5]); 7] = [
    // Unfinished tops of slabs, blinding and sub-floors.
    (1, [10.0, 15.0, 20.0, 25.0, 30.0]),
    // Row 1 with higher requirements (e.g. to take floating screeds, industrial floors).
    (2, [5.0, 8.0, 12.0, 15.0, 20.0]),
    // Finished floors (screeds as wearing layers, floors to take coverings).
    (3, [2.0, 4.0, 10.0, 12.0, 15.0]),
    // Row 3 with higher requirements.
    (4, [1.0, 3.0, 9.0, 12.0, 15.0]),
    // Unfinished walls and soffits of structural slabs.
    (5, [5.0, 10.0, 15.0, 25.0, 30.0]),
    // Finished walls and soffits (e.g. plastered, clad, to take coverings).
    (6, [3.0, 5.0, 10.0, 20.0, 25.0]),
    // Row 6 with higher requirements.
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
/// ACI 117's abrupt irregularities (offsets, such as a layer's step) per class: 1/8, 1/4, 1/4
/// and 1 inch, in metres (class C allows a gradual 1/2 inch but an abrupt 1/4).
const ACI_ABRUPT: [(char, f64); 4] = [
    ('A', 0.003175),
    ('B', 0.00635),
    ('C', 0.00635),
    ('D', 0.0254),
];
/// The distance within which ACI 117 reads an offset as abrupt: 1 inch.
pub const ACI_ABRUPT_WITHIN: f64 = 0.0254;

/// The values `--flatness` accepts, for an error message.
pub const ACCEPTED: &str = "din18202:1 to din18202:7 (5-7 walls, 1-4 floors), aci117:A, \
                            aci117:B, aci117:C, aci117:D";

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
            FlatnessStandard::Din18202 { row } => {
                write!(f, "{DIN_18202_EDITION} Table 3 row {row}")
            }
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

    /// The longest distance between a straightedge's supports it judges, metres: DIN 18202 has
    /// no upper bound (beyond 15 m its last limit holds); ACI 117 lays a 5 ft straightedge.
    pub fn max_support(&self) -> f64 {
        match self {
            FlatnessStandard::Din18202 { .. } => f64::INFINITY,
            FlatnessStandard::Aci117 { .. } => ACI_SPAN,
        }
    }

    /// The spans its table lists, metres.
    pub fn spans(&self) -> Vec<f64> {
        match self {
            FlatnessStandard::Din18202 { .. } => DIN_SPANS.to_vec(),
            FlatnessStandard::Aci117 { .. } => vec![ACI_SPAN],
        }
    }

    /// The largest gap allowed with the straightedge's supports `span` apart, metres: DIN 18202
    /// interpolates linearly between its distances, holds the 0.1 m limit below 0.1 m and the
    /// 15 m limit beyond 15 m.
    pub fn limit(&self, span: f64) -> f64 {
        match *self {
            FlatnessStandard::Din18202 { row } => {
                let limits = DIN_ROWS
                    .iter()
                    .find(|r| r.0 == row)
                    .map_or(DIN_ROWS[5].1, |r| r.1);
                interpolate(&DIN_SPANS, &limits, span) * 1e-3
            }
            FlatnessStandard::Aci117 { class } => ACI_CLASSES
                .iter()
                .find(|c| c.0 == class)
                .map_or(ACI_CLASSES[1].1, |c| c.1),
        }
    }
}

impl FlatnessStandard {
    /// The largest abrupt offset allowed (within [`ACI_ABRUPT_WITHIN`]), metres; `None` where
    /// the standard has no such limit (DIN 18202 judges steps by its straightedge alone).
    pub fn abrupt_limit(&self) -> Option<f64> {
        match *self {
            FlatnessStandard::Din18202 { .. } => None,
            FlatnessStandard::Aci117 { class } => {
                ACI_ABRUPT.iter().find(|c| c.0 == class).map(|c| c.1)
            }
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
        // A dent's rims 0.3 m apart: 3 + 2 · 0.2 / 0.9 mm.
        assert!((din6.limit(0.3) - 0.0034444).abs() < 1e-6);
        let aci: FlatnessStandard = "ACI117:b".parse().unwrap();
        assert!((aci.limit(1.524) - 0.25 * 0.0254).abs() < 1e-12);
        assert_eq!(aci.spans(), vec![1.524]);
        assert_eq!(aci.max_support(), 1.524);
        // Abrupt offsets: 1/8, 1/4, 1/4, 1 inch; DIN 18202 has none.
        let abrupt = |c: &str| {
            format!("aci117:{c}")
                .parse::<FlatnessStandard>()
                .unwrap()
                .abrupt_limit()
                .unwrap()
        };
        for (c, inches) in [("A", 0.125), ("B", 0.25), ("C", 0.25), ("D", 1.0)] {
            assert!((abrupt(c) - inches * 0.0254).abs() < 1e-12, "{c}");
        }
        assert_eq!(
            "din18202:6"
                .parse::<FlatnessStandard>()
                .unwrap()
                .abrupt_limit(),
            None
        );
        for bad in [
            "din18202:8",
            "din18202:0",
            "din18202",
            "aci117:E",
            "aci117:AB",
            "iso:1",
        ] {
            let e = bad.parse::<FlatnessStandard>().unwrap_err().to_string();
            assert!(e.contains("din18202:1") && e.contains(bad), "{e}");
        }
        assert!(din6.to_string().contains("DIN 18202:2019-07 Table 3 row 6"));
    }

    /// DIN 18202:2019-07 Table 3 as printed, every row at every distance: rows 1-4 floors,
    /// 5-7 walls.
    #[test]
    fn table_3_row_by_row() {
        // Read down the printed table's columns (an oracle apart from `DIN_ROWS`, which is
        // held by rows): the limit at each distance, rows 1 to 7, millimetres.
        let printed: [(f64, [f64; 7]); 5] = [
            (0.1, [10.0, 5.0, 2.0, 1.0, 5.0, 3.0, 2.0]),
            (1.0, [15.0, 8.0, 4.0, 3.0, 10.0, 5.0, 3.0]),
            (4.0, [20.0, 12.0, 10.0, 9.0, 15.0, 10.0, 8.0]),
            (10.0, [25.0, 15.0, 12.0, 12.0, 25.0, 20.0, 15.0]),
            (15.0, [30.0, 20.0, 15.0, 15.0, 30.0, 25.0, 20.0]),
        ];
        for row in 1..=7usize {
            let s: FlatnessStandard = format!("din18202:{row}").parse().unwrap();
            for (d, limits) in &printed {
                let l = limits[row - 1];
                assert!((s.limit(*d) * 1e3 - l).abs() < 1e-9, "row {row} at {d} m");
            }
            // Halfway between two distances, halfway between their limits.
            let mid = s.limit(0.55) * 1e3;
            let half = 0.5 * (printed[0].1[row - 1] + printed[1].1[row - 1]);
            assert!((mid - half).abs() < 1e-9, "row {row}");
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
        write!(f, "{DIN_18202_EDITION} Tables 1 and 2")
    }
}
