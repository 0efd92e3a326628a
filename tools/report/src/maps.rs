//! Deviation maps: each scan layer's part seen from its four sides and from above, coloured by
//! deviation on the scale the rerun view uses (core's `colour`), with the design's outline and
//! every finding drawn and labelled where it is.
//!
//! Two maps per side: the points' C2M, each point drawn on the side its design triangle faces,
//! and the design samples' M3C2 with coverage's missing material. Both are rasters of a fixed
//! size per design (a pixel keeps the mean of the nearest surface that falls in it; deeper
//! surfaces are hidden as in a drawing), so memory follows the design, never the scan. The
//! raster goes into the SVG as a PNG; the outline's scale, the axes and the call-outs are SVG.

use std::collections::BTreeMap;
use std::fmt::Write;

use asbuilt_core::Design;
use asbuilt_core::cells::floor_i64;
use asbuilt_core::colour::deviation_colour;
use asbuilt_core::findings::Judged;
use asbuilt_core::scan_layer::SampleState;
use asbuilt_core::verdict::Verdict;
use asbuilt_protocol::{DeviationFlags, PointDeviation};
use base64::Engine;
use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::Item;
use crate::markup::Margins;

/// Pixels along the design's longest side.
const LONGEST_SIDE_PX: f64 = 320.0;
/// Screen pixels per raster pixel.
const ZOOM: f64 = 2.0;
/// A surface within this many pixels of the nearest one in a pixel is the same surface.
const SLAB_PX: f64 = 2.0;
/// Room around the raster for axes and labels.
const MARGINS: Margins = Margins::new(56.0, 12.0, 12.0, 30.0);

/// Where a map looks from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Side {
    /// From −y: x to the right, z up.
    Front,
    /// From +x: y to the right.
    Right,
    /// From +y: −x to the right.
    Back,
    /// From −x: −y to the right.
    Left,
    /// From above: x to the right, y up.
    Top,
}

impl Side {
    /// In declaration order: `side as usize` indexes it.
    pub const ALL: [Side; 5] = [Side::Front, Side::Right, Side::Back, Side::Left, Side::Top];

    /// The side as file names and titles spell it.
    pub fn name(self) -> &'static str {
        match self {
            Side::Front => "front",
            Side::Right => "right",
            Side::Back => "back",
            Side::Left => "left",
            Side::Top => "top",
        }
    }

    /// What a person calls the view.
    pub fn title(self) -> &'static str {
        match self {
            Side::Front => "front (from −y)",
            Side::Right => "right (from +x)",
            Side::Back => "back (from +y)",
            Side::Left => "left (from −x)",
            Side::Top => "top (from above)",
        }
    }

    /// Towards the viewer.
    fn toward(self) -> [f64; 3] {
        match self {
            Side::Front => [0.0, -1.0, 0.0],
            Side::Right => [1.0, 0.0, 0.0],
            Side::Back => [0.0, 1.0, 0.0],
            Side::Left => [-1.0, 0.0, 0.0],
            Side::Top => [0.0, 0.0, 1.0],
        }
    }

    /// (right, up, nearness): the screen's axes and how near the viewer a point is.
    pub fn project(self, p: [f64; 3]) -> [f64; 3] {
        let [x, y, z] = p;
        match self {
            Side::Front => [x, z, -y],
            Side::Right => [y, z, x],
            Side::Back => [-x, z, y],
            Side::Left => [-y, z, -x],
            Side::Top => [x, y, z],
        }
    }

    /// The design-frame axis along the screen's right, and its sign.
    fn right_axis(self) -> (&'static str, f64) {
        match self {
            Side::Front | Side::Top => ("x", 1.0),
            Side::Right => ("y", 1.0),
            Side::Back => ("x", -1.0),
            Side::Left => ("y", -1.0),
        }
    }

    fn up_axis(self) -> &'static str {
        if self == Side::Top { "y" } else { "z" }
    }

    /// The side a surface with outward normal `n` faces; `None` for faces turned down.
    fn facing(n: [f64; 3]) -> Option<Side> {
        Side::ALL
            .into_iter()
            .map(|s| {
                let t = s.toward();
                (s, n[0] * t[0] + n[1] * t[1] + n[2] * t[2])
            })
            .filter(|(_, d)| *d > 0.3)
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(s, _)| s)
    }
}

/// What a pixel holds: the nearest surface's values.
#[derive(Debug, Clone, Copy)]
struct Cell {
    near: f32,
    sum: f32,
    values: u32,
    missing: u32,
    not_judged: u32,
}

const EMPTY: Cell = Cell {
    near: f32::NEG_INFINITY,
    sum: 0.0,
    values: 0,
    missing: 0,
    not_judged: 0,
};

/// What a mark says about its spot of the surface.
#[derive(Debug, Clone, Copy)]
enum Mark {
    Value(f64),
    Missing,
    NotJudged,
}

/// One side's raster.
#[derive(Debug, Clone)]
struct Raster {
    side: Side,
    /// The screen axes' lowest values, metres.
    u0: f64,
    v0: f64,
    w: usize,
    h: usize,
    cells: Vec<Cell>,
}

impl Raster {
    fn new(side: Side, lo: [f64; 3], hi: [f64; 3], pixel: f64) -> Self {
        let mut min = [f64::INFINITY; 3];
        let mut max = [f64::NEG_INFINITY; 3];
        for i in 0..8 {
            let c = [
                if i & 1 == 0 { lo[0] } else { hi[0] },
                if i & 2 == 0 { lo[1] } else { hi[1] },
                if i & 4 == 0 { lo[2] } else { hi[2] },
            ];
            let p = side.project(c);
            for k in 0..3 {
                min[k] = min[k].min(p[k]);
                max[k] = max[k].max(p[k]);
            }
        }
        let w = (((max[0] - min[0]) / pixel).ceil() as usize).max(1);
        let h = (((max[1] - min[1]) / pixel).ceil() as usize).max(1);
        Self {
            side,
            u0: min[0],
            v0: min[1],
            w,
            h,
            cells: vec![EMPTY; w * h],
        }
    }

    /// Where `p` falls: its column, row and nearness; None for a point off the number line.
    fn locate(&self, p: [f64; 3], pixel: f64) -> Option<(i64, i64, f32)> {
        let [u, v, near] = self.side.project(p);
        if !(u.is_finite() && v.is_finite() && near.is_finite()) {
            return None;
        }
        let (i, j) = self.cell_of(u, v, pixel);
        Some((i, j, near as f32))
    }

    /// The cell index of column `i`, row `j`, if inside.
    fn index(&self, i: i64, j: i64) -> Option<usize> {
        (i >= 0 && j >= 0 && i < self.w as i64 && j < self.h as i64)
            .then(|| j as usize * self.w + i as usize)
    }

    /// Marks the pixels within `radius` pixels of `p`.
    fn mark(&mut self, p: [f64; 3], mark: Mark, pixel: f64, radius: i64) {
        let Some((i, j, near)) = self.locate(p, pixel) else {
            return;
        };
        let slab = (SLAB_PX * pixel) as f32;
        for jj in j.saturating_sub(radius)..=j.saturating_add(radius) {
            for ii in i.saturating_sub(radius)..=i.saturating_add(radius) {
                if let Some(k) = self.index(ii, jj) {
                    self.mark_cell(k, near, mark, slab);
                }
            }
        }
    }

    /// Marks cell `k` with a surface at `near`.
    fn mark_cell(&mut self, k: usize, near: f32, mark: Mark, slab: f32) {
        let c = &mut self.cells[k];
        if near > c.near + slab {
            // A nearer surface hides what the pixel held.
            *c = Cell { near, ..EMPTY };
        } else if near < c.near - slab {
            return;
        }
        c.near = c.near.max(near);
        match mark {
            Mark::Value(d) => {
                c.sum += d as f32;
                c.values += 1;
            }
            Mark::Missing => c.missing += 1,
            Mark::NotJudged => c.not_judged += 1,
        }
    }

    /// The tile of cell `k`: squares of [`TILE_PX`] pixels, numbered row by row.
    fn tile(&self, k: usize) -> usize {
        let tiles_across = self.w.div_ceil(TILE_PX);
        (k / self.w / TILE_PX) * tiles_across + (k % self.w) / TILE_PX
    }

    fn tiles(&self) -> usize {
        self.w.div_ceil(TILE_PX) * self.h.div_ceil(TILE_PX)
    }

    /// Appends each point (design frame) on the raster, with its deviation, to `batch`.
    fn locate_all(&self, points: &[([f64; 3], f64)], pixel: f64, batch: &mut TileBatch) {
        for &(p, d) in points {
            let Some((i, j, near)) = self.locate(p, pixel) else {
                continue;
            };
            if let Some(k) = self.index(i, j).and_then(|k| u32::try_from(k).ok()) {
                // The cell adds the deviation as an f32: nothing is lost keeping it so.
                batch.marks.push((k, near, d as f32));
            }
        }
    }

    /// Marks the cells of `batch` tile by tile, and empties it.
    ///
    /// Points arrive in scan order, or in none, and land all over a raster of megabytes: one
    /// cache miss each, and a chunk's points are too few to meet a pixel twice. A batch of
    /// many chunks sorted by tile (a counting sort: two passes in order) brings each tile's
    /// cells into the cache once for many marks. The sort is stable, so every cell takes its
    /// marks in the order they came, and the raster's bits are those of marking one by one.
    fn mark_batch(&mut self, batch: &mut TileBatch, pixel: f64) {
        let TileBatch {
            marks,
            starts,
            sorted,
        } = batch;
        starts.clear();
        starts.resize(self.tiles() + 1, 0);
        for &(k, ..) in marks.iter() {
            starts[self.tile(k as usize) + 1] += 1;
        }
        for t in 1..starts.len() {
            starts[t] += starts[t - 1];
        }
        sorted.clear();
        sorted.resize(marks.len(), (0, 0.0, 0.0));
        for &m in marks.iter() {
            let t = self.tile(m.0 as usize);
            sorted[starts[t]] = m;
            starts[t] += 1;
        }
        let slab = (SLAB_PX * pixel) as f32;
        for &(k, near, d) in sorted.iter() {
            self.mark_cell(k as usize, near, Mark::Value(f64::from(d)), slab);
        }
        marks.clear();
    }

    /// Another raster of the same side and frame drawn over this one: where both hold a
    /// surface, the nearer hides the other unless they are the same.
    fn merge(&mut self, other: &Raster, pixel: f64) {
        let slab = (SLAB_PX * pixel) as f32;
        for (c, o) in self.cells.iter_mut().zip(&other.cells) {
            if o.near == f32::NEG_INFINITY || o.near < c.near - slab {
                continue;
            }
            if c.near == f32::NEG_INFINITY || o.near > c.near + slab {
                *c = *o;
                continue;
            }
            c.near = c.near.max(o.near);
            c.sum += o.sum;
            c.values += o.values;
            c.missing += o.missing;
            c.not_judged += o.not_judged;
        }
    }

    fn occupied(&self, k: usize) -> bool {
        self.cells[k].near != f32::NEG_INFINITY
    }

    /// The nearness of the surface at `p`'s pixel, if any.
    fn surface_at(&self, p: [f64; 3], pixel: f64) -> Option<f32> {
        let [u, v, _] = self.side.project(p);
        let (i, j) = self.cell_of(u, v, pixel);
        if i < 0 || j < 0 || i >= self.w as i64 || j >= self.h as i64 {
            return None;
        }
        let k = j as usize * self.w + i as usize;
        self.occupied(k).then(|| self.cells[k].near)
    }

    /// The column and row of screen coordinates (u, v), row 0 at the top of the picture;
    /// outside the raster for points beyond it (saturating, never wrapping).
    fn cell_of(&self, u: f64, v: f64, pixel: f64) -> (i64, i64) {
        let i = floor_i64((u - self.u0) / pixel);
        let j = (self.h as i64 - 1).saturating_sub(floor_i64((v - self.v0) / pixel));
        (i, j)
    }
}

/// Pixels along a tile's side: 32 × 32 cells of 20 bytes fit the first-level cache.
const TILE_PX: usize = 32;

/// Marks waiting to be drawn on one side's raster, and the buffers that sort them, reused.
#[derive(Debug, Default)]
struct TileBatch {
    /// Each point's cell, nearness and deviation, in the order they came.
    marks: Vec<(u32, f32, f32)>,
    /// Where each tile's marks start in `sorted`.
    starts: Vec<usize>,
    /// The marks in tile order.
    sorted: Vec<(u32, f32, f32)>,
}

/// Points batched before their marks are drawn: 12 bytes each, twice (as they came and
/// sorted), so at most 12 MB whatever the scan.
const BATCH_POINTS: usize = 1 << 19;

/// The five sides' rasters of one kind of map.
#[derive(Debug, Clone)]
pub struct Sides {
    rasters: Vec<Raster>,
}

impl Sides {
    fn new(frame: &MapFrame) -> Self {
        Self {
            rasters: Side::ALL
                .into_iter()
                .map(|s| Raster::new(s, frame.lo, frame.hi, frame.pixel))
                .collect(),
        }
    }

    fn side(&self, s: Side) -> &Raster {
        &self.rasters[s as usize]
    }

    fn mark(&mut self, side: Side, p: [f64; 3], mark: Mark, pixel: f64, radius: i64) {
        self.rasters[side as usize].mark(p, mark, pixel, radius);
    }

    fn merge(&mut self, other: &Sides, pixel: f64) {
        for (a, b) in self.rasters.iter_mut().zip(&other.rasters) {
            a.merge(b, pixel);
        }
    }

    /// Whether any side holds anything.
    pub fn is_empty(&self) -> bool {
        self.rasters
            .iter()
            .all(|r| r.cells.iter().all(|c| c.near == f32::NEG_INFINITY))
    }
}

/// The extent every map of a design shares.
#[derive(Debug, Clone, Copy)]
pub struct MapFrame {
    lo: [f64; 3],
    hi: [f64; 3],
    /// Metres per raster pixel.
    pixel: f64,
}

impl MapFrame {
    /// The design's box, grown by `margin` metres.
    pub fn of(design: &Design, margin: f64) -> Self {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for v in &design.vertices {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        if !lo[0].is_finite() {
            lo = [0.0; 3];
            hi = [1.0; 3];
        }
        for k in 0..3 {
            lo[k] -= margin;
            hi[k] += margin;
        }
        let longest = (0..3).map(|k| hi[k] - lo[k]).fold(0.0, f64::max);
        Self {
            lo,
            hi,
            pixel: (longest / LONGEST_SIDE_PX).max(1e-6),
        }
    }
}

/// One scan layer's maps.
#[derive(Debug, Clone)]
pub struct ScanLayerMaps {
    /// The job.
    pub job: u64,
    /// NaN when not printing.
    pub printed_height: f64,
    /// The points' C2M.
    pub points: Sides,
    /// The design samples' M3C2 and missing material, with findings.
    pub samples: Option<Sides>,
    frame: MapFrame,
    tolerance: f64,
}

/// A scan layer: its job and its printed height's bits.
type LayerKey = (u64, u64);

/// Collects the maps of a job while its stations stream: each station's points into a raster of
/// its own, merged into its scan layer's when it reports; the design samples' states with each
/// scan layer's latest findings.
pub struct MapCollector {
    frame: MapFrame,
    tolerance: f64,
    /// The side each design triangle faces, for the points matched to it.
    facing: Vec<Option<Side>>,
    /// Design sample spacing, metres.
    spacing: f64,
    stations: FxHashMap<(u64, u32), Sides>,
    layers: BTreeMap<LayerKey, ScanLayerMaps>,
    /// A chunk's points (design frame) and distances, side by side, reused chunk after chunk.
    by_side: [Vec<([f64; 3], f64)>; 5],
    /// Each side's marks not yet drawn, all of the station `batched`.
    batches: [TileBatch; 5],
    /// The station whose marks wait in `batches`, and how many points they came from.
    batched: Option<((u64, u32), usize)>,
    /// False when the maps are not wanted: everything offered is ignored.
    on: bool,
}

impl MapCollector {
    /// Maps of `design` at `tolerance`, with design samples `spacing` apart.
    pub fn new(design: &Design, tolerance: f64, spacing: f64) -> Self {
        let frame = MapFrame::of(design, 2.0 * tolerance);
        let facing = design
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| design.vertices[i as usize]);
                let n = (b - a).cross(&(c - a));
                let l = n.norm();
                (l > 0.0)
                    .then(|| Side::facing([n.x / l, n.y / l, n.z / l]))
                    .flatten()
            })
            .collect();
        Self {
            frame,
            tolerance,
            facing,
            spacing,
            stations: FxHashMap::default(),
            layers: BTreeMap::new(),
            by_side: Default::default(),
            batches: Default::default(),
            batched: None,
            on: true,
        }
    }

    /// The collector that draws nothing: `finish` gives no maps, and report.html shows none.
    pub fn off(mut self) -> Self {
        self.on = false;
        self
    }

    /// A chunk of `station`'s deviations.
    pub fn points(&mut self, station: (u64, u32), devs: &[PointDeviation]) {
        if !self.on {
            return;
        }
        if self.batched.is_some_and(|(s, _)| s != station) {
            self.draw_batched();
        }
        let frame = self.frame;
        let facing = &self.facing;
        let sides = self
            .stations
            .entry(station)
            .or_insert_with(|| Sides::new(&frame));
        // The points are sorted by side in one pass, then each side's are located by a task of
        // its own.
        for b in &mut self.by_side {
            b.clear();
        }
        for d in devs {
            if let Some(side) = side_of(facing, d) {
                self.by_side[side as usize].push((d.position, d.distance));
            }
        }
        sides
            .rasters
            .par_iter()
            .zip(self.by_side.par_iter())
            .zip(self.batches.par_iter_mut())
            .for_each(|((raster, points), batch)| raster.locate_all(points, frame.pixel, batch));
        let waiting = self.batched.map_or(0, |(_, n)| n) + devs.len();
        self.batched = Some((station, waiting));
        if waiting >= BATCH_POINTS {
            self.draw_batched();
        }
    }

    /// Draws the batched marks on their station's rasters, each side by a task of its own: the
    /// rasters are apart, so the cores share both the work and the cache.
    fn draw_batched(&mut self) {
        let Some((station, _)) = self.batched.take() else {
            return;
        };
        let pixel = self.frame.pixel;
        if let Some(sides) = self.stations.get_mut(&station) {
            (sides.rasters.par_iter_mut())
                .zip(self.batches.par_iter_mut())
                .for_each(|(raster, batch)| raster.mark_batch(batch, pixel));
        }
    }

    fn layer(&mut self, job: u64, printed_height: f64) -> &mut ScanLayerMaps {
        let frame = self.frame;
        let tolerance = self.tolerance;
        self.layers
            .entry((job, printed_height.to_bits()))
            .or_insert_with(|| ScanLayerMaps {
                job,
                printed_height,
                points: Sides::new(&frame),
                samples: None,
                frame,
                tolerance,
            })
    }

    /// Forgets a station's points: it was interrupted, and its next attempt sends them again.
    pub fn station_dropped(&mut self, station: (u64, u32)) {
        if self.batched.is_some_and(|(s, _)| s == station) {
            self.batched = None;
            self.batches.iter_mut().for_each(|b| b.marks.clear());
        }
        self.stations.remove(&station);
    }

    /// `station` reported, at `printed_height`: its points join its scan layer's.
    pub fn station_done(&mut self, station: (u64, u32), printed_height: f64) {
        if self.batched.is_some_and(|(s, _)| s == station) {
            self.draw_batched();
        }
        let Some(sides) = self.stations.remove(&station) else {
            return;
        };
        let pixel = self.frame.pixel;
        self.layer(station.0, printed_height)
            .points
            .merge(&sides, pixel);
    }

    /// The design samples' states of a scan layer's latest findings.
    pub fn samples(&mut self, job: u64, printed_height: f64, samples: &[SampleState]) {
        if !self.on {
            return;
        }
        let frame = self.frame;
        // A sample stands for about a square `spacing` wide; the samples are scattered, not on a
        // grid, so the squares overlap a little to leave no holes.
        let radius = ((0.75 * self.spacing / frame.pixel).ceil() as i64).clamp(0, 8);
        let mut sides = Sides::new(&frame);
        for s in samples {
            let n = [s.normal.x, s.normal.y, s.normal.z];
            let Some(side) = Side::facing(n) else {
                continue;
            };
            // What the findings judged, nothing else: a sample they left out (near a sharp
            // edge, never in view, a missing patch too small to count) is "not judged".
            let mark = match (s.judged, s.m3c2) {
                (Judged::Missing, _) => Mark::Missing,
                (Judged::Measured, Some(d)) => Mark::Value(d),
                _ => Mark::NotJudged,
            };
            sides.mark(side, s.position.into(), mark, frame.pixel, radius);
        }
        self.layer(job, printed_height).samples = Some(sides);
    }

    /// The scan layers' maps, by job and printed height.
    pub fn finish(mut self) -> Vec<ScanLayerMaps> {
        // Stations that never reported (cut short) are left out: their scan layer is unknown.
        self.stations.clear();
        let mut out: Vec<_> = self.layers.into_values().collect();
        out.sort_by(|a, b| {
            (a.job, a.printed_height)
                .partial_cmp(&(b.job, b.printed_height))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        out
    }
}

/// Which map of a scan layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapKind {
    /// The points' C2M.
    Points,
    /// The design samples' M3C2 and missing material.
    Samples,
}

/// The side a matched point is drawn on: the one its design triangle faces; past the design's
/// triangles come the cap's, which close a printed height and face up.
fn side_of(facing: &[Option<Side>], d: &PointDeviation) -> Option<Side> {
    if d.flags.contains(DeviationFlags::REJECTED) || !d.distance.is_finite() {
        return None;
    }
    match facing.get(d.triangle as usize) {
        Some(f) => *f,
        None if d.triangle != u32::MAX => Some(Side::Top),
        None => None,
    }
}

impl MapKind {
    /// The kind as file names spell it.
    pub fn name(self) -> &'static str {
        match self {
            MapKind::Points => "c2m",
            MapKind::Samples => "m3c2",
        }
    }
}

const NOT_JUDGED: [u8; 3] = [222, 222, 222];
const OUTLINE: [u8; 3] = [70, 70, 70];
const MISSING: [u8; 3] = [0, 0, 255];

impl ScanLayerMaps {
    fn sides(&self, kind: MapKind) -> Option<&Sides> {
        match kind {
            MapKind::Points => Some(&self.points),
            MapKind::Samples => self.samples.as_ref(),
        }
    }

    /// The side on which a point of the design shows: the nearest surface there is at it.
    fn shows_on(&self, p: [f64; 3]) -> Vec<Side> {
        let sides = self.samples.as_ref().unwrap_or(&self.points);
        let pixel = self.frame.pixel;
        Side::ALL
            .into_iter()
            .filter(|&s| {
                sides
                    .side(s)
                    .surface_at(p, pixel)
                    .is_some_and(|near| (s.project(p)[2] as f32 - near).abs() <= 0.05)
            })
            .collect()
    }

    /// The PNG of one side: the map's colours over the design's footprint in light grey, and
    /// (from the design samples, when there are any) its outline just outside it.
    fn png(&self, kind: MapKind, side: Side) -> Option<Vec<u8>> {
        let map = self.sides(kind)?.side(side);
        let footprint = self.samples.as_ref().map(|s| s.side(side));
        let (w, h) = (map.w, map.h);
        let inside = |k: usize| footprint.is_some_and(|f| f.occupied(k));
        let mut rgba = vec![0u8; w * h * 4];
        for k in 0..w * h {
            let c = map.cells[k];
            let colour = if c.values > 0 {
                deviation_colour(f64::from(c.sum / c.values as f32), self.tolerance)
            } else if c.missing > 0 {
                MISSING
            } else if c.not_judged > 0 || inside(k) {
                NOT_JUDGED
            } else {
                let (i, j) = (k % w, k / w);
                let next_to_design = (i > 0 && inside(k - 1))
                    || (i + 1 < w && inside(k + 1))
                    || (j > 0 && inside(k - w))
                    || (j + 1 < h && inside(k + w));
                if !next_to_design {
                    continue;
                }
                OUTLINE
            };
            rgba[4 * k..4 * k + 3].copy_from_slice(&colour);
            rgba[4 * k + 3] = 255;
        }
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, w as u32, h as u32);
            enc.set_color(png::ColorType::Rgba);
            enc.set_depth(png::BitDepth::Eight);
            // fdeflate's PNG-tuned mode: the maps are flat colour fields, which it packs nearly
            // as small as the default level at a fraction of the time.
            enc.set_compression(png::Compression::Fast);
            let mut writer = enc.write_header().ok()?;
            writer.write_image_data(&rgba).ok()?;
        }
        Some(out)
    }

    /// Screen position of design point `p` on `side`'s map.
    pub fn screen(&self, side: Side, p: [f64; 3]) -> (f64, f64) {
        let r = self.points.side(side);
        let scale = ZOOM / self.frame.pixel;
        let [u, v, _] = side.project(p);
        let top_v = r.v0 + r.h as f64 * self.frame.pixel;
        (
            MARGINS.left + (u - r.u0) * scale,
            MARGINS.top + (top_v - v) * scale,
        )
    }

    /// Width and height of `side`'s SVG, screen pixels.
    pub fn svg_size(&self, side: Side) -> (f64, f64) {
        let r = self.points.side(side);
        (
            MARGINS.left + r.w as f64 * ZOOM + MARGINS.right,
            MARGINS.top + r.h as f64 * ZOOM + MARGINS.bottom,
        )
    }

    /// The SVG of one side's map with `items`' call-outs; `None` when that map was not made.
    pub fn svg(&self, kind: MapKind, side: Side, items: &[Item]) -> Option<String> {
        let Margins { left, top, .. } = MARGINS;
        let png = self.png(kind, side)?;
        let r = self.points.side(side);
        let (iw, ih) = (r.w as f64 * ZOOM, r.h as f64 * ZOOM);
        let (w, h) = self.svg_size(side);
        let scale = ZOOM / self.frame.pixel;
        let mut svg = format!(
            "<svg class=\"map\" width=\"{w:.0}\" \
             height=\"{h:.0}\" viewBox=\"0 0 {w:.0} {h:.0}\" data-kind=\"{}\" data-side=\"{}\" \
             data-u0=\"{}\" data-v0=\"{}\" data-px-per-m=\"{}\" data-left=\"{left}\" \
             data-top=\"{top}\" data-height-px=\"{ih}\" role=\"img\" aria-label=\"{} map, {}\">",
            kind.name(),
            side.name(),
            r.u0,
            r.v0,
            scale,
            kind.name(),
            side.title()
        );
        let _ = write!(
            svg,
            "<image x=\"{left}\" y=\"{top}\" width=\"{iw}\" height=\"{ih}\" \
             preserveAspectRatio=\"none\" style=\"image-rendering:pixelated\" \
             href=\"data:image/png;base64,{}\"/>",
            base64::engine::general_purpose::STANDARD.encode(png)
        );
        self.axes(&mut svg, side);
        if side != Side::Top && self.printed_height.is_finite() {
            let (_, y) = self.screen(side, [0.0, 0.0, self.printed_height]);
            let (x0, _) = (left, 0.0);
            let _ = write!(
                svg,
                "<line class=\"printed-height\" x1=\"{x0}\" y1=\"{y:.1}\" x2=\"{:.1}\" \
                 y2=\"{y:.1}\" stroke=\"#555\" stroke-dasharray=\"4,3\"/>",
                left + iw
            );
        }
        let band_label_y = self.band_label_positions(side, items);
        for (k, it) in items.iter().enumerate() {
            self.callout(&mut svg, side, it, band_label_y[k]);
        }
        svg.push_str("</svg>");
        Some(svg)
    }

    fn axes(&self, svg: &mut String, side: Side) {
        let Margins { left, top, .. } = MARGINS;
        let r = self.points.side(side);
        let px = self.frame.pixel;
        let (iw, ih) = (r.w as f64 * ZOOM, r.h as f64 * ZOOM);
        let _ = write!(
            svg,
            "<rect x=\"{left}\" y=\"{top}\" width=\"{iw}\" height=\"{ih}\" fill=\"none\" \
             stroke=\"#bbb\"/>"
        );
        let (right_name, sign) = side.right_axis();
        let span_u = r.w as f64 * px;
        let step = tick_step(span_u, iw);
        let mut t = (r.u0 / step).ceil() * step;
        while t <= r.u0 + span_u + 1e-9 {
            let x = left + (t - r.u0) * ZOOM / px;
            let _ = write!(
                svg,
                "<line x1=\"{x:.1}\" y1=\"{:.1}\" x2=\"{x:.1}\" y2=\"{:.1}\" stroke=\"#888\"/>\
                 <text x=\"{x:.1}\" y=\"{:.1}\" font-size=\"10\" text-anchor=\"middle\">{}</text>",
                top + ih,
                top + ih + 4.0,
                top + ih + 15.0,
                tick_text(sign * t)
            );
            t += step;
        }
        let span_v = r.h as f64 * px;
        let step = tick_step(span_v, ih.max(90.0));
        let mut t = (r.v0 / step).ceil() * step;
        while t <= r.v0 + span_v + 1e-9 {
            let y = top + ih - (t - r.v0) * ZOOM / px;
            let _ = write!(
                svg,
                "<line x1=\"{:.1}\" y1=\"{y:.1}\" x2=\"{left}\" y2=\"{y:.1}\" stroke=\"#888\"/>\
                 <text x=\"{:.1}\" y=\"{:.1}\" font-size=\"10\" text-anchor=\"end\">{}</text>",
                left - 4.0,
                left - 6.0,
                y + 3.5,
                tick_text(t)
            );
            t += step;
        }
        let _ = write!(
            svg,
            "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"10\" text-anchor=\"end\" fill=\"#555\">\
             {right_name} m</text><text x=\"4\" y=\"{:.1}\" font-size=\"10\" fill=\"#555\">{} m\
             </text>",
            left + iw,
            top + ih + 27.0,
            top + 8.0,
            side.up_axis()
        );
    }

    /// Where each layer band's number goes beside its bar: at the bar's middle, moved up just
    /// enough that numbers of neighbouring bands do not overprint each other (with a leader
    /// line back to the bar). `None` for items that are not bars.
    fn band_label_positions(&self, side: Side, items: &[Item]) -> Vec<Option<f64>> {
        const GAP: f64 = 10.0;
        let mut out = vec![None; items.len()];
        if side == Side::Top {
            return out;
        }
        let mut bars: Vec<(usize, f64)> = items
            .iter()
            .enumerate()
            .filter(|(_, it)| it.at.is_none() || it.extent.is_none())
            .map(|(k, it)| {
                let (_, ya) = self.screen(side, [0.0, 0.0, it.z[0]]);
                let (_, yb) = self.screen(side, [0.0, 0.0, it.z[1]]);
                (k, 0.5 * (ya + yb))
            })
            .collect();
        // From the bottom of the picture up (screen y grows downwards).
        bars.sort_by(|a, b| b.1.total_cmp(&a.1));
        let mut above = f64::INFINITY;
        for (k, y) in bars {
            let y = y.min(above - GAP);
            out[k] = Some(y);
            above = y;
        }
        out
    }

    /// An area's box and numbered circle where it shows; a layer band's bar at the left, its
    /// number at `label_y`.
    fn callout(&self, svg: &mut String, side: Side, it: &Item, label_y: Option<f64>) {
        let colour = if it.verdict == Verdict::Fail {
            "#c00"
        } else {
            "#d80"
        };
        match (it.at, it.extent) {
            (Some(at), Some([lo, hi])) => {
                let shows = self.shows_on(at);
                // An area that goes round the part (its centre inside it) is marked on every
                // elevation its extent reaches, at the middle of its box.
                let around = shows.is_empty() && side != Side::Top;
                if !(shows.contains(&side) || around) {
                    return;
                }
                let (x0, y0) = self.screen(side, lo);
                let (x1, y1) = self.screen(side, hi);
                let (cx, cy) = if around {
                    (0.5 * (x0 + x1), 0.5 * (y0 + y1))
                } else {
                    self.screen(side, at)
                };
                let _ = write!(
                    svg,
                    "<g class=\"finding\" data-label=\"{l}\" data-kind=\"{k}\" \
                     data-verdict=\"{v}\"><rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" \
                     height=\"{:.1}\" fill=\"none\" stroke=\"{colour}\" stroke-width=\"1.5\"/>\
                     <circle cx=\"{cx:.1}\" cy=\"{cy:.1}\" r=\"8\" fill=\"#fff\" \
                     stroke=\"{colour}\" stroke-width=\"2\"/><text class=\"label\" x=\"{cx:.1}\" \
                     y=\"{:.1}\" font-size=\"10\" font-weight=\"bold\" text-anchor=\"middle\" \
                     fill=\"{colour}\">{l}</text><title>{}</title></g>",
                    x0.min(x1) - 2.0,
                    y0.min(y1) - 2.0,
                    (x1 - x0).abs() + 4.0,
                    (y1 - y0).abs() + 4.0,
                    cy + 3.5,
                    crate::markup::esc(&it.text),
                    l = it.label,
                    k = it.kind,
                    v = it.verdict,
                );
            }
            _ if side != Side::Top => {
                // A layer band or the top: a bracket over its heights beside the picture.
                let (_, ya) = self.screen(side, [0.0, 0.0, it.z[0]]);
                let (_, yb) = self.screen(side, [0.0, 0.0, it.z[1]]);
                let x = MARGINS.left - 1.0;
                let ym = 0.5 * (ya + yb);
                let yl = label_y.unwrap_or(ym);
                let _ = write!(
                    svg,
                    "<g class=\"finding\" data-label=\"{l}\" data-kind=\"{k}\" \
                     data-verdict=\"{v}\"><line x1=\"{x}\" y1=\"{:.1}\" x2=\"{x}\" y2=\"{:.1}\" \
                     stroke=\"{colour}\" stroke-width=\"3\"/><line class=\"leader\" x1=\"{x}\" \
                     y1=\"{ym:.1}\" x2=\"{:.1}\" y2=\"{yl:.1}\" stroke=\"{colour}\" \
                     stroke-width=\"0.6\"/><text class=\"label\" x=\"{:.1}\" y=\"{:.1}\" \
                     font-size=\"9\" font-weight=\"bold\" text-anchor=\"start\" \
                     fill=\"{colour}\">{l}</text><title>{}</title></g>",
                    ya.max(yb),
                    ya.min(yb).min(ya.max(yb) - 1.0),
                    x + 3.0,
                    x + 4.0,
                    yl + 3.0,
                    crate::markup::esc(&it.text),
                    l = it.label,
                    k = it.kind,
                    v = it.verdict,
                );
            }
            _ => {}
        }
    }
}

/// A round step for about five ticks over `span` metres drawn `screen` pixels long, at least
/// 45 pixels apart so that their numbers do not run into each other.
fn tick_step(span: f64, screen: f64) -> f64 {
    let raw = (span / 5.0).max(span * 45.0 / screen.max(1.0));
    let p = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * p)
}

fn tick_text(v: f64) -> String {
    let v = if v.abs() < 1e-9 { 0.0 } else { v };
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use asbuilt_core::design::shapes::cuboid;
    use nalgebra::Point3;

    /// The point at `p` on the cuboid's face `triangle`, `d` off the design.
    fn dev(p: [f64; 3], d: f64, triangle: u32) -> PointDeviation {
        PointDeviation {
            position: p,
            distance: d,
            triangle,
            ..Default::default()
        }
    }

    /// Marks taken tile by tile leave every cell with the bits of marking one point after
    /// another: points in no order, many to a pixel, at nearnesses inside and beyond the slab
    /// (so hiding depends on the order), some off the raster, over every side.
    #[test]
    fn marks_sorted_by_tile_give_the_bits_of_marks_one_by_one() {
        let design = cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.8, 1.2));
        let frame = MapFrame::of(&design, 0.01);
        let pixel = frame.pixel;
        // A cheap generator: the order is scrambled, the values repeat often enough to share
        // pixels.
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let points: Vec<([f64; 3], f64)> = (0..40_000)
            .map(|_| {
                // Coarse positions crowd many points into a pixel; depths a few slabs apart.
                let q = |v: f64, span: f64| ((v * 60.0).floor() / 60.0) * span - 0.1;
                let p = [q(next(), 1.2), q(next(), 0.9), q(next(), 1.3)];
                (p, (next() - 0.5) * 0.02)
            })
            .collect();
        for side in Side::ALL {
            let mut one_by_one = Raster::new(side, frame.lo, frame.hi, pixel);
            for &(p, d) in &points {
                one_by_one.mark(p, Mark::Value(d), pixel, 0);
            }
            // Two chunks in one batch, and in two batches with the buffers reused.
            let (a, b) = points.split_at(17_000);
            let mut batch = TileBatch::default();
            let mut one_batch = Raster::new(side, frame.lo, frame.hi, pixel);
            one_batch.locate_all(a, pixel, &mut batch);
            one_batch.locate_all(b, pixel, &mut batch);
            one_batch.mark_batch(&mut batch, pixel);
            let mut two_batches = Raster::new(side, frame.lo, frame.hi, pixel);
            for chunk in [a, b] {
                two_batches.locate_all(chunk, pixel, &mut batch);
                two_batches.mark_batch(&mut batch, pixel);
            }
            assert!(
                one_by_one.tiles() > 4,
                "{side:?}: the raster spans several tiles"
            );
            let bits = |c: &Cell| (c.near.to_bits(), c.sum.to_bits(), c.values);
            let marked = one_by_one.cells.iter().filter(|c| c.values > 1).count();
            assert!(
                marked > 100,
                "{side:?}: pixels hold several marks ({marked})"
            );
            for (k, x) in one_by_one.cells.iter().enumerate() {
                assert_eq!(bits(x), bits(&one_batch.cells[k]), "{side:?}, cell {k}");
                assert_eq!(bits(x), bits(&two_batches.cells[k]), "{side:?}, cell {k}");
            }
        }
    }

    /// Stations whose chunks alternate, or whose batches fill, draw what stations sent one
    /// after the other draw; a dropped station's batched points are forgotten with it.
    #[test]
    fn batched_marks_follow_their_station() {
        let design = cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.8, 1.2));
        let front = face_of(&design, [0.0, -1.0, 0.0]);
        let chunk = |seed: u32, n: u32| -> Vec<PointDeviation> {
            (0..n)
                .map(|i| {
                    let t = f64::from((i * 7919 + seed * 104_729) % 10_007) / 10_007.0;
                    let p = [t, -0.001 * f64::from(seed), (t * 37.0).fract() * 1.2];
                    dev(p, (t - 0.5) * 0.004, front)
                })
                .collect()
        };
        let (a1, a2, b1, b2) = (
            chunk(1, 3000),
            chunk(2, 3000),
            chunk(3, 3000),
            chunk(4, 3000),
        );
        let layer_cells = |m: MapCollector| -> Vec<(u32, u32, u32)> {
            let maps = m.finish();
            assert_eq!(maps.len(), 1);
            let raster = maps[0].points.side(Side::Front);
            (raster.cells.iter())
                .map(|c| (c.near.to_bits(), c.sum.to_bits(), c.values))
                .collect()
        };
        let mut apart = MapCollector::new(&design, 0.002, 0.01);
        for (st, chunks) in [((1, 1), [&a1, &a2]), ((1, 2), [&b1, &b2])] {
            for c in chunks {
                apart.points(st, c);
            }
            apart.station_done(st, 1.2);
        }
        let mut alternating = MapCollector::new(&design, 0.002, 0.01);
        alternating.points((1, 1), &a1);
        alternating.points((1, 2), &b1);
        alternating.points((1, 9), &b2); // dropped: must leave no mark
        alternating.station_dropped((1, 9));
        alternating.points((1, 1), &a2);
        alternating.points((1, 2), &b2);
        alternating.station_done((1, 1), 1.2);
        alternating.station_done((1, 2), 1.2);
        let want = layer_cells(apart);
        assert!(want.iter().filter(|c| c.2 > 0).count() > 1000);
        assert_eq!(want, layer_cells(alternating));
    }

    fn face_of(design: &Design, toward: [f64; 3]) -> u32 {
        (0..design.triangles.len() as u32)
            .find(|&t| {
                let [a, b, c] = design.triangles[t as usize].map(|i| design.vertices[i as usize]);
                let n = (b - a).cross(&(c - a)).normalize();
                (n.x * toward[0] + n.y * toward[1] + n.z * toward[2]) > 0.99
            })
            .unwrap()
    }

    fn pixels(png: &[u8]) -> (u32, u32, Vec<u8>) {
        let mut reader = png::Decoder::new(std::io::Cursor::new(png))
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        (info.width, info.height, buf)
    }

    #[test]
    fn points_colour_the_side_their_triangle_faces_and_the_nearer_surface_hides_the_farther() {
        // A 1 × 0.2 × 0.5 m block; the front (−y) face 4 mm out, the back (+y) 4 mm in.
        let design = cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.2, 0.5));
        let (front, back) = (
            face_of(&design, [0.0, -1.0, 0.0]),
            face_of(&design, [0.0, 1.0, 0.0]),
        );
        let mut maps = MapCollector::new(&design, 0.004, 0.01);
        let mut devs = Vec::new();
        for i in 1..400 {
            for k in 1..200 {
                let (x, z) = (f64::from(i) * 0.0025, f64::from(k) * 0.0025);
                devs.push(dev([x, -0.004, z], 0.004, front));
                devs.push(dev([x, 0.204, z], -0.004, back));
            }
        }
        maps.points((1, 0), &devs);
        maps.station_done((1, 0), f64::NAN);
        let layers = maps.finish();
        assert_eq!(layers.len(), 1);
        let m = &layers[0];
        let middle = |side| {
            let (w, h, px) = pixels(&m.png(MapKind::Points, side).unwrap());
            let k = ((h / 2) * w + w / 2) as usize * 4;
            [px[k], px[k + 1], px[k + 2], px[k + 3]]
        };
        // Saturated red from the front, blue from the back: each face on its own side, the
        // far face hidden.
        assert_eq!(middle(Side::Front), [255, 0, 0, 255]);
        assert_eq!(middle(Side::Back), [0, 0, 255, 255]);
        // Nothing faces the ends or the top.
        let (_, _, px) = pixels(&m.png(MapKind::Points, Side::Top).unwrap());
        assert!(px.iter().all(|&b| b == 0));
        // Twice the raster's pixels on screen, the design's longest side 320 of them.
        let svg = m.svg(MapKind::Points, Side::Front, &[]).unwrap();
        let doc = roxmltree::Document::parse(&svg).unwrap();
        let image = doc.descendants().find(|n| n.has_tag_name("image")).unwrap();
        let w: f64 = image.attribute("width").unwrap().parse().unwrap();
        // The front's width is the block's length, its longest side.
        assert_eq!(w, ZOOM * LONGEST_SIDE_PX);
        // A point's screen position: x grows along the part, z upwards.
        let (x0, y0) = m.screen(Side::Front, [0.0, 0.0, 0.0]);
        let (x1, y1) = m.screen(Side::Front, [1.0, 0.0, 0.5]);
        let px_per_m = ZOOM * LONGEST_SIDE_PX / (1.0 + 4.0 * 0.004);
        assert!((x1 - x0 - px_per_m).abs() < 1e-9, "{x0} {x1}");
        assert!((y0 - y1 - 0.5 * px_per_m).abs() < 1e-9, "{y0} {y1}");
        // The margin (twice the tolerance) to the picture's left edge.
        assert!((x0 - MARGINS.left - 0.008 * px_per_m).abs() < 1e-9, "{x0}");
    }

    #[test]
    fn numbers_of_neighbouring_layer_bands_do_not_overprint() {
        let design = cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(2.0, 0.2, 1.0));
        let mut layers = MapCollector::new(&design, 0.005, 0.01);
        layers.points((1, 0), &[dev([1.0, 0.0, 0.5], 0.0, 0)]);
        layers.station_done((1, 0), f64::NAN);
        let m = &layers.finish()[0];
        let band = |k: u32| Item {
            label: (k + 1).to_string(),
            kind: crate::ItemKind::Width,
            verdict: Verdict::Fail,
            value: 0.01,
            uncertainty: Some(0.001),
            limit: 0.005,
            layers: Some([k, k]),
            z: [0.02 * f64::from(k), 0.02 * f64::from(k + 1)],
            at: None,
            extent: None,
            since: 0,
            change: crate::Change::New,
            previous: None,
            text: String::new(),
        };
        let items: Vec<Item> = (2..6).map(band).collect();
        let ys: Vec<f64> = m
            .band_label_positions(Side::Front, &items)
            .into_iter()
            .map(Option::unwrap)
            .collect();
        // Bands 2 cm high are about 6 screen pixels apart; their numbers are 10 apart.
        for w in ys.windows(2) {
            assert!(w[0] - w[1] >= 10.0 - 1e-9, "{ys:?}");
        }
        // The lowest band's number stays at its bar.
        let (_, ya) = m.screen(Side::Front, [0.0, 0.0, 0.04]);
        let (_, yb) = m.screen(Side::Front, [0.0, 0.0, 0.06]);
        assert!((ys[0] - 0.5 * (ya + yb)).abs() < 1e-9);
        assert!(
            m.band_label_positions(Side::Top, &items)
                .iter()
                .all(Option::is_none)
        );
    }

    #[test]
    fn points_far_outside_or_not_finite_are_left_off_the_map() {
        let design = cuboid(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.2, 0.5));
        let top = face_of(&design, [0.0, 0.0, 1.0]);
        let mut maps = MapCollector::new(&design, 0.004, 0.01);
        let far = [
            [1e300, -1e300, 1e300],
            [-1e300, 1e300, -1e300],
            [f64::INFINITY, 0.0, 0.5],
            [f64::NAN, 0.1, 0.5],
        ];
        let devs: Vec<_> = far.iter().map(|&p| dev(p, 0.001, top)).collect();
        maps.points((1, 0), &devs);
        maps.station_done((1, 0), f64::NAN);
        let m = &maps.finish()[0];
        assert!(m.points.is_empty());
        assert!(m.svg(MapKind::Points, Side::Top, &[]).is_some());
    }

    #[test]
    fn sides_project_as_a_viewer_standing_there_sees() {
        // Seen from each side, the right of the screen and the nearness follow the view.
        let p = [1.0, 2.0, 3.0];
        assert_eq!(Side::Front.project(p), [1.0, 3.0, -2.0]);
        assert_eq!(Side::Back.project(p), [-1.0, 3.0, 2.0]);
        assert_eq!(Side::Left.project(p), [-2.0, 3.0, -1.0]);
        assert_eq!(Side::Right.project(p), [2.0, 3.0, 1.0]);
        assert_eq!(Side::Top.project(p), [1.0, 2.0, 3.0]);
        for s in Side::ALL {
            assert_eq!(Side::facing(s.toward()), Some(s));
            // What faces the viewer is nearer than what faces away.
            let t = s.toward();
            assert!(s.project(t)[2] > s.project(t.map(|v| -v))[2]);
        }
        assert_eq!(Side::facing([0.0, 0.0, -1.0]), None);
    }
}
