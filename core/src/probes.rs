//! Fixed probes on the design (samples or core points) meeting a stream of scan points.
//!
//! Reverse C2C and streaming M3C2 both ask, for every probe, about the scan points within a
//! fixed reach of it. The probes are bucketed once into cubic cells as wide as that reach; each
//! chunk of scan points is bucketed into the same cells, and every probe cell next to an occupied
//! point cell visits the points of its 27 neighbours. Each probe's state is touched by one task
//! only, so cells run in parallel without locks, and the result does not depend on how the scan
//! is cut into chunks. State is per probe; the only per-point memory is the chunk's own scratch.

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// Cells per axis are addressed with 21 bits, centred on the probes' bounds.
const AXIS_BITS: u32 = 21;
const AXIS_BIAS: i64 = 1 << (AXIS_BITS - 1);

#[derive(Debug, Clone, Copy)]
struct Cell {
    key: u64,
    start: u32,
    end: u32,
}

/// Probes sorted by cell. Every per-probe array a caller keeps must follow [`ProbeGrid::ids`]
/// order, which is the order of [`ProbeGrid::points`].
pub struct ProbeGrid {
    cell: f64,
    origin: Point3<f64>,
    points: Vec<Point3<f64>>,
    normals: Vec<Vector3<f64>>,
    ids: Vec<u32>,
    cells: Vec<Cell>,
    lookup: FxHashMap<u64, u32>,
}

/// Per-chunk buffers, sized by the largest chunk and the number of probe cells, and reused:
/// a stream of chunks no larger than the first allocates nothing new.
#[derive(Default)]
pub struct Scratch {
    keyed: Vec<(u64, u32)>,
    sorted: Vec<Point3<f64>>,
    runs: FxHashMap<u64, (u32, u32)>,
    active: Vec<u32>,
    /// Per probe cell, the chunk that last activated it.
    mark: Vec<u32>,
    generation: u32,
}

impl Scratch {
    /// Memory held, bytes.
    pub fn bytes(&self) -> usize {
        self.keyed.capacity() * size_of::<(u64, u32)>()
            + self.sorted.capacity() * size_of::<Point3<f64>>()
            + self.runs.capacity() * (size_of::<u64>() + size_of::<(u32, u32)>())
            + (self.active.capacity() + self.mark.capacity()) * size_of::<u32>()
    }
}

impl ProbeGrid {
    /// `reach` is the largest distance from a probe at which a scan point can matter.
    pub fn new(points: &[Point3<f64>], normals: &[Vector3<f64>], reach: f64) -> Self {
        assert_eq!(points.len(), normals.len(), "one normal per probe");
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
        let cell = reach
            .max(extent / (AXIS_BIAS as f64 - 4.0))
            .max(f64::MIN_POSITIVE);
        let origin = Point3::from((lo.coords + hi.coords) * 0.5);
        let mut grid = Self {
            cell,
            origin,
            points: Vec::new(),
            normals: Vec::new(),
            ids: Vec::new(),
            cells: Vec::new(),
            lookup: FxHashMap::default(),
        };
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
    }

    #[inline]
    fn coords(&self, p: &Point3<f64>) -> Option<[i64; 3]> {
        let mut c = [0i64; 3];
        for k in 0..3 {
            let v = ((p[k] - self.origin[k]) / self.cell).floor();
            // NaN fails both comparisons and is refused with the far points.
            if !(v > -(AXIS_BIAS as f64) + 2.0 && v < AXIS_BIAS as f64 - 2.0) {
                return None;
            }
            c[k] = v as i64;
        }
        Some(c)
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
        self.coords(p).map(Self::pack)
    }

    fn neighbours(key: u64) -> impl Iterator<Item = u64> {
        let c = Self::unpack(key);
        (0..27).map(move |i| {
            let d = [i % 3 - 1, (i / 3) % 3 - 1, i / 9 - 1];
            Self::pack([c[0] + d[0], c[1] + d[1], c[2] + d[2]])
        })
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
        assert_eq!(state.len(), self.points.len(), "one state per probe");
        let Scratch {
            keyed,
            sorted,
            runs,
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
        sorted.clear();
        runs.clear();
        active.clear();
        keyed.reserve(chunk.len());
        sorted.reserve(chunk.len());
        runs.reserve(chunk.len());
        active.reserve(self.cells.len());
        keyed.extend(
            chunk
                .iter()
                .enumerate()
                .filter_map(|(i, p)| self.key(p).map(|k| (k, i as u32))),
        );
        keyed.sort_unstable();
        sorted.extend(keyed.iter().map(|&(_, i)| chunk[i as usize]));
        for (key, start, end) in runs_of(keyed) {
            runs.insert(key, (start, end));
            for k in Self::neighbours(key) {
                if let Some(&c) = self.lookup.get(&k)
                    && mark[c as usize] != *generation
                {
                    mark[c as usize] = *generation;
                    active.push(c);
                }
            }
        }
        active.sort_unstable();

        // Cells are sorted by key and hold consecutive probes, so the active cells cut `state`
        // into disjoint slices in order.
        let mut jobs: Vec<(&Cell, &mut [S])> = Vec::with_capacity(active.len());
        let mut rest = state;
        let mut offset = 0usize;
        for &c in active.iter() {
            let cell = &self.cells[c as usize];
            let (_, tail) = rest.split_at_mut(cell.start as usize - offset);
            let (mine, tail) = tail.split_at_mut((cell.end - cell.start) as usize);
            jobs.push((cell, mine));
            rest = tail;
            offset = cell.end as usize;
        }
        let (sorted, runs) = (&*sorted, &*runs);
        jobs.into_par_iter().for_each(|(cell, states)| {
            for nk in Self::neighbours(cell.key) {
                let Some(&(s, e)) = runs.get(&nk) else {
                    continue;
                };
                let pts = &sorted[s as usize..e as usize];
                let range = cell.start as usize..cell.end as usize;
                for ((p, n), st) in self.points[range.clone()]
                    .iter()
                    .zip(&self.normals[range])
                    .zip(states.iter_mut())
                {
                    for q in pts {
                        visit(q - p, n, st);
                    }
                }
            }
        });
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
    use super::*;
    use crate::test_points::{random_points, seeded};

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
}
