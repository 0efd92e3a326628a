//! Flatness as a surveyor measures it: a virtual straightedge laid on every planar face the
//! scans saw, along the layers and across them, resting on two high points of the surface, the
//! gap under it judged by the standard's table at the distance between those points (DIN 18202
//! Table 3, ACI 117).
//!
//! Scan points matched to a face's triangles are gathered in cells in the face's plane (memory
//! grows with the face's area, never with the scan): 5 mm along the layers and 1 mm across them,
//! so that layer ribs of 10 mm pitch keep their depth. A straightedge lies in a lane 30 mm wide
//! (a straightedge's width), in bins 10 mm long along the layers and 1 mm across them; each bin
//! of the lane's profile is the mean of its points, without the cells far from the bin's median
//! cell and without bins that caught only the end of a scan line, so that no stray point holds
//! the straightedge up while a rib or a dent keeps its shape; across the layers a local
//! quadratic over ±3 bins takes most of the noise and little of a rib. A straightedge position
//! counts where at least 70 % of the 5 mm blocks between its supports were measured.
//!
//! Positions are chosen on one half of the points and their gaps measured on the other
//! ([`Half`]): the deepest gap over a face is then the surface's, not its noise's maximum. Every
//! gap carries its expanded uncertainty (k = 2, [`uncertainty`]).

mod abrupt;
mod chords;
mod dimensions;
mod faces;
mod standard;
pub(crate) mod straightedge;
mod uncertainty;

pub use abrupt::AbruptStep;
pub use chords::{Chord, each_chord};
pub use dimensions::{
    Dimension, DimensionKind, Plumb, TABLE_1, TABLE_1_SIZES, TABLE_2, TABLE_2_SIZES, table_1,
    table_2,
};
pub use faces::{Face, PlanarFaces};
pub use standard::{
    ACCEPTED, DIN_18202_EDITION, DIN_ROWS, DIN_SPANS, DimensionsStandard, FlatnessStandard,
    UnknownDimensionsStandard, UnknownStandard,
};

use asbuilt_protocol::{DeviationFlags, PointDeviation};
use nalgebra::Point3;

use crate::verdict::{DecisionRule, Verdict};
use straightedge::Located;

/// The cell along the layers (the face's `u`), metres.
pub const CELL_ALONG: f64 = 0.005;
/// The cell across the layers (the face's `v`), metres: a quarter of the finest layer pitch
/// printed (10 mm ribs at 2.5 mm point spacing keep their depth).
pub const CELL_ACROSS: f64 = 0.001;
/// Faces smaller than this are not judged, m².
pub const MIN_FACE_AREA: f64 = 0.01;
/// The width of a lane the straightedge lies in, metres.
pub const LANE: f64 = 0.03;
/// The blocks whose measured share decides whether a straightedge position counts, metres.
pub const BLOCK: f64 = 0.005;
/// The share of blocks between a straightedge's supports that must be measured.
pub const MIN_FILLED: f64 = 0.7;
/// Views steeper than this (between the face's normal and the ray from the scanner) are left
/// out: at grazing incidence a point's range noise and mixed returns land across the surface.
pub const MAX_INCIDENCE_DEG: f64 = 75.0;
/// A face's cells at most; a larger face takes larger cells.
const MAX_CELLS: usize = 2 << 20;
/// Stations a scan layer's cells tell apart; beyond, a cell counts as seen by several.
const MAX_STATIONS: usize = 250;
/// A cell's station tag: nothing seen yet.
const EMPTY: u8 = 255;
/// A cell's station tag: seen by more than one station.
pub(crate) const MIXED: u8 = 254;

/// Which way the straightedge lies on a face.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub enum Direction {
    /// Along the layers (horizontal on a wall).
    #[cfg_attr(feature = "serde", serde(rename = "along_layers"))]
    Along,
    /// Across the layers.
    #[cfg_attr(feature = "serde", serde(rename = "across_layers"))]
    Across,
}

impl std::fmt::Display for Direction {
    /// For people: "along layers", "across layers".
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.as_str().replace('_', " "))
    }
}

impl Direction {
    /// As report.json spells it.
    pub fn as_str(self) -> &'static str {
        match self {
            Direction::Along => "along_layers",
            Direction::Across => "across_layers",
        }
    }
}

/// A gap under the straightedge on one face, one way: the one that governs the face's verdict
/// (`span` `None`: any distance between the supports, judged at that distance), or the deepest
/// with its supports at most `span` apart (one of the table's distances).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlatnessGap {
    /// The face, an index into [`PlanarFaces::faces`].
    pub face: u32,
    /// Which way the straightedge lay.
    pub direction: Direction,
    /// `None` for the governing gap; else the table's distance its supports are within.
    pub span: Option<f64>,
    /// The gap, metres.
    pub gap: f64,
    /// The distance between the straightedge's two supports, metres.
    pub support_distance: f64,
    /// The standard's limit at that distance, metres.
    pub limit: f64,
    /// The gap's expanded uncertainty (k = 2), metres.
    pub uncertainty: f64,
    /// Where the gap is deepest, design frame.
    pub at: Point3<f64>,
    /// Where the straightedge rests, design frame.
    pub supports: [Point3<f64>; 2],
}

impl FlatnessGap {
    /// The verdict by `rule`.
    pub fn verdict(&self, rule: DecisionRule) -> Verdict {
        rule.decide(self.gap, self.uncertainty, self.limit)
    }
}

/// Why a face, one way, was not judged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize),
    serde(rename_all = "snake_case")
)]
pub enum NotJudgedReason {
    /// No scan point of the scan layer was matched to it (out of view, or seen only at grazing
    /// incidence).
    NotSeen,
    /// Points were seen, but no straightedge position had 70 % of its blocks measured.
    TooSparse,
}

impl NotJudgedReason {
    /// As report.json spells it.
    pub fn as_str(self) -> &'static str {
        match self {
            NotJudgedReason::NotSeen => "not_seen",
            NotJudgedReason::TooSparse => "too_sparse",
        }
    }

    /// For people.
    pub fn describe(self) -> &'static str {
        match self {
            NotJudgedReason::NotSeen => {
                "no scan point on it (out of view, or seen only beyond 75° incidence)"
            }
            NotJudgedReason::TooSparse => {
                "too few points: no straightedge position had 70 % of its length measured"
            }
        }
    }
}

/// A face, one way, that was not judged.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NotJudged {
    /// The face.
    pub face: u32,
    /// Which way.
    pub direction: Direction,
    /// Why.
    pub reason: NotJudgedReason,
}

/// A scan layer's faces judged by a flatness standard.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FlatnessJudgement {
    /// Per face and direction judged: the governing gap, then the deepest at each of the
    /// table's distances up to the face's size.
    pub gaps: Vec<FlatnessGap>,
    /// Per face and direction not judged, and why.
    pub not_judged: Vec<NotJudged>,
    /// Per face and direction judged, the largest abrupt offset, where the standard limits
    /// them (ACI 117).
    pub abrupt: Vec<AbruptStep>,
}

/// A station whose points the grid takes: which one, where it scanned from and how well its
/// pose is known.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StationView {
    /// Job and station.
    pub key: (u64, u32),
    /// The scanner's position, design frame, when known.
    pub origin: Option<Point3<f64>>,
    /// The pose's position σ per axis, metres (NaN or 0 when unknown).
    pub position_sigma: f64,
}

/// One cell: the sum, sum of squares and count of its points' heights off the plane, the sum
/// and count of those in the choosing half ([`Half`]), and which stations saw them: the first
/// and how many of its points, and the other (one more, or [`MIXED`] for several). One record per cell, so that adding a point touches one cache line.
#[derive(Debug, Clone, Copy)]
struct Cell {
    sum: f64,
    sq: f64,
    choose_sum: f64,
    count: u32,
    choose_count: u32,
    first_count: u32,
    first: u8,
    other: u8,
}

impl Cell {
    const EMPTY: Cell = Cell {
        sum: 0.0,
        sq: 0.0,
        choose_sum: 0.0,
        count: 0,
        choose_count: 0,
        first_count: 0,
        first: EMPTY,
        other: EMPTY,
    };

    /// The station that saw the cell, [`MIXED`] when several did, [`EMPTY`] before any.
    fn station(&self) -> u8 {
        if self.other == EMPTY {
            self.first
        } else {
            MIXED
        }
    }

    /// The stations behind the cell's mean with their shares of its points: the first, and
    /// the rest as the other (as [`MIXED`] when it stands for several).
    fn shares(&self) -> [(u8, f64); 2] {
        let n = self.count.max(1) as f64;
        let first = self.first_count as f64 / n;
        [(self.first, first), (self.other, 1.0 - first)]
    }
}

/// One face's cells, row by row along `u`.
#[derive(Debug, Clone)]
struct Cells {
    /// Cell size along `u` and along `v`.
    size: [f64; 2],
    nu: usize,
    nv: usize,
    cell: Vec<Cell>,
}

/// Which of a face's points a straightedge's profile is read from (dimensions and the noise
/// estimate take them all). The deepest gap over a face is a maximum
/// over thousands of straightedge positions, and read from the same points that chose it, it
/// takes their noise along (layer ribs 4 mm deep read 4.7-4.8 mm at 0.3 mm noise): the
/// position is chosen on one half of the points and the gap measured on the other, whose noise
/// the choice never saw (sample splitting, as in cross-validation). Each point falls in a half
/// by a hash of its place in its chunk, independent of where it lies and of its noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Half {
    /// The half the straightedge's positions are chosen on.
    Choose,
    /// The other half, which measures the chosen positions' gaps.
    Measure,
}

impl Half {
    /// The half a point falls in, from its sequence number (SplitMix64's finaliser).
    fn of(sequence: u64) -> bool {
        let mut z = sequence.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        (z ^ (z >> 31)) & 1 == 0
    }
}

impl Cells {
    /// Cell `k`'s sum and count of heights in `half`.
    fn sum_count(&self, k: usize, half: Half) -> (f64, u32) {
        match half {
            Half::Choose => (self.cell[k].choose_sum, self.cell[k].choose_count),
            Half::Measure => (
                self.cell[k].sum - self.cell[k].choose_sum,
                self.cell[k].count - self.cell[k].choose_count,
            ),
        }
    }

    /// Cell `k`'s mean height in `half`.
    fn mean_of(&self, k: usize, half: Half) -> Option<f64> {
        let (sum, n) = self.sum_count(k, half);
        (n > 0).then(|| sum / n as f64)
    }
}

/// Scan points gathered per planar face, judged by a standard on demand.
#[derive(Debug, Clone)]
pub struct FlatnessGrid {
    faces: PlanarFaces,
    cells: Vec<Cells>,
    /// The height the part stands on: where heights are measured from.
    bed: f64,
    /// The scan layer's stations, in the order they came, with their position σ.
    stations: Vec<((u64, u32), f64)>,
    /// Points offered through [`FlatnessGrid::add_point`], which picks their [`Half`].
    offered: u64,
}

impl FlatnessGrid {
    /// Empty cells over every planar face of `design` of [`MIN_FACE_AREA`] or more.
    pub fn new(design: &crate::Design) -> Self {
        let faces = PlanarFaces::of(design, MIN_FACE_AREA);
        let cells = faces
            .faces
            .iter()
            .map(|f| {
                let [su, sv] = f.size();
                let scale = ((su * sv) / (CELL_ALONG * CELL_ACROSS * MAX_CELLS as f64))
                    .sqrt()
                    .max(1.0);
                let size = [CELL_ALONG * scale, CELL_ACROSS * scale];
                let nu = (su / size[0]).ceil().max(1.0) as usize;
                let nv = (sv / size[1]).ceil().max(1.0) as usize;
                Cells {
                    size,
                    nu,
                    nv,
                    cell: vec![Cell::EMPTY; nu * nv],
                }
            })
            .collect();
        Self {
            faces,
            cells,
            bed: design.bounds().0.z,
            stations: Vec::new(),
            offered: 0,
        }
    }

    /// The faces.
    pub fn faces(&self) -> &[Face] {
        &self.faces.faces
    }

    /// Bytes the cells take.
    pub fn bytes(&self) -> usize {
        self.cells
            .iter()
            .map(|c| c.cell.len() * std::mem::size_of::<Cell>())
            .sum()
    }

    /// Forgets every point and station (a new scan layer).
    pub fn clear(&mut self) {
        for c in &mut self.cells {
            c.cell.fill(Cell::EMPTY);
        }
        self.stations.clear();
        self.offered = 0;
    }

    /// The tag the cells give `station`'s points, registering it on first sight.
    pub fn station(&mut self, station: &StationView) -> u8 {
        if let Some(k) = self.stations.iter().position(|s| s.0 == station.key) {
            return k as u8;
        }
        if self.stations.len() >= MAX_STATIONS {
            return MIXED;
        }
        self.stations.push((station.key, station.position_sigma));
        (self.stations.len() - 1) as u8
    }

    /// Adds a chunk's deviations of `station`: each matched point goes to its triangle's face,
    /// unless the face was seen at more than [`MAX_INCIDENCE_DEG`] from the station's origin.
    pub fn add(&mut self, devs: &[PointDeviation], station: &StationView) {
        let tag = self.station(station);
        let min_cos = MAX_INCIDENCE_DEG.to_radians().cos();
        for (i, d) in devs.iter().enumerate() {
            if d.flags.contains(DeviationFlags::REJECTED) || !d.distance.is_finite() {
                continue;
            }
            let Some(Some(f)) = self.faces.of_triangle.get(d.triangle as usize) else {
                continue;
            };
            let p = Point3::from(d.position);
            if let Some(o) = station.origin {
                let ray = o - p;
                let n = ray.norm();
                if n > 0.0 && ray.dot(&self.faces.faces[*f as usize].normal) < min_cos * n {
                    continue;
                }
            }
            // By its place in the chunk: the recording keeps a chunk's points in order, so a
            // report read back from it splits them as the live agent did.
            self.add_to(*f as usize, &p, tag, Half::of(i as u64));
        }
    }

    /// Adds a point to face `f`, seen by the station tagged `tag` ([`FlatnessGrid::station`]),
    /// its [`Half`] by how many points came this way before it.
    pub fn add_point(&mut self, f: usize, p: &Point3<f64>, tag: u8) {
        let choose = Half::of(self.offered);
        self.offered += 1;
        self.add_to(f, p, tag, choose);
    }

    /// Adds a point to face `f`, to the choosing half when `choose`.
    fn add_to(&mut self, f: usize, p: &Point3<f64>, tag: u8, choose: bool) {
        let face = &self.faces.faces[f];
        let c = &mut self.cells[f];
        let [u, v, w] = face.coordinates(p);
        let iu = ((u - face.extent[0][0]) / c.size[0]).floor();
        let iv = ((v - face.extent[1][0]) / c.size[1]).floor();
        if iu < 0.0 || iv < 0.0 || iu >= c.nu as f64 || iv >= c.nv as f64 {
            return;
        }
        let k = iv as usize * c.nu + iu as usize;
        let c = &mut c.cell[k];
        c.sum += w;
        c.sq += w * w;
        c.count += 1;
        if choose {
            c.choose_sum += w;
            c.choose_count += 1;
        }
        if c.first == EMPTY {
            c.first = tag;
        }
        if tag == c.first {
            c.first_count += 1;
        } else {
            c.other = match c.other {
                EMPTY => tag,
                t if t == tag => tag,
                _ => MIXED,
            };
        }
    }

    /// Every face judged by `standard`, in both directions: the gap that governs each, the
    /// deepest at each of the table's distances that fit the face, and what was not judged.
    pub fn judge(&self, standard: &FlatnessStandard) -> FlatnessJudgement {
        let mut out = FlatnessJudgement::default();
        for (f, face) in self.faces.faces.iter().enumerate() {
            let size = face.size();
            for (axis, direction) in [(0, Direction::Along), (1, Direction::Across)] {
                let setup = self.setup(f, axis);
                let found = self.straightedge((f, axis), &setup, standard);
                let Some((governing, by_span)) = found else {
                    let seen = self.cells[f].cell.iter().any(|c| c.count > 0);
                    out.not_judged.push(NotJudged {
                        face: f as u32,
                        direction,
                        reason: if seen {
                            NotJudgedReason::TooSparse
                        } else {
                            NotJudgedReason::NotSeen
                        },
                    });
                    continue;
                };
                let gap = |c: &Located, span: Option<f64>| {
                    let d = c.support_distance;
                    FlatnessGap {
                        face: f as u32,
                        direction,
                        span,
                        gap: c.gap,
                        support_distance: d,
                        limit: standard.limit(d),
                        uncertainty: self.gap_uncertainty((f, axis), &setup, c),
                        at: c.at,
                        supports: c.supports,
                    }
                };
                out.gaps.push(gap(&governing, None));
                if let Some(limit) = standard.abrupt_limit() {
                    out.abrupt.extend(self.abrupt((f, axis), &setup, limit));
                }
                for (span, c) in standard.spans().into_iter().zip(by_span) {
                    if let Some(c) = c.filter(|_| span <= size[axis] + 1e-9) {
                        out.gaps.push(gap(&c, Some(span)));
                    }
                }
            }
        }
        out
    }
}

#[cfg(test)]
pub(crate) mod tests;
