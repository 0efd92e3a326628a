//! What a line profiler should have seen: the design samples its laser's plane swept over.
//!
//! A terrestrial scanner sees from one origin, so coverage asks whether a sample faces it; a
//! profiler's plane moves with every profile. A sample is swept when the plane passed it
//! between two consecutive profiles (its signed distance to the plane changed sign), within the
//! fan's angle and the sensor's range, facing the sensor closely enough to return light, with
//! the design clear between them. Swept and without a point near it, a sample is missing
//! material; never swept, it was never judged. One flag per sample: memory follows the design,
//! never the scan.

use nalgebra::{Isometry3, Point3, Vector3};

use crate::c2m::Surface;

/// The profiler's field of view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepParams {
    /// The fan's full angle, degrees.
    pub fan_deg: f64,
    /// The farthest range that returns, metres.
    pub max_range: f64,
    /// The largest angle between a sample's normal and the line to the sensor that still
    /// returns light, degrees.
    pub max_incidence_deg: f64,
    /// Consecutive profiles further apart than this sweep nothing between them, metres: the
    /// profiler did not see what lies between (poses refused, a jump to another outline).
    pub max_step: f64,
}

impl Default for SweepParams {
    /// A 60° fan, 0.3 m of range, 80° of incidence, 5 mm between profiles at most.
    fn default() -> Self {
        Self {
            fan_deg: 60.0,
            max_range: 0.3,
            max_incidence_deg: 80.0,
            max_step: 0.005,
        }
    }
}

/// The samples swept so far, and the previous profile's plane.
#[derive(Debug, Clone)]
pub struct Sweep {
    params: SweepParams,
    points: Vec<Point3<f64>>,
    normals: Vec<Vector3<f64>>,
    /// Sample indices by grid cell (`cell` metres a side), sorted by cell key.
    cells: Vec<(i64, u32)>,
    cell: f64,
    swept: Vec<bool>,
    previous: Option<Isometry3<f64>>,
    /// Scratch: the samples near a profile.
    near: Vec<u32>,
}

/// Grid cells per axis in the packed key; ±2^20 cells around the origin.
const KEY_BITS: i64 = 21;

fn key(c: [i64; 3]) -> i64 {
    let m = (1 << KEY_BITS) - 1;
    ((c[0] & m) << (2 * KEY_BITS)) | ((c[1] & m) << KEY_BITS) | (c[2] & m)
}

impl Sweep {
    /// Over design samples at `points` with outward unit `normals` (one each).
    pub fn new(points: &[Point3<f64>], normals: &[Vector3<f64>], params: SweepParams) -> Self {
        // A cell a sixth of the range: a profile's reach spans a few cells each way.
        let cell = (params.max_range / 6.0).max(1e-3);
        let mut cells: Vec<(i64, u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                (
                    key((p.coords / cell).map(|v| v.floor() as i64).into()),
                    i as u32,
                )
            })
            .collect();
        cells.sort_unstable();
        Self {
            params,
            points: points.to_vec(),
            normals: normals.to_vec(),
            cells,
            cell,
            swept: vec![false; points.len()],
            previous: None,
            near: Vec::new(),
        }
    }

    /// Whether each sample was swept, in sample order.
    pub fn swept(&self) -> &[bool] {
        &self.swept
    }

    /// Takes up what was swept before (`flags`, one per sample, as [`Self::swept`] gave them);
    /// false, and nothing changed, for another number of samples.
    pub fn set_swept(&mut self, flags: &[bool]) -> bool {
        if flags.len() != self.swept.len() {
            return false;
        }
        self.swept.copy_from_slice(flags);
        true
    }

    /// Sweeps the next profiles with the field of view `params`.
    pub fn set_params(&mut self, params: SweepParams) {
        self.params = params;
    }

    /// Samples swept so far.
    pub fn count(&self) -> usize {
        self.swept.iter().filter(|&&s| s).count()
    }

    /// The next profile of a pass, taken from `sensor` (`T_design_sensor`: z the view, x the
    /// laser line, y the plane's normal): the samples its plane passed since the previous
    /// profile's are swept where the profiler could see them.
    pub fn profile(&mut self, sensor: &Isometry3<f64>, design: &dyn Surface) {
        let Some(previous) = self.previous.replace(*sensor) else {
            return;
        };
        let step = (sensor.translation.vector - previous.translation.vector).norm();
        // A step that is not a number sweeps nothing either.
        if step.is_nan() || step > self.params.max_step {
            return;
        }
        let (here, before) = (sensor.inverse(), previous.inverse());
        let half = 0.5 * self.params.fan_deg.to_radians();
        let cos_incidence = self.params.max_incidence_deg.to_radians().cos();
        let eye = Point3::from(sensor.translation.vector);
        self.gather(&eye);
        for &i in &self.near {
            let i = i as usize;
            if self.swept[i] {
                continue;
            }
            let p = self.points[i];
            let (now, then) = (here * p, before * p);
            // The plane passed it: on different sides of this plane and the previous one (or
            // on this one).
            if (now.y > 0.0) == (then.y > 0.0) && now.y != 0.0 {
                continue;
            }
            let range = now.coords.norm();
            if range > self.params.max_range || now.z <= 0.0 || now.x.atan2(now.z).abs() > half {
                continue;
            }
            let to_eye = (eye - p) / range;
            if self.normals[i].dot(&to_eye) < cos_incidence {
                continue;
            }
            // The sample's own face aside: a millimetre's margin at its end.
            if design.blocks_sight(&eye, &p, 1e-3) {
                continue;
            }
            self.swept[i] = true;
        }
    }

    /// The pass is over: the next profile starts a new one (no sweep from the last of this one).
    pub fn end_pass(&mut self) {
        self.previous = None;
    }

    /// The samples within the range's cells around `eye`, into `self.near`.
    fn gather(&mut self, eye: &Point3<f64>) {
        self.near.clear();
        let r = (self.params.max_range / self.cell).ceil() as i64;
        let c = (eye.coords / self.cell).map(|v| v.floor() as i64);
        for x in c.x - r..=c.x + r {
            for y in c.y - r..=c.y + r {
                for z in c.z - r..=c.z + r {
                    let k = key([x, y, z]);
                    let from = self.cells.partition_point(|e| e.0 < k);
                    for e in self.cells[from..].iter().take_while(|e| e.0 == k) {
                        self.near.push(e.1);
                    }
                }
            }
        }
    }
}
