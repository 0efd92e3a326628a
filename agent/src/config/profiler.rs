//! `[profiler]`: a line profiler scanning while printing. Its profiles are placed by the
//! robot's mount poses interpolated at each profile's time (`asbuilt_core::profiler`); these
//! settings say how the two clocks relate, how long a profile may wait for its later pose and
//! what the profiler can see. Used only by passes that send profiles; a cell with a terrestrial
//! scanner needs none of it.

use serde::Deserialize;

/// `[profiler]`, every key with its default.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct ProfilerConfig {
    /// The robot's clock less the profiler's, nanoseconds: added to a profile's timestamp to
    /// place it on the robot's clock (from the cell's clock calibration).
    pub clock_offset_ns: i64,
    /// A profile whose bracketing poses are further apart than this is refused, milliseconds.
    pub max_pose_gap_ms: f64,
    /// Robot poses kept, at most (4,096: four seconds at 1 kHz).
    pub poses_kept: usize,
    /// Profiles that may wait for their later pose at once; the oldest is refused when more
    /// come (256: 128 ms at 2 kHz).
    pub wait_profiles: usize,
    /// One-sigma position uncertainty of a placed profile, metres (the robot's pose accuracy):
    /// the findings' level of detection.
    pub position_sigma: f64,
    /// The laser fan's full angle, degrees.
    pub fan_deg: f64,
    /// The farthest range that returns, metres.
    pub max_range: f64,
    /// The largest angle between the surface's normal and the line to the sensor that still
    /// returns light, degrees.
    pub max_incidence_deg: f64,
    /// Consecutive profiles further apart than this sweep nothing between them, metres.
    pub max_step: f64,
    /// Placed points compared at once (a batch of the pass).
    pub batch_points: usize,
    /// Placed points a pass holds while its printed design is being prepared; more are
    /// refused and counted.
    pub hold_points: usize,
}

impl Default for ProfilerConfig {
    fn default() -> Self {
        let sweep = asbuilt_core::profiler::SweepParams::default();
        Self {
            clock_offset_ns: 0,
            max_pose_gap_ms: 20.0,
            poses_kept: 4096,
            wait_profiles: 256,
            position_sigma: 0.001,
            fan_deg: sweep.fan_deg,
            max_range: sweep.max_range,
            max_incidence_deg: sweep.max_incidence_deg,
            max_step: sweep.max_step,
            batch_points: 1 << 15,
            hold_points: 1 << 20,
        }
    }
}

impl ProfilerConfig {
    /// The field of view the sweep judges coverage by.
    pub fn sweep(&self) -> asbuilt_core::profiler::SweepParams {
        asbuilt_core::profiler::SweepParams {
            fan_deg: self.fan_deg,
            max_range: self.max_range,
            max_incidence_deg: self.max_incidence_deg,
            max_step: self.max_step,
        }
    }

    /// How the pose track keeps and uses its poses (the calibration comes with each pose).
    pub fn track(&self) -> asbuilt_core::profiler::PoseTrackParams {
        asbuilt_core::profiler::PoseTrackParams {
            capacity: self.poses_kept,
            max_gap_ns: (self.max_pose_gap_ms * 1e6) as u64,
            clock_offset_ns: self.clock_offset_ns,
            mount_sensor: nalgebra::Isometry3::identity(),
        }
    }

    /// Every problem with the values, as `profiler.key: what to give`.
    pub fn check(&self, problems: &mut Vec<String>) {
        let positive = |v: f64| v > 0.0 && v.is_finite();
        for (key, v, unit) in [
            ("max_pose_gap_ms", self.max_pose_gap_ms, "milliseconds"),
            ("position_sigma", self.position_sigma, "metres"),
            ("max_range", self.max_range, "metres"),
            ("max_step", self.max_step, "metres"),
        ] {
            if !positive(v) {
                problems.push(format!(
                    "profiler.{key}: give a positive number of {unit}, got {v}"
                ));
            }
        }
        for (key, v, lo, hi) in [
            ("fan_deg", self.fan_deg, 1.0, 179.0),
            ("max_incidence_deg", self.max_incidence_deg, 0.0, 89.0),
        ] {
            if !(lo..=hi).contains(&v) {
                problems.push(format!(
                    "profiler.{key}: {v} is not an angle in [{lo}, {hi}] degrees"
                ));
            }
        }
        for (key, v, lo, hi) in [
            ("poses_kept", self.poses_kept, 2, 1 << 20),
            ("wait_profiles", self.wait_profiles, 1, 1 << 16),
            ("batch_points", self.batch_points, 1, 1 << 22),
            ("hold_points", self.hold_points, 0, 1 << 26),
        ] {
            if !(lo..=hi).contains(&v) {
                problems.push(format!("profiler.{key}: {v} is not in [{lo}, {hi}]"));
            }
        }
    }
}
