//! Fixed probes on the design (samples or core points) meeting a stream of scan points.
//!
//! Reverse C2C and streaming M3C2 both ask, for every probe, about the scan points within a
//! fixed region around it: a ball for coverage, a cylinder along the probe's normal for M3C2.
//! The probes are bucketed once into cubic cells as wide as the region's reach; each chunk of
//! scan points is bucketed too, and every probe cell next to an occupied point cell is active.
//! Each probe's state is touched by one task only, so cells run in parallel without locks, and
//! which points a probe is offered does not depend on how the scan is cut into chunks. State is
//! per probe; the only per-point memory is the chunk's own scratch.
//!
//! A ball's probe visits the points of its cell's 27 neighbours. A cylinder is long and thin
//! (M3C2's is 2 to 5 times longer than wide, and the probes sit on a surface): the points of 27
//! cells as wide as its length are mostly far to its side, and testing them was nearly all of
//! M3C2's time. So for cylinders the points are bucketed into fine cells as wide as the
//! cylinder's radius, and each probe visits only the fine cells its cylinder's bounding box
//! touches: every point inside the cylinder is in that box, so nothing is missed.
//!
//! A probe that keeps only its nearest point (coverage) needs none of the points farther than
//! the nearest it has: its region narrows as it learns. Such probes search fine cells too, in a
//! box their state gives, first within one fine cell of the probe and then as far as what that
//! found still leaves open ([`ProbeGrid::offer_narrowing`]). On a dense scan the first box finds
//! a point a millimetre away, and the second is the probe's own few cells, where a ball of 27
//! cells held thousands of points.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::cells::floor_i64;

mod clip;
mod coords;
mod fine;
use clip::Clip;
pub(crate) use coords::Coords;
pub use coords::Run;
use fine::{Fine, Ys};

/// A cylinder's box is cut column by column when it spans at most this many fine cells in y
/// (a cylinder ten times longer than wide spans 22).
const CLIP_ROWS: usize = 32;

/// Cells per axis are addressed with 21 bits, centred on the probes' bounds.
const AXIS_BITS: u32 = 21;
const AXIS_BIAS: i64 = 1 << (AXIS_BITS - 1);

/// A cell of at most this many fine cells gets a table of where each starts, per chunk (a
/// column's points are then two reads away); a larger one is searched.
const DENSE_FINE_CELLS: usize = 4096;
/// The tables of a chunk hold at most this many entries per point (plus a fixed 64 k).
const DENSE_ENTRIES_PER_POINT: usize = 16;

#[derive(Debug, Clone, Copy)]
struct Cell {
    key: u64,
    start: u32,
    end: u32,
}

/// The region around a probe in which a scan point can matter to it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Region {
    /// A ball of this radius.
    Ball(f64),
    /// A cylinder along the probe's normal, centred on the probe.
    Cylinder {
        /// Its radius.
        radius: f64,
        /// Half its length, along the normal each way.
        half_length: f64,
    },
    /// A ball of radius `reach` for a probe that keeps only what is nearest: its state narrows
    /// the box it is offered ([`ProbeGrid::offer_narrowing`]), searched in fine cells `fine`
    /// wide.
    Narrowing {
        /// The ball's radius.
        reach: f64,
        /// The fine cells' width.
        fine: f64,
    },
}

impl Region {
    /// The farthest a point of the region is from its probe.
    pub fn reach(self) -> f64 {
        match self {
            Region::Ball(r) => r,
            Region::Cylinder {
                radius,
                half_length,
            } => radius.hypot(half_length),
            Region::Narrowing { reach, .. } => reach,
        }
    }
}

/// Probes sorted by cell. Every per-probe array a caller keeps must follow [`ProbeGrid::ids`]
/// order, which is the order of [`ProbeGrid::points`].
pub struct ProbeGrid {
    region: Region,
    cell: f64,
    origin: Point3<f64>,
    points: Vec<Point3<f64>>,
    normals: Vec<Vector3<f64>>,
    ids: Vec<u32>,
    cells: Vec<Cell>,
    lookup: FxHashMap<u64, u32>,
    /// For cylinders: the fine cell's width, how many fine cells make a cell along each axis,
    /// and each probe's cylinder's bounding box half-widths, in grid order.
    fine: Option<Fine>,
}

/// Columns per cell side up to which a chunk keeps, per cell, which columns hold points: a
/// row of columns is a word's bits.
const ROW_BITS: i64 = 64;

/// A neighbour cell holding points of the chunk.
#[derive(Clone, Copy)]
struct Near {
    /// Its first fine cell.
    first: [i64; 3],
    /// Its run in the sorted points.
    start: usize,
    end: usize,
    /// Where its table of fine cells starts (dense chunks).
    table: usize,
    /// Where its rows of occupied columns start (dense chunks with rows).
    rows: usize,
}

/// A chunk sorted for the fine cells, as [`ProbeGrid::bucket_fine`] leaves it.
struct Bucketed<'a> {
    columned: &'a [(u64, u32, u32)],
    sorted: &'a Coords,
    starts: &'a [u32],
    dense: bool,
    /// With tables and at most [`ROW_BITS`] columns a side: per cell, per x, bit y set when
    /// column (x, y) holds points of the chunk. Empty otherwise.
    rows: &'a [u64],
}

/// Per-chunk buffers, sized by the largest chunk and the number of probe cells, and reused:
/// a stream of chunks no larger than the first allocates nothing new.
#[derive(Default)]
pub struct Scratch {
    keyed: Vec<(u64, u32)>,
    /// For cylinders: each point's cell, fine cell within it, and place in the chunk.
    columned: Vec<(u64, u32, u32)>,
    /// For cylinders: per occupied cell, where each of its fine cells starts in `sorted`
    /// (and one past the last), when a cell has few enough fine cells ([`DENSE_FINE_CELLS`]).
    starts: Vec<u32>,
    /// With the tables: per occupied cell, per x, the columns holding points (a bit per y).
    /// A scanner's chunk sweeps the whole part, so most of a box's columns hold none of it.
    rows: Vec<u64>,
    sorted: Coords,
    runs: FxHashMap<u64, (u32, u32, u32)>,
    active: Vec<u32>,
    /// Per probe cell, the chunk that last activated it.
    mark: Vec<u32>,
    generation: u32,
}

impl Scratch {
    /// Memory held, bytes.
    pub fn bytes(&self) -> usize {
        self.keyed.capacity() * size_of::<(u64, u32)>()
            + self.columned.capacity() * size_of::<(u64, u32, u32)>()
            + self.starts.capacity() * size_of::<u32>()
            + self.rows.capacity() * size_of::<u64>()
            + self.sorted.bytes()
            + self.runs.capacity() * (size_of::<u64>() + size_of::<(u32, u32, u32)>())
            + (self.active.capacity() + self.mark.capacity()) * size_of::<u32>()
    }
}

impl ProbeGrid {
    /// `reach` is the largest distance from a probe at which a scan point can matter.
    pub fn new(points: &[Point3<f64>], normals: &[Vector3<f64>], reach: f64) -> Self {
        Self::around(points, normals, Region::Ball(reach))
    }

    /// Probes that each care about the scan points in `region` around them (normals unit).
    pub fn around(points: &[Point3<f64>], normals: &[Vector3<f64>], region: Region) -> Self {
        assert_eq!(points.len(), normals.len(), "one normal per probe");
        let reach = region.reach();
        let (mut lo, mut hi) = (Point3::origin(), Point3::origin());
        if let Some(first) = points.first() {
            (lo, hi) = (*first, *first);
            for p in points {
                lo = lo.inf(p);
                hi = hi.sup(p);
            }
        }
        let extent = (hi - lo).max();
        // Keep the whole design plus a margin of cells addressable.
        let smallest = (extent / (AXIS_BIAS as f64 - 4.0)).max(f64::MIN_POSITIVE);
        // A cylinder's fine cells are as wide as its radius, a narrowing ball's as it asks, and
        // a whole number of them make a cell as wide as the reach (a fine cell's coordinates
        // then give its cell's).
        let cylinder = match region {
            Region::Cylinder {
                radius,
                half_length,
            } if radius < reach => Some((radius, half_length)),
            _ => None,
        };
        let fine = match region {
            Region::Narrowing { fine, .. } if fine > 0.0 && fine < reach => Some(fine),
            _ => cylinder.map(|(radius, _)| radius),
        }
        .map(|width| {
            width
                .max((extent + 2.0 * reach) / (AXIS_BIAS as f64 - 4.0))
                .max(f64::MIN_POSITIVE)
        });
        // Strictly wider than the reach, so that rounding never puts a point within reach two
        // cells away.
        let per_cell = fine.map_or(1, |f| (reach / f).floor() as i64 + 1);
        // A fine cell's index within its cell is a u32: a cylinder over 1600 times longer than
        // wide is searched as a ball.
        let (fine, per_cell) = match fine {
            Some(_) if per_cell.checked_pow(3).is_none_or(|c| c >= u32::MAX as i64) => (None, 1),
            _ => (fine, per_cell),
        };
        let cell = match fine {
            Some(f) => f * per_cell as f64,
            None => reach.max(smallest),
        };
        let origin = Point3::from((lo.coords + hi.coords) * 0.5);
        let mut grid = Self {
            region,
            cell,
            origin,
            points: Vec::new(),
            normals: Vec::new(),
            ids: Vec::new(),
            cells: Vec::new(),
            lookup: FxHashMap::default(),
            fine: None,
        };
        if let Some(width) = fine {
            // Set now: probes and points find their cells the same way, through fine cells.
            grid.fine = Some(Fine::new(width, per_cell));
        }
        let mut keyed: Vec<(u64, u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                (
                    grid.key(p).expect("probes lie inside their own grid"),
                    i as u32,
                )
            })
            .collect();
        keyed.sort_unstable();
        grid.points = keyed.iter().map(|&(_, i)| points[i as usize]).collect();
        grid.normals = keyed.iter().map(|&(_, i)| normals[i as usize]).collect();
        grid.ids = keyed.iter().map(|&(_, i)| i).collect();
        for (key, start, end) in runs_of(&keyed) {
            grid.lookup.insert(key, grid.cells.len() as u32);
            grid.cells.push(Cell { key, start, end });
        }
        if let (Some(f), Some((radius, half_length))) = (grid.fine.as_mut(), cylinder) {
            // Along axis k a cylinder reaches h·|n_k| with its axis and r·√(1 − n_k²) with its
            // disc; a hair more, so that rounding cannot leave a point of its rim outside.
            let pad = reach * 1e-9;
            f.half_box = grid
                .normals
                .iter()
                .map(|n| {
                    n.map(|c| half_length * c.abs() + radius * (1.0 - c * c).max(0.0).sqrt() + pad)
                })
                .collect();
        }
        grid
    }

    /// Probes in the grid.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the grid holds no probe.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The probes' positions, in grid order.
    pub fn points(&self) -> &[Point3<f64>] {
        &self.points
    }

    /// The probes' unit normals, in grid order.
    pub fn normals(&self) -> &[Vector3<f64>] {
        &self.normals
    }

    /// The caller's index of each probe, in grid order.
    pub fn ids(&self) -> &[u32] {
        &self.ids
    }

    /// Memory held, bytes.
    pub fn bytes(&self) -> usize {
        self.points.capacity() * size_of::<Point3<f64>>()
            + self.normals.capacity() * size_of::<Vector3<f64>>()
            + self.ids.capacity() * size_of::<u32>()
            + self.cells.capacity() * size_of::<Cell>()
            + self.lookup.capacity() * (size_of::<u64>() + size_of::<u32>())
            + self
                .fine
                .as_ref()
                .map_or(0, |f| f.half_box.capacity() * size_of::<Vector3<f64>>())
    }

    /// `p`'s cell coordinates in cells `width` wide; `None` for a point far outside the
    /// design (or not finite).
    #[inline]
    fn coords_at(&self, p: &Point3<f64>, width: f64) -> Option<[i64; 3]> {
        let v = self.scaled(p, width);
        let mut c = [0i64; 3];
        for k in 0..3 {
            // floor(v) > -BIAS + 2 and floor(v) < BIAS - 2, asked of v itself. NaN fails both
            // comparisons and is refused with the far points.
            if !(v[k] >= -(AXIS_BIAS as f64) + 3.0 && v[k] < AXIS_BIAS as f64 - 2.0) {
                return None;
            }
            c[k] = floor_i64(v[k]);
        }
        Some(c)
    }

    /// `p` in units of `width` from the grid's origin: what [`Self::coords_at`] floors.
    #[inline]
    fn scaled(&self, p: &Point3<f64>, width: f64) -> [f64; 3] {
        let o = &self.origin;
        [
            (p.x - o.x) / width,
            (p.y - o.y) / width,
            (p.z - o.z) / width,
        ]
    }

    /// A cylinder's probe's cut of its box column by column; `None` for other regions.
    #[inline]
    fn clip(&self, fine: &Fine, p: &Point3<f64>, n: &Vector3<f64>) -> Option<Clip> {
        let Region::Cylinder {
            radius,
            half_length,
        } = self.region
        else {
            return None;
        };
        Some(Clip::new(
            self.scaled(p, fine.width),
            n,
            radius / fine.width,
            half_length / fine.width,
        ))
    }

    #[inline]
    fn pack(c: [i64; 3]) -> u64 {
        let f = |v: i64| (v + AXIS_BIAS) as u64;
        (f(c[0]) << (2 * AXIS_BITS)) | (f(c[1]) << AXIS_BITS) | f(c[2])
    }

    #[inline]
    fn unpack(key: u64) -> [i64; 3] {
        let m = (1u64 << AXIS_BITS) - 1;
        [
            ((key >> (2 * AXIS_BITS)) & m) as i64 - AXIS_BIAS,
            ((key >> AXIS_BITS) & m) as i64 - AXIS_BIAS,
            (key & m) as i64 - AXIS_BIAS,
        ]
    }

    #[inline]
    fn key(&self, p: &Point3<f64>) -> Option<u64> {
        match &self.fine {
            Some(f) => self.coords_at(p, f.width).map(|c| Self::pack(f.cell_of(c))),
            None => self.coords_at(p, self.cell).map(Self::pack),
        }
    }

    fn neighbours(key: u64) -> impl Iterator<Item = u64> {
        let c = Self::unpack(key);
        (0..27).map(move |i| {
            let d = [i % 3 - 1, (i / 3) % 3 - 1, i / 9 - 1];
            Self::pack([c[0] + d[0], c[1] + d[1], c[2] + d[2]])
        })
    }

    /// A new chunk of `points`: the buffers emptied, and a new mark for the probe cells it
    /// activates.
    fn restart(&self, scratch: &mut Scratch, points: usize) {
        let Scratch {
            keyed,
            columned,
            sorted,
            runs,
            starts,
            rows,
            active,
            mark,
            generation,
        } = scratch;
        if mark.len() != self.cells.len() {
            *mark = vec![0; self.cells.len()];
            *generation = 0;
        }
        *generation = generation.wrapping_add(1);
        if *generation == 0 {
            mark.fill(0);
            *generation = 1;
        }
        keyed.clear();
        columned.clear();
        sorted.clear();
        runs.clear();
        starts.clear();
        rows.clear();
        active.clear();
        sorted.reserve(points);
        active.reserve(self.cells.len());
    }

    /// Marks active the probe cells next to the point cell `key`, once a chunk.
    fn activate(&self, key: u64, mark: &mut [u32], generation: u32, active: &mut Vec<u32>) {
        for k in Self::neighbours(key) {
            if let Some(&c) = self.lookup.get(&k)
                && mark[c as usize] != generation
            {
                mark[c as usize] = generation;
                active.push(c);
            }
        }
    }

    /// The active cells (sorted) with their probes' states: cells are sorted by key and hold
    /// consecutive probes, so they cut `state` into disjoint slices in order.
    fn jobs<'a, S>(&'a self, active: &[u32], state: &'a mut [S]) -> Vec<(&'a Cell, &'a mut [S])> {
        let mut jobs = Vec::with_capacity(active.len());
        let mut rest = state;
        let mut offset = 0usize;
        for &c in active {
            let cell = &self.cells[c as usize];
            let (_, tail) = rest.split_at_mut(cell.start as usize - offset);
            let (mine, tail) = tail.split_at_mut((cell.end - cell.start) as usize);
            jobs.push((cell, mine));
            rest = tail;
            offset = cell.end as usize;
        }
        jobs
    }

    /// Offers `chunk` to every probe: `visit(offset, normal, state)` runs for each point in the
    /// probe's cell and its neighbours, with the point's offset from the probe (some beyond the
    /// reach: the visitor applies its own test). `state` holds one entry per probe in grid
    /// order. Non-finite points and points far outside the design are never offered.
    pub fn offer<S, F>(
        &self,
        scratch: &mut Scratch,
        state: &mut [S],
        chunk: &[Point3<f64>],
        visit: F,
    ) where
        S: Send,
        F: Fn(Vector3<f64>, &Vector3<f64>, &mut S) + Sync,
    {
        self.offer_slices(scratch, state, chunk, each_point(visit));
    }

    /// [`Self::offer`] a run of points at a time: `visit(probe, normal, points, state)`, the
    /// points in the order [`Self::offer`] gives them. A visitor that tests many points can then
    /// test them without a branch per point.
    pub fn offer_slices<S, F>(
        &self,
        scratch: &mut Scratch,
        state: &mut [S],
        chunk: &[Point3<f64>],
        visit: F,
    ) where
        S: Send,
        F: Fn(&Point3<f64>, &Vector3<f64>, Run<'_>, &mut S) + Sync,
    {
        assert_eq!(state.len(), self.points.len(), "one state per probe");
        if let Some(fine) = &self.fine {
            return match self.region {
                // Offered as a ball: the box of the whole reach.
                Region::Narrowing { reach, .. } => {
                    let whole = Vector3::repeat(reach * (1.0 + 1e-9));
                    self.offer_fine(fine, scratch, state, chunk, |_, _, _| whole, false, visit)
                }
                _ => {
                    let boxes = |i: usize, _: &Vector3<f64>, _: &S| fine.half_box[i];
                    self.offer_fine(fine, scratch, state, chunk, boxes, false, visit)
                }
            };
        }
        self.restart(scratch, chunk.len());
        let Scratch {
            keyed,
            sorted,
            runs,
            active,
            mark,
            generation,
            ..
        } = scratch;
        keyed.reserve(chunk.len());
        runs.reserve(chunk.len());
        keyed.extend(
            chunk
                .iter()
                .enumerate()
                .filter_map(|(i, p)| self.key(p).map(|k| (k, i as u32))),
        );
        keyed.sort_unstable();
        sorted.extend(keyed.iter().map(|&(_, i)| &chunk[i as usize]));
        for (key, start, end) in runs_of(keyed) {
            runs.insert(key, (start, end, 0));
            self.activate(key, mark, *generation, active);
        }
        active.sort_unstable();

        let jobs = self.jobs(active, state);
        let (sorted, runs) = (&*sorted, &*runs);
        jobs.into_par_iter().for_each(|(cell, states)| {
            for nk in Self::neighbours(cell.key) {
                let Some(&(s, e, _)) = runs.get(&nk) else {
                    continue;
                };
                let pts = sorted.run(s as usize..e as usize);
                let range = cell.start as usize..cell.end as usize;
                for ((p, n), st) in self.points[range.clone()]
                    .iter()
                    .zip(&self.normals[range])
                    .zip(states.iter_mut())
                {
                    visit(p, n, pts, st);
                }
            }
        });
    }

    /// Offers `chunk` to probes that keep only what is nearest ([`Region::Narrowing`]): a probe
    /// is offered the points in the box `bound(normal, state)` gives (half-widths around the
    /// probe, at most the reach), first cut to one fine cell's width, then whole as that first
    /// box's points leave it, a run at a time as [`Self::offer_slices`] gives them. A point may
    /// be offered to a probe twice: `visit` must keep what it keeps by a rule a repeat cannot
    /// change (a minimum, an or). Any other grid offers as [`Self::offer_slices`] does.
    pub fn offer_narrowing<S, F, B>(
        &self,
        scratch: &mut Scratch,
        state: &mut [S],
        chunk: &[Point3<f64>],
        bound: B,
        visit: F,
    ) where
        S: Send,
        F: Fn(&Point3<f64>, &Vector3<f64>, Run<'_>, &mut S) + Sync,
        B: Fn(&Vector3<f64>, &S) -> Vector3<f64> + Sync,
    {
        match (&self.fine, self.region) {
            (Some(fine), Region::Narrowing { .. }) => {
                assert_eq!(state.len(), self.points.len(), "one state per probe");
                let boxes = |_: usize, n: &Vector3<f64>, s: &S| bound(n, s);
                self.offer_fine(fine, scratch, state, chunk, boxes, true, visit);
            }
            _ => self.offer_slices(scratch, state, chunk, visit),
        }
    }

    /// [`Self::offer`] in fine cells. A chunk's points are sorted by cell, then by fine cell
    /// within it (x, then y, then z), then chunk order. A probe takes, in each of its cell's 27
    /// neighbours, the fine cells its box (`bound(probe, normal, state)`) touches, a column along
    /// z at a time, and visits their points; `narrowing`, a box cut to a fine cell first.
    #[allow(clippy::too_many_arguments)]
    fn offer_fine<S, F, B>(
        &self,
        fine: &Fine,
        scratch: &mut Scratch,
        state: &mut [S],
        chunk: &[Point3<f64>],
        bound: B,
        narrowing: bool,
        visit: F,
    ) where
        S: Send,
        F: Fn(&Point3<f64>, &Vector3<f64>, Run<'_>, &mut S) + Sync,
        B: Fn(usize, &Vector3<f64>, &S) -> Vector3<f64> + Sync,
    {
        let dense = self.bucket_fine(fine, scratch, chunk);
        let Scratch {
            columned,
            sorted,
            runs,
            starts,
            rows,
            active,
            ..
        } = scratch;
        let jobs = self.jobs(active, state);
        let m = fine.per_cell;
        let bucketed = Bucketed {
            columned,
            sorted,
            starts,
            dense,
            rows,
        };
        let fine_cells = (m * m * m) as usize;
        let first_cut = Vector3::repeat(fine.width);
        let runs = &*runs;
        jobs.into_par_iter().for_each(|(cell, states)| {
            // The neighbours holding points, with their first fine cell.
            let near: Vec<Near> = Self::neighbours(cell.key)
                .filter_map(|k| {
                    let &(start, end, table) = runs.get(&k)?;
                    Some(Near {
                        first: Self::unpack(k).map(|v| v * m),
                        start: start as usize,
                        end: end as usize,
                        table: table as usize,
                        // The tables and the rows follow the cells in one order.
                        rows: table as usize / (fine_cells + 1) * m as usize,
                    })
                })
                .collect();
            let range = cell.start as usize..cell.end as usize;
            for (((i, p), n), st) in range
                .clone()
                .zip(&self.points[range.clone()])
                .zip(&self.normals[range])
                .zip(states.iter_mut())
            {
                let e = bound(i, n, st);
                if narrowing {
                    let first = e.inf(&first_cut);
                    let at_first = |qs: Run<'_>| visit(p, n, qs, st);
                    self.visit_box(fine, &bucketed, &near, (p, &first), None, at_first);
                    let e = bound(i, n, st);
                    if e.iter().zip(&first).any(|(a, b)| a > b) {
                        self.visit_box(fine, &bucketed, &near, (p, &e), None, |qs| {
                            visit(p, n, qs, st);
                        });
                    }
                } else {
                    let clip = self.clip(fine, p, n);
                    self.visit_box(fine, &bucketed, &near, (p, &e), clip.as_ref(), |qs| {
                        visit(p, n, qs, st);
                    });
                }
            }
        });
    }

    /// Visits the points of a chunk's fine cells that the box of half-widths `e` around `p`
    /// touches (each column cut to the heights `clip` leaves), in the cells `near`, a stretch
    /// of the laid-out chunk at a time: a column's fine cells, or several columns where they
    /// follow each other in the layout (a box that spans a cell's height).
    #[inline]
    fn visit_box(
        &self,
        fine: &Fine,
        chunk: &Bucketed,
        near: &[Near],
        (p, e): (&Point3<f64>, &Vector3<f64>),
        clip: Option<&Clip>,
        mut visit: impl FnMut(Run<'_>),
    ) {
        let m = fine.per_cell;
        let (Some(lo), Some(hi)) = (
            self.coords_at(&(p - e), fine.width),
            self.coords_at(&(p + e), fine.width),
        ) else {
            return;
        };
        // The columns' y bounds on the cylinder's t, once for the box: its cells stack in z.
        let mut ty = [(0.0, 0.0); CLIP_ROWS];
        let clip = clip.filter(|_| hi[1] - lo[1] < CLIP_ROWS as i64);
        if let Some(c) = clip {
            for y in lo[1]..=hi[1] {
                ty[(y - lo[1]) as usize] = c.slab(1, y);
            }
        }
        let first_row = lo[1];
        let mut pending = 0..0;
        for near in near {
            let first = near.first;
            let lo = [0, 1, 2].map(|k| lo[k].max(first[k]));
            let hi = [0, 1, 2].map(|k| hi[k].min(first[k] + m - 1));
            if (0..3).any(|k| lo[k] > hi[k]) {
                continue;
            }
            let run = &chunk.columned[near.start..near.end];
            let mut from = 0;
            for x in lo[0]..=hi[0] {
                // The column's x bound on t, once for its y's.
                let cut = clip.map(|c| (c, c.slab(0, x)));
                let ys = if chunk.rows.is_empty() {
                    Ys::Range(lo[1]..=hi[1])
                } else {
                    // Only the columns holding points, in the same order.
                    let box_ys =
                        (u64::MAX >> (ROW_BITS - (hi[1] - lo[1] + 1))) << (lo[1] - first[1]);
                    Ys::Bits {
                        row: chunk.rows[near.rows + (x - first[0]) as usize] & box_ys,
                        first: first[1],
                    }
                };
                for y in ys {
                    let (z0, z1) = match cut {
                        Some((c, tx)) => {
                            match c.heights(tx, ty[(y - first_row) as usize], lo[2], hi[2]) {
                                Some(z) => z,
                                None => continue,
                            }
                        }
                        None => (lo[2], hi[2]),
                    };
                    let column = ((x - first[0]) * m + (y - first[1])) * m - first[2];
                    let (a, b) = ((column + z0) as usize, (column + z1) as usize);
                    // The fine cells a..=b of this column are one stretch of the run.
                    let points = if chunk.dense {
                        let table = near.table;
                        chunk.starts[table + a] as usize..chunk.starts[table + b + 1] as usize
                    } else {
                        from += run[from..].partition_point(|t| (t.1 as usize) < a);
                        let to = from + run[from..].partition_point(|t| t.1 as usize <= b);
                        let points = near.start + from..near.start + to;
                        from = to;
                        points
                    };
                    if points.is_empty() {
                        continue;
                    }
                    if points.start == pending.end {
                        pending.end = points.end;
                    } else {
                        if !pending.is_empty() {
                            visit(chunk.sorted.run(pending));
                        }
                        pending = points;
                    }
                }
            }
        }
        if !pending.is_empty() {
            visit(chunk.sorted.run(pending));
        }
    }

    /// Sorts a chunk for [`Self::offer_fine`]: its points by cell and fine cell, each occupied
    /// cell's run, and the probe cells it activates. Returns whether each run has its table of
    /// where its fine cells start: only while the tables stay within a few entries per point
    /// of the chunk, so memory follows the chunk, never its spread.
    fn bucket_fine(&self, fine: &Fine, scratch: &mut Scratch, chunk: &[Point3<f64>]) -> bool {
        self.restart(scratch, chunk.len());
        let m = fine.per_cell;
        let columned = &mut scratch.columned;
        columned.reserve(chunk.len());
        for (i, p) in chunk.iter().enumerate() {
            if let Some(f) = self.coords_at(p, fine.width) {
                let (c, local) = fine.split(f);
                columned.push((Self::pack(c), local, i as u32));
            }
        }
        // The occupied cells and their points, counted in `runs` (a scan's chunk keeps to a few
        // cells at a time, so the last one found is tried first).
        let runs = &mut scratch.runs;
        let mut last: Option<(u64, u32)> = None;
        for &(key, _, _) in columned.iter() {
            match &mut last {
                Some((k, n)) if *k == key => *n += 1,
                _ => {
                    if let Some((k, n)) = last {
                        runs.entry(k).or_default().1 += n;
                    }
                    last = Some((key, 1));
                }
            }
        }
        if let Some((k, n)) = last {
            runs.entry(k).or_default().1 += n;
        }
        let mut keys: Vec<u64> = runs.keys().copied().collect();
        keys.sort_unstable();
        let fine_cells = (m * m * m) as usize;
        let dense = fine_cells <= DENSE_FINE_CELLS
            && keys.len() * (fine_cells + 1) <= DENSE_ENTRIES_PER_POINT * chunk.len() + (1 << 16);
        if dense {
            self.count_fine(fine, scratch, &keys, chunk);
        } else {
            self.sort_fine(scratch, chunk);
        }
        for key in keys {
            self.activate(
                key,
                &mut scratch.mark,
                scratch.generation,
                &mut scratch.active,
            );
        }
        scratch.active.sort_unstable();
        dense
    }

    /// Lays a chunk's points out by cell (in key order), fine cell, then chunk order, with each
    /// cell's table of where its fine cells start: a counting sort, as `runs` counted the cells.
    ///
    /// The tables serve as the sort's cursors too, one place ahead: fine cell l is counted at
    /// l + 2 and summed, so that its cursor at l + 1 holds where it starts; laying out its points
    /// moves the cursor to where l + 1 starts, which is the table. A copy of the tables as
    /// cursors cost as much again in memory and a copy per chunk.
    fn count_fine(&self, fine: &Fine, scratch: &mut Scratch, keys: &[u64], chunk: &[Point3<f64>]) {
        let m = fine.per_cell as usize;
        let fine_cells = m * m * m;
        let Scratch {
            columned,
            starts,
            sorted,
            runs,
            rows,
            ..
        } = scratch;
        let mut start = 0u32;
        for (c, key) in keys.iter().enumerate() {
            let run = runs.get_mut(key).expect("counted");
            let n = run.1;
            *run = (start, start + n, (c * (fine_cells + 1)) as u32);
            start += n;
        }
        // One more than the tables: the last fine cell of the last table counts there. A last
        // fine cell's count starts nothing, and in any other table it lands on the next
        // table's first entry, which is set below.
        let tables = keys.len() * (fine_cells + 1);
        starts.resize(tables + 1, 0);
        let table_of = |key: u64, cached: &mut (u64, usize)| {
            if cached.0 != key || cached.1 == usize::MAX {
                *cached = (key, runs[&key].2 as usize);
            }
            cached.1
        };
        let mut cached = (0, usize::MAX);
        for &(key, local, _) in columned.iter() {
            starts[table_of(key, &mut cached) + local as usize + 2] += 1;
        }
        starts.truncate(tables);
        for key in keys {
            let (first, _, table) = runs[key];
            let table = &mut starts[table as usize..table as usize + fine_cells + 1];
            table[0] = first;
            table[1] = first;
            for j in 2..table.len() {
                table[j] += table[j - 1];
            }
        }
        sorted.resize(columned.len());
        // The three columns as slices, so that their bounds stay in registers: through the
        // vectors, every store reloaded them.
        let (xs, ys, zs) = sorted.columns_mut();
        let cursors = starts.as_mut_slice();
        let mut cached = (0, usize::MAX);
        for &(key, local, i) in columned.iter() {
            let slot = &mut cursors[table_of(key, &mut cached) + local as usize + 1];
            let (p, at) = (&chunk[i as usize], *slot as usize);
            (xs[at], ys[at], zs[at]) = (p.x, p.y, p.z);
            *slot += 1;
        }
        if m as i64 <= ROW_BITS {
            // A column's fine cells are m in a row of the table: it holds points when its
            // first start differs from the next column's.
            rows.reserve(keys.len() * m);
            for table in starts.chunks_exact(fine_cells + 1) {
                for x in 0..m {
                    let mut row = 0u64;
                    for y in 0..m {
                        let c = (x * m + y) * m;
                        row |= u64::from(table[c] != table[c + m]) << y;
                    }
                    rows.push(row);
                }
            }
        }
    }

    /// Lays a chunk's points out by cell, fine cell, then chunk order, by sorting them: for
    /// cells with too many fine cells for tables, whose runs are then searched.
    fn sort_fine(&self, scratch: &mut Scratch, chunk: &[Point3<f64>]) {
        let Scratch {
            columned,
            sorted,
            runs,
            ..
        } = scratch;
        columned.sort_unstable();
        sorted.extend(columned.iter().map(|&(_, _, i)| &chunk[i as usize]));
        let mut start = 0u32;
        for run in columned.chunk_by(|a, b| a.0 == b.0) {
            runs.insert(run[0].0, (start, start + run.len() as u32, 0));
            start += run.len() as u32;
        }
    }
}

/// A visitor of runs that hands `visit` each point of a run in order, as its offset from the
/// probe.
fn each_point<S>(
    visit: impl Fn(Vector3<f64>, &Vector3<f64>, &mut S) + Sync,
) -> impl Fn(&Point3<f64>, &Vector3<f64>, Run<'_>, &mut S) + Sync {
    move |p, n, run, st| {
        for q in run.iter() {
            visit(q - p, n, st);
        }
    }
}

/// The runs of equal keys in a key-sorted list: key, first index, one past the last.
fn runs_of(keyed: &[(u64, u32)]) -> impl Iterator<Item = (u64, u32, u32)> + '_ {
    keyed.chunk_by(|a, b| a.0 == b.0).scan(0u32, |start, run| {
        let s = *start;
        *start += run.len() as u32;
        Some((run[0].0, s, *start))
    })
}

#[cfg(test)]
mod tests {
    use super::fine::Divide;
    use super::*;
    use crate::test_points::{random_points, seeded};
    use rand::Rng;

    #[test]
    fn fine_cells_divide_as_integers_do() {
        let mut rng = seeded(11);
        let edges = [
            -AXIS_BIAS,
            -AXIS_BIAS + 1,
            -1,
            0,
            1,
            AXIS_BIAS - 1,
            AXIS_BIAS,
        ];
        for m in 1..1 << 11 {
            let d = Divide::new(m);
            let near = [-m - 1, -m, -m + 1, m - 1, m, m + 1];
            let random = (0..50).map(|_| rng.random_range(-AXIS_BIAS..=AXIS_BIAS));
            for v in edges.into_iter().chain(near).chain(random) {
                assert_eq!(d.split(v), (v.div_euclid(m), v.rem_euclid(m)), "{v} / {m}");
            }
        }
        let fine = Fine::new(0.5, 7);
        for c in [[-8, 0, 13], [6, -7, -1], [0, 0, 0]] {
            let (cell, local) = fine.split(c);
            assert_eq!(cell, c.map(|v| v.div_euclid(7)));
            assert_eq!(fine.cell_of(c), cell);
            let r = c.map(|v| v.rem_euclid(7));
            assert_eq!(local as i64, (r[0] * 7 + r[1]) * 7 + r[2]);
        }
    }

    #[test]
    fn every_point_within_reach_is_offered_to_every_probe_exactly_once() {
        let mut rng = seeded(3);
        let probes = random_points(&mut rng, 500, 0.0..1.0);
        let normals = vec![Vector3::z(); probes.len()];
        let reach = 0.15;
        let grid = ProbeGrid::new(&probes, &normals, reach);
        let points: Vec<Point3<f64>> = random_points(&mut rng, 3000, -0.2..1.2)
            .into_iter()
            .chain([Point3::new(f64::NAN, 0.0, 0.0), Point3::new(1e12, 0.0, 0.0)])
            .collect();
        let mut state = vec![0u32; grid.len()];
        let mut scratch = Scratch::default();
        for chunk in points.chunks(700) {
            grid.offer(&mut scratch, &mut state, chunk, |v, _, s| {
                *s += u32::from(v.norm() <= reach);
            });
        }
        for (i, &id) in grid.ids().iter().enumerate() {
            let p = probes[id as usize];
            assert_eq!(grid.points()[i], p);
            let truth = points.iter().filter(|q| (*q - p).norm() <= reach).count() as u32;
            assert_eq!(state[i], truth, "probe {id}");
        }
    }

    /// 400 probes in the unit cube, along random unit normals (a degenerate one along x).
    fn probes_facing_anywhere(rng: &mut impl rand::Rng) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
        let probes = random_points(rng, 400, 0.0..1.0);
        let normals = random_points(rng, probes.len(), -1.0..1.0)
            .into_iter()
            .map(|p| p.coords.try_normalize(1e-6).unwrap_or(Vector3::x()))
            .chain([Vector3::x(), Vector3::y(), Vector3::z()])
            .take(probes.len())
            .collect();
        (probes, normals)
    }

    /// The counting sort lays a chunk out as sorting it does: cells in key order, fine cells,
    /// then chunk order (the order M3C2's sums are taken in), with the same runs.
    #[test]
    fn counting_lays_points_out_as_sorting_does() {
        let mut rng = seeded(8);
        let probes = random_points(&mut rng, 300, 0.0..1.0);
        let normals = vec![Vector3::z(); probes.len()];
        let region = Region::Cylinder {
            radius: 0.02,
            half_length: 0.1,
        };
        let grid = ProbeGrid::around(&probes, &normals, region);
        let fine = grid.fine.as_ref().unwrap();
        let mut points = random_points(&mut rng, 20_000, -0.1..1.1);
        // Repeats, so that fine cells hold points whose order only the chunk gives.
        points.extend(points[..5000].to_vec());
        points.push(Point3::new(f64::NAN, 0.0, 0.0));
        let mut counted = Scratch::default();
        assert!(
            grid.bucket_fine(fine, &mut counted, &points),
            "dense tables"
        );
        let mut sorted = Scratch::default();
        grid.restart(&mut sorted, points.len());
        sorted.columned = counted.columned.clone();
        grid.sort_fine(&mut sorted, &points);
        assert_eq!(counted.sorted, sorted.sorted);
        for (key, (s, e, _)) in &sorted.runs {
            let (cs, ce, table) = counted.runs[key];
            assert_eq!((cs, ce), (*s, *e));
            let m = fine.per_cell as usize;
            let table = &counted.starts[table as usize..][..m * m * m + 1];
            assert_eq!((table[0], table[m * m * m]), (cs, ce));
            let run = &sorted.columned[*s as usize..*e as usize];
            for (local, &start) in table[..m * m * m].iter().enumerate() {
                let first = run.partition_point(|t| (t.1 as usize) < local);
                assert_eq!(start, s + first as u32, "fine cell {local}");
            }
        }
    }

    /// What a sample keeps of the points it is offered: the nearest (a tie to the larger offset
    /// along the normal) and whether one lies on its normal line, within `t` of it.
    #[derive(Debug, Clone, Copy, PartialEq)]
    struct Nearest {
        d2: f64,
        along: f64,
        buried: bool,
        offers: u32,
    }

    fn keep(st: &mut Nearest, v: Vector3<f64>, n: &Vector3<f64>, reach: f64, t: f64) {
        st.offers += 1;
        let d2 = v.norm_squared();
        if d2 <= reach * reach {
            let along = v.dot(n);
            if d2 < st.d2 || (d2 == st.d2 && along > st.along) {
                (st.d2, st.along) = (d2, along);
            }
            st.buried |= along > 0.0 && d2 - along * along <= t * t;
        }
    }

    /// Narrowing probes keep, over chunks large and small, exactly what brute force over every
    /// point keeps: the same nearest point (ties included: points are repeated, and some stand
    /// at one distance from a probe), the same buried flag; while offered a small share of the
    /// points. Fine cells with tables and without.
    #[test]
    fn narrowing_probes_keep_what_every_point_gives() {
        for (reach, fine, chunk) in [(0.1, 0.01, 700), (0.1, 0.01, 20_000), (0.1, 0.002, 20_000)] {
            let t = 0.004;
            let mut rng = seeded(11);
            let (probes, normals) = probes_facing_anywhere(&mut rng);
            let region = Region::Narrowing { reach, fine };
            let grid = ProbeGrid::around(&probes, &normals, region);
            // Sparse points everywhere, a dense patch, repeats, points at one distance from a
            // probe, and points on a few probes' normal lines.
            let mut points = random_points(&mut rng, 30_000, -0.2..1.2);
            points.extend(random_points(&mut rng, 20_000, 0.4..0.5));
            points.extend(points[..2000].to_vec());
            for (p, n) in probes.iter().zip(&normals).take(40) {
                let side = n.cross(&Vector3::new(0.3, -0.7, 0.2)).normalize();
                points.push(p + n * 0.05 + side * (t * 0.99));
                points.push(p + side * 0.02);
                points.push(p - side * 0.02);
                points.push(p + n * 0.02);
            }
            points.extend([Point3::new(f64::NAN, 0.0, 0.0), Point3::new(1e12, 0.0, 0.0)]);
            let none = Nearest {
                d2: f64::INFINITY,
                along: 0.0,
                buried: false,
                offers: 0,
            };
            let mut state = vec![none; grid.len()];
            let mut scratch = Scratch::default();
            let pad = reach * 1e-9;
            for c in points.chunks(chunk) {
                let bound = |n: &Vector3<f64>, st: &Nearest| {
                    let ball = Vector3::repeat(st.d2.sqrt().min(reach) + pad);
                    if st.buried {
                        return ball;
                    }
                    let line = n.map(|c| reach * c.abs() + t * (1.0 - c * c).max(0.0).sqrt());
                    ball.sup(&line.add_scalar(pad))
                };
                let visit = each_point(|v, n, st: &mut Nearest| keep(st, v, n, reach, t));
                grid.offer_narrowing(&mut scratch, &mut state, c, bound, visit);
            }
            let mut offered = 0u64;
            for (i, &id) in grid.ids().iter().enumerate() {
                let (p, n) = (probes[id as usize], normals[id as usize]);
                let mut truth = none;
                for q in points.iter().filter(|q| q.iter().all(|c| c.is_finite())) {
                    keep(&mut truth, q - p, &n, reach, t);
                }
                let got = state[i];
                assert_eq!(
                    (got.d2, got.along, got.buried),
                    (truth.d2, truth.along, truth.buried),
                    "probe {id}, fine {fine}, chunk {chunk}"
                );
                offered += u64::from(got.offers);
            }
            assert!(
                offered < (points.len() * probes.len()) as u64 / 50,
                "{offered} offers, fine {fine}, chunk {chunk}"
            );
        }
    }

    /// Cylinders along random unit normals: every point inside a probe's cylinder is offered
    /// to it exactly once (none missed, none twice), as brute force over all points finds;
    /// points on the cylinder's rim and end caps count. Short and long cylinders, small and
    /// large chunks: the fine cells' tables and their search both serve.
    #[test]
    fn every_point_inside_a_cylinder_is_offered_to_its_probe_exactly_once() {
        for (radius, half_length, chunk) in [
            (0.03, 0.12, 1500),
            (0.03, 0.12, 30_000),
            (0.005, 0.12, 30_000),
        ] {
            cylinders_offer_what_brute_force_finds(radius, half_length, chunk);
        }
    }

    fn cylinders_offer_what_brute_force_finds(radius: f64, half_length: f64, chunk: usize) {
        let mut rng = seeded(5);
        let (probes, normals) = probes_facing_anywhere(&mut rng);
        let inside = |v: Vector3<f64>, n: &Vector3<f64>| {
            let a = v.dot(n);
            a.abs() <= half_length && v.norm_squared() - a * a <= radius * radius
        };
        let grid = ProbeGrid::around(
            &probes,
            &normals,
            Region::Cylinder {
                radius,
                half_length,
            },
        );
        let mut points: Vec<Point3<f64>> = random_points(&mut rng, 60_000, -0.2..1.2);
        // Points on the rims and caps of a few cylinders, all round, at both ends and between:
        // where a cylinder reaches farthest along each axis, which the columns' cut must keep.
        for (p, n) in probes.iter().zip(&normals).take(50) {
            let a = n.cross(&Vector3::new(0.3, -0.7, 0.2)).normalize();
            let b = n.cross(&a);
            points.push(p - n * half_length);
            for k in 0..32 {
                let angle = f64::from(k) * std::f64::consts::TAU / 32.0;
                let side = (a * angle.cos() + b * angle.sin()) * radius;
                for t in [
                    -half_length,
                    -0.4 * half_length,
                    0.0,
                    0.7 * half_length,
                    half_length,
                ] {
                    points.push(p + n * t + side);
                }
            }
        }
        points.extend([Point3::new(f64::NAN, 0.0, 0.0), Point3::new(1e12, 0.0, 0.0)]);
        let mut state = vec![(0u32, 0u32); grid.len()];
        let mut scratch = Scratch::default();
        for chunk in points.chunks(chunk) {
            grid.offer(&mut scratch, &mut state, chunk, |v, n, s| {
                s.0 += u32::from(inside(v, n));
                s.1 += 1;
            });
        }
        let mut offered = 0u64;
        for (i, &id) in grid.ids().iter().enumerate() {
            let (p, n) = (probes[id as usize], normals[id as usize]);
            assert_eq!(grid.normals()[i], n);
            let truth = points.iter().filter(|q| inside(*q - p, &n)).count() as u32;
            assert_eq!(
                state[i].0, truth,
                "probe {id}, radius {radius}, chunk {chunk}"
            );
            offered += u64::from(state[i].1);
        }
        // The fine cells keep the offers near the cylinders: a small share of all pairs.
        assert!(
            offered < (points.len() * probes.len()) as u64 / 20,
            "{offered}"
        );
        // Scratch stays within the tables' bound for the largest chunk.
        assert!(scratch.starts.len() <= DENSE_ENTRIES_PER_POINT * chunk + (1 << 16));
    }
}
