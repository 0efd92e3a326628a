//! A laser line profiler beside the nozzle, scanning the layer just laid while the robot
//! prints: a fan of rays in the plane across the path, behind the nozzle, riding a little
//! outside the outline and tilted in, so it sees the layer's top and its outer side (an LMI
//! Gocator or Keyence LJ-X class sensor).
//!
//! A layer's pass follows each of the layer's outlines at the print speed, material on the
//! left (holes are followed the other way round). The robot reports the
//! mount's pose (at the nozzle, x along the path) at its own rate, each sampled a little off
//! its tick and stamped with when it was; the profiler stamps its profiles on its own clock,
//! `clock_offset_ns` behind the robot's. Each profile is the nearest as-built surface on each
//! ray, with range noise: as for the terrestrial scanner, the rays are not cast one by one
//! against the mesh. The triangles near the sensor are cut by the laser's plane into segments,
//! and each segment fills the rays between its ends.
//!
//! A pass is produced profile by profile ([`ProfilePass::profile`]): a layer's 12,000
//! profiles of 2,048 points would be 300 MB at once.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use asbuilt_core::profiler::MountPose;

use super::asbuilt::AsBuilt;
use super::part::{Part, PartError, Ring, signed_area2};

/// The profiler and how the robot carries it. Defaults: 2,048 points at 2 kHz, a 60° fan
/// 100 mm above the layer, 60 mm behind the nozzle and 50 mm outside the outline, 0.05 mm
/// noise; printing at 0.2 m/s with poses at 250 Hz.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProfilerModel {
    /// Points (rays) per profile.
    pub points: usize,
    /// Profiles per second.
    pub rate_hz: f64,
    /// The fan's full angle, degrees.
    pub fan_deg: f64,
    /// The farthest range that returns, metres.
    pub max_range: f64,
    /// Range noise σ along the ray, metres.
    pub noise: f64,
    /// How far behind the nozzle the laser line falls, metres.
    pub behind: f64,
    /// The sensor's height above the layer's top, metres.
    pub standoff: f64,
    /// How far outside the outline the sensor rides, metres; it is tilted to look at the
    /// outline's edge, so it sees the top inside and the side below.
    pub side: f64,
    /// The print speed along the path, metres per second.
    pub speed: f64,
    /// The robot's poses per second.
    pub pose_rate_hz: f64,
    /// A pose is sampled up to this far off its tick, nanoseconds (and stamped truly).
    pub pose_time_jitter_ns: i64,
    /// The robot's clock less the profiler's, nanoseconds.
    pub clock_offset_ns: i64,
}

impl Default for ProfilerModel {
    fn default() -> Self {
        Self {
            points: 2048,
            rate_hz: 2000.0,
            fan_deg: 60.0,
            max_range: 0.3,
            noise: 0.05e-3,
            behind: 0.06,
            standoff: 0.1,
            side: 0.05,
            speed: 0.2,
            pose_rate_hz: 250.0,
            pose_time_jitter_ns: 500_000,
            clock_offset_ns: 0,
        }
    }
}

impl ProfilerModel {
    /// The profiler in the mount's frame (`T_mount_sensor`): `behind` the nozzle, `side`
    /// outside the outline (the mount's −y: material is on its left) and `standoff` above it;
    /// its y along the path, its z looking down and tilted in at the outline's edge, its x
    /// (the laser line) across.
    pub fn mount_sensor(&self) -> Isometry3<f64> {
        let tilt = self.side.atan2(self.standoff);
        let (s, c) = tilt.sin_cos();
        let x = Vector3::new(0.0, c, s);
        let z = Vector3::new(0.0, s, -c);
        let axes = Matrix3::from_columns(&[x, Vector3::x(), z]);
        Isometry3::from_parts(
            Translation3::new(-self.behind, -self.side, self.standoff),
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(axes)),
        )
    }
}

/// One profile: when, on the profiler's clock, and its points in its own frame (x across the
/// line, z along the view; y is 0), only the rays that returned.
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    /// Nanoseconds on the profiler's clock.
    pub sensor_ns: u64,
    /// Metres, sensor frame.
    pub points: Vec<[f32; 3]>,
}

/// Headings and positions are blended over this much path either side, metres: the robot
/// turns through a corner over a few centimetres, never in an instant.
const TURN: f64 = 0.01;
/// The robot moves from one outline to the next in this long, without poses or profiles.
const TRAVEL_NS: i64 = 100_000_000;
/// Cells of the grid of triangles near the layer, metres.
const CELL: f64 = 0.05;

/// One outline of a layer's path, as the nozzle follows it.
struct Loop {
    ring: Ring,
    /// Arc length at each vertex, and the whole loop's at the end.
    at: Vec<f64>,
    /// When the nozzle starts it, robot clock.
    start_ns: i64,
    /// Profiles before this loop's.
    first_profile: usize,
    profiles: usize,
}

impl Loop {
    fn length(&self) -> f64 {
        *self.at.last().unwrap_or(&0.0)
    }

    fn duration_ns(&self, speed: f64) -> i64 {
        (self.length() / speed * 1e9) as i64
    }

    /// The robot's path at arc length `s`: the outline is a polygon, and the path rounds its
    /// vertices as a controller blends its moves, averaging the outline over the turn's
    /// length either side (a tent, so the heading turns smoothly too).
    fn blended(&self, s: f64) -> [f64; 2] {
        const K: i32 = 8;
        let (mut sum, mut weight) = ([0.0; 2], 0.0);
        for i in -K..=K {
            let w = f64::from(K + 1 - i.abs());
            let q = self.point(s + f64::from(i) / f64::from(K) * TURN);
            sum = [sum[0] + w * q[0], sum[1] + w * q[1]];
            weight += w;
        }
        [sum[0] / weight, sum[1] / weight]
    }

    /// The point at arc length `s`, wrapping around the loop.
    fn point(&self, s: f64) -> [f64; 2] {
        let len = self.length();
        let s = s.rem_euclid(len.max(f64::MIN_POSITIVE));
        let i = self
            .at
            .partition_point(|&a| a <= s)
            .clamp(1, self.ring.len());
        let (p, q) = (self.ring[i - 1], self.ring[i % self.ring.len()]);
        let f = (s - self.at[i - 1]) / (self.at[i] - self.at[i - 1]).max(f64::MIN_POSITIVE);
        [p[0] + f * (q[0] - p[0]), p[1] + f * (q[1] - p[1])]
    }
}

/// The triangles of the top of the as-built part, by the cells their plan bounds touch.
struct Grid {
    lo: [f64; 2],
    nx: usize,
    ny: usize,
    cells: Vec<Vec<u32>>,
}

impl Grid {
    /// Triangles reaching above `below`.
    fn new(mesh: &AsBuilt, below: f64) -> Self {
        let corners = |t: u32| mesh.triangles[t as usize].map(|v| mesh.vertices[v as usize]);
        let near: Vec<u32> = (0..mesh.triangles.len() as u32)
            .filter(|&t| corners(t).iter().any(|p| p.z >= below))
            .collect();
        let Some((lo, hi)) = plan_bounds(near.iter().flat_map(|&t| corners(t))) else {
            return Self {
                lo: [0.0; 2],
                nx: 0,
                ny: 0,
                cells: Vec::new(),
            };
        };
        let nx = ((hi[0] - lo[0]) / CELL).floor() as usize + 1;
        let ny = ((hi[1] - lo[1]) / CELL).floor() as usize + 1;
        let mut grid = Self {
            lo,
            nx,
            ny,
            cells: vec![Vec::new(); nx * ny],
        };
        for &t in &near {
            let (a, b) = plan_bounds(corners(t)).expect("a triangle has corners");
            let ((x0, y0), (x1, y1)) = (grid.cell_of(a[0], a[1]), grid.cell_of(b[0], b[1]));
            for y in y0..=y1 {
                for x in x0..=x1 {
                    grid.cells[y * nx + x].push(t);
                }
            }
        }
        grid
    }

    fn cell_of(&self, x: f64, y: f64) -> (usize, usize) {
        let cx = ((x - self.lo[0]) / CELL)
            .floor()
            .clamp(0.0, (self.nx - 1) as f64);
        let cy = ((y - self.lo[1]) / CELL)
            .floor()
            .clamp(0.0, (self.ny - 1) as f64);
        (cx as usize, cy as usize)
    }

    /// Triangles whose cells are within `r` of (x, y), each once (in `out`, cleared first).
    fn near(&self, x: f64, y: f64, r: f64, out: &mut Vec<u32>) {
        out.clear();
        if self.cells.is_empty() {
            return;
        }
        let (x0, y0) = self.cell_of(x - r, y - r);
        let (x1, y1) = self.cell_of(x + r, y + r);
        for cy in y0..=y1 {
            for cx in x0..=x1 {
                out.extend_from_slice(&self.cells[cy * self.nx + cx]);
            }
        }
        out.sort_unstable();
        out.dedup();
    }
}

/// The lowest and highest x and y of `points`, or `None` for none.
fn plan_bounds(points: impl IntoIterator<Item = Point3<f64>>) -> Option<([f64; 2], [f64; 2])> {
    points.into_iter().fold(None, |b, p| {
        let (lo, hi) = b.unwrap_or(([p.x, p.y], [p.x, p.y]));
        Some((
            [lo[0].min(p.x), lo[1].min(p.y)],
            [hi[0].max(p.x), hi[1].max(p.y)],
        ))
    })
}

/// A layer's pass of the profiler: the robot's poses and the profiles, both in time order.
pub struct ProfilePass<'a> {
    /// The layer just laid, from 0.
    pub layer: u32,
    model: ProfilerModel,
    seed: u64,
    /// The height the nozzle travels at: the layer's nominal top.
    z: f64,
    loops: Vec<Loop>,
    mesh: &'a AsBuilt,
    grid: Grid,
    /// Each ray's direction in the laser's plane, (sin, cos) of its angle from the sensor's z
    /// towards its x: the same for every profile.
    rays: Vec<[f64; 2]>,
}

impl<'a> ProfilePass<'a> {
    /// The pass over layer `layer` of `part`, printed as `built` (which holds that layer), the
    /// nozzle starting at `start_ns` on the robot's clock; `seed` makes the noise repeatable.
    pub fn new(
        part: &Part,
        built: &'a AsBuilt,
        layer: u32,
        model: ProfilerModel,
        seed: u64,
        start_ns: i64,
    ) -> Result<Self, PartError> {
        let (z0, z1) = part.layer_span(layer);
        let mut loops = Vec::new();
        let (mut t, mut first_profile) = (start_ns, 0);
        for mut ring in part.section(0.5 * (z0 + z1))? {
            if ring.len() < 2 {
                continue;
            }
            if signed_area2(&ring) < 0.0 {
                ring.reverse();
            }
            let mut at = vec![0.0];
            for k in 0..ring.len() {
                let (p, q) = (ring[k], ring[(k + 1) % ring.len()]);
                at.push(at[k] + (q[0] - p[0]).hypot(q[1] - p[1]));
            }
            let mut l = Loop {
                ring,
                at,
                start_ns: t,
                first_profile,
                profiles: 0,
            };
            let duration = l.duration_ns(model.speed);
            l.profiles = (duration as f64 * 1e-9 * model.rate_hz).floor() as usize;
            first_profile += l.profiles;
            t += duration + TRAVEL_NS;
            loops.push(l);
        }
        // What the fan can reach below the nozzle's height.
        let grid = Grid::new(built, z1 - model.standoff - model.max_range);
        let half = 0.5 * model.fan_deg.to_radians();
        let n = model.points.max(2);
        let rays = (0..n)
            .map(|i| {
                let a = -half + 2.0 * half * i as f64 / (n - 1) as f64;
                [a.sin(), a.cos()]
            })
            .collect();
        Ok(Self {
            layer,
            model,
            seed,
            z: z1,
            loops,
            mesh: built,
            grid,
            rays,
        })
    }

    /// Profiles in the pass.
    pub fn profiles(&self) -> usize {
        self.loops.iter().map(|l| l.profiles).sum()
    }

    /// When the pass ends, robot clock: the last outline done.
    pub fn end_ns(&self) -> i64 {
        self.loops
            .last()
            .map_or(0, |l| l.start_ns + l.duration_ns(self.model.speed))
    }

    /// The mount's true pose at `t_ns` on the robot's clock, while the nozzle is on an outline.
    pub fn mount_at(&self, t_ns: i64) -> Option<Isometry3<f64>> {
        let l = self.loops.iter().find(|l| {
            (l.start_ns..=l.start_ns + l.duration_ns(self.model.speed)).contains(&t_ns)
        })?;
        let s = (t_ns - l.start_ns) as f64 * 1e-9 * self.model.speed;
        let p = l.blended(s);
        let (a, b) = (l.blended(s - 0.5 * TURN), l.blended(s + 0.5 * TURN));
        let heading = (b[1] - a[1]).atan2(b[0] - a[0]);
        Some(Isometry3::from_parts(
            Translation3::new(p[0], p[1], self.z),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), heading),
        ))
    }

    /// The robot's poses of the mount over the pass, in time order: at `pose_rate_hz` on each
    /// outline, each sampled up to the jitter off its tick and stamped with when it was, and
    /// one at each outline's ends.
    pub fn poses(&self) -> Vec<MountPose> {
        let m = &self.model;
        let step = (1e9 / m.pose_rate_hz) as i64;
        let mut rng =
            ChaCha8Rng::seed_from_u64(self.seed ^ 0x005E_ED0F_9053 ^ u64::from(self.layer));
        let mut out = Vec::new();
        for l in &self.loops {
            let end = l.start_ns + l.duration_ns(m.speed);
            let mut t = l.start_ns;
            while t <= end {
                let jitter = if m.pose_time_jitter_ns > 0 && t > l.start_ns && t + step <= end {
                    rng.random_range(-m.pose_time_jitter_ns..=m.pose_time_jitter_ns)
                } else {
                    0
                };
                let at = t + jitter;
                if let Some(pose) = self.mount_at(at) {
                    out.push(MountPose { time_ns: at, pose });
                }
                t += step;
            }
            if out.last().is_some_and(|p| p.time_ns < end)
                && let Some(pose) = self.mount_at(end)
            {
                out.push(MountPose { time_ns: end, pose });
            }
        }
        out
    }

    /// When profile `k` was taken, robot clock.
    pub fn profile_time_ns(&self, k: usize) -> Option<i64> {
        let l = self
            .loops
            .iter()
            .find(|l| (l.first_profile..l.first_profile + l.profiles).contains(&k))?;
        let i = (k - l.first_profile) as f64;
        Some(l.start_ns + (i / self.model.rate_hz * 1e9) as i64)
    }

    /// Profile `k` (from 0) of the pass; `None` past the last.
    pub fn profile(&self, k: usize) -> Option<Profile> {
        let t = self.profile_time_ns(k)?;
        let sensor = self.mount_at(t)? * self.model.mount_sensor();
        let ranges = self.ranges(&sensor);
        let m = &self.model;
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.seed ^ (u64::from(self.layer) << 40) ^ (k as u64).wrapping_mul(0x9E37_79B9),
        );
        let noise = Normal::new(0.0, m.noise.max(0.0)).expect("a finite σ");
        let points = ranges
            .iter()
            .enumerate()
            .filter(|(_, r)| r.is_finite())
            .map(|(i, &r)| {
                let [sin, cos] = self.rays[i];
                let r = r + noise.sample(&mut rng);
                [(r * sin) as f32, 0.0, (r * cos) as f32]
            })
            .collect();
        Some(Profile {
            sensor_ns: (t - m.clock_offset_ns).max(0) as u64,
            points,
        })
    }

    /// The nearest surface on each ray from `sensor` (`T_design_sensor`): infinite where none
    /// is within range.
    fn ranges(&self, sensor: &Isometry3<f64>) -> Vec<f64> {
        let m = &self.model;
        let n = m.points.max(2);
        let half = 0.5 * m.fan_deg.to_radians();
        let mut range = vec![f64::INFINITY; n];
        let o = sensor.translation.vector;
        let mut near = Vec::new();
        self.grid
            .near(o.x, o.y, m.max_range * half.sin() + CELL, &mut near);
        let inv = sensor.inverse();
        for &t in &near {
            let ps = self.mesh.triangles[t as usize].map(|v| inv * self.mesh.vertices[v as usize]);
            let Some((a, b)) = cut(&ps) else { continue };
            let Some((a, b)) = in_front(a, b) else {
                continue;
            };
            let (aa, ab) = (a[0].atan2(a[1]), b[0].atan2(b[1]));
            let (lo, hi) = (aa.min(ab), aa.max(ab));
            let to_index = |x: f64| (x + half) / (2.0 * half) * (n - 1) as f64;
            let first = to_index(lo).ceil().max(0.0) as usize;
            let last = to_index(hi).floor().min((n - 1) as f64);
            if last < 0.0 {
                continue;
            }
            let e = [b[0] - a[0], b[1] - a[1]];
            for (i, r) in range
                .iter_mut()
                .enumerate()
                .take(last as usize + 1)
                .skip(first)
            {
                let d = self.rays[i];
                let den = d[0] * e[1] - d[1] * e[0];
                if den.abs() < 1e-15 {
                    continue;
                }
                let hit = (a[0] * e[1] - a[1] * e[0]) / den;
                if hit > 0.0 && hit <= m.max_range && hit < *r {
                    *r = hit;
                }
            }
        }
        range
    }
}

/// Where the laser's plane (the sensor's y = 0) cuts a triangle given in the sensor's frame:
/// a segment in (x, z), or `None`.
fn cut(ps: &[Point3<f64>; 3]) -> Option<([f64; 2], [f64; 2])> {
    let mut ends = [[0.0; 2]; 2];
    let mut n = 0;
    for k in 0..3 {
        let (p, q) = (ps[k], ps[(k + 1) % 3]);
        if (p.y < 0.0) != (q.y < 0.0) {
            let f = p.y / (p.y - q.y);
            if n < 2 {
                ends[n] = [p.x + f * (q.x - p.x), p.z + f * (q.z - p.z)];
            }
            n += 1;
        }
    }
    (n == 2).then_some((ends[0], ends[1]))
}

/// The part of a segment in front of the sensor (z > 0), or `None`.
fn in_front(a: [f64; 2], b: [f64; 2]) -> Option<([f64; 2], [f64; 2])> {
    const NEAR: f64 = 1e-6;
    match (a[1] > NEAR, b[1] > NEAR) {
        (true, true) => Some((a, b)),
        (false, false) => None,
        (a_in, _) => {
            let (p, q) = if a_in { (a, b) } else { (b, a) };
            let f = (p[1] - NEAR) / (p[1] - q[1]);
            Some((p, [p[0] + f * (q[0] - p[0]), NEAR]))
        }
    }
}

#[cfg(test)]
mod tests;
