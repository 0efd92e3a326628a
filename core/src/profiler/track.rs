//! The robot's recent poses of the profiler's mount, and the pose at a profile's time.

use std::collections::VecDeque;

use nalgebra::{Isometry3, Translation3, UnitQuaternion};

/// A pose of the profiler's mount as the robot reported it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MountPose {
    /// When the robot sampled it, nanoseconds on the robot's clock.
    pub time_ns: i64,
    /// The mount in the frame the points go into (`T_frame_mount`).
    pub pose: Isometry3<f64>,
}

/// How a track keeps and uses its poses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseTrackParams {
    /// Poses kept, at most; the oldest go first. At 1 kHz, 4,096 are four seconds: longer
    /// than any profile should wait for the pose after it.
    pub capacity: usize,
    /// A profile whose bracketing poses are further apart than this is refused, nanoseconds:
    /// over a longer gap the path between them is not known to be straight.
    pub max_gap_ns: u64,
    /// The robot's clock less the sensor's, nanoseconds: added to a profile's timestamp to
    /// place it on the robot's clock.
    pub clock_offset_ns: i64,
    /// The sensor in the mount's frame (`T_mount_sensor`), from calibration.
    pub mount_sensor: Isometry3<f64>,
}

impl Default for PoseTrackParams {
    /// 4,096 poses, a 20 ms gap (five poses missed at 250 Hz), no clock offset, the sensor at
    /// the mount.
    fn default() -> Self {
        Self {
            capacity: 4096,
            max_gap_ns: 20_000_000,
            clock_offset_ns: 0,
            mount_sensor: Isometry3::identity(),
        }
    }
}

/// Where a profile was taken from, or why it cannot be known (yet).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PoseAt {
    /// The sensor's pose at the profile's time (`T_frame_sensor`).
    Ready(Isometry3<f64>),
    /// No pose at or after the profile's time has come yet: ask again when one has.
    Wait,
    /// The pose cannot be known; the profile is refused.
    Refused(Refused),
}

/// Why a profile has no pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refused {
    /// The poses either side of it are further apart than the allowed gap.
    Gap {
        /// Their distance in time, nanoseconds.
        gap_ns: u64,
    },
    /// It is older than the oldest pose kept: placing it would be extrapolation.
    BeforePoses {
        /// By how much, nanoseconds.
        by_ns: u64,
    },
    /// Its timestamp with the clock offset is beyond the clock's range.
    BadTime,
    /// It waited for the pose after it while the wait was full: the robot's poses stopped
    /// coming or lag further behind than the wait holds.
    WaitFull,
    /// No pose after it came before its pass ended.
    NoLaterPose,
}

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refused::Gap { gap_ns } => write!(
                f,
                "the robot's poses either side of it are {:.1} ms apart, more than allowed \
                 (max_pose_gap)",
                *gap_ns as f64 * 1e-6
            ),
            Refused::BeforePoses { by_ns } => write!(
                f,
                "it was taken {:.1} ms before the oldest pose kept: it would need extrapolation \
                 (is the clock offset right?)",
                *by_ns as f64 * 1e-6
            ),
            Refused::BadTime => f.write_str("its timestamp with the clock offset is out of range"),
            Refused::WaitFull => f.write_str(
                "it waited for the robot's next pose while the wait was full (are the poses \
                 still coming?)",
            ),
            Refused::NoLaterPose => {
                f.write_str("no robot pose after it came before its pass ended")
            }
        }
    }
}

/// Why a pose was not taken.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum PoseRefused {
    /// Not after the last pose taken (the robot's poses come in time order).
    #[error("pose at {time_ns} ns is not after the last one ({last_ns} ns)")]
    NotAfter {
        /// This pose's time.
        time_ns: i64,
        /// The last pose's time.
        last_ns: i64,
    },
    /// A translation or rotation that is not a finite number, or a rotation that is not one.
    #[error("pose at {time_ns} ns is not a rigid motion (NaN, infinite or a zero quaternion)")]
    NotRigid {
        /// This pose's time.
        time_ns: i64,
    },
}

/// The robot's recent poses of the mount: a fixed number, in time order.
#[derive(Debug, Clone)]
pub struct PoseTrack {
    params: PoseTrackParams,
    poses: VecDeque<MountPose>,
}

impl PoseTrack {
    /// An empty track (a capacity of 0 is taken as 2: a bracket needs two).
    pub fn new(params: PoseTrackParams) -> Self {
        let params = PoseTrackParams {
            capacity: params.capacity.max(2),
            ..params
        };
        Self {
            poses: VecDeque::with_capacity(params.capacity),
            params,
        }
    }

    /// How it keeps and uses poses.
    pub fn params(&self) -> &PoseTrackParams {
        &self.params
    }

    /// What the poses' buffer holds without growing.
    #[cfg(test)]
    pub(crate) fn poses_capacity(&self) -> usize {
        self.poses.capacity()
    }

    /// Applies `mount_sensor` (`T_mount_sensor`) from now on.
    pub fn set_mount_sensor(&mut self, mount_sensor: Isometry3<f64>) {
        self.params.mount_sensor = mount_sensor;
    }

    /// Poses kept now.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// Whether no pose has been taken.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// The newest pose's time on the robot's clock, if any.
    pub fn newest_ns(&self) -> Option<i64> {
        self.poses.back().map(|p| p.time_ns)
    }

    /// Takes the robot's next pose (the newest again changes nothing); the oldest goes when the
    /// track is full.
    pub fn push(&mut self, pose: MountPose) -> Result<(), PoseRefused> {
        let t = pose.time_ns;
        let q = pose.pose.rotation.coords;
        let rigid = pose.pose.translation.vector.iter().all(|v| v.is_finite())
            && q.iter().all(|v| v.is_finite())
            && (q.norm() - 1.0).abs() < 1e-6;
        if !rigid {
            return Err(PoseRefused::NotRigid { time_ns: t });
        }
        if let Some(last) = self.poses.back()
            && t <= last.time_ns
        {
            // The newest pose again (a service's history, delivered to a subscriber that
            // joined late): nothing new.
            if *last == pose {
                return Ok(());
            }
            return Err(PoseRefused::NotAfter {
                time_ns: t,
                last_ns: last.time_ns,
            });
        }
        if self.poses.len() == self.params.capacity {
            self.poses.pop_front();
        }
        self.poses.push_back(pose);
        Ok(())
    }

    /// The profile's time on the robot's clock: its sensor timestamp plus the clock offset.
    pub fn robot_time(&self, sensor_ns: u64) -> Option<i64> {
        i64::try_from(i128::from(sensor_ns) + i128::from(self.params.clock_offset_ns)).ok()
    }

    /// The sensor's pose when it took a profile stamped `sensor_ns` on its own clock.
    pub fn at(&self, sensor_ns: u64) -> PoseAt {
        let Some(t) = self.robot_time(sensor_ns) else {
            return PoseAt::Refused(Refused::BadTime);
        };
        match self.mount_at(t) {
            PoseAt::Ready(mount) => PoseAt::Ready(mount * self.params.mount_sensor),
            other => other,
        }
    }

    /// The mount's pose at `t` on the robot's clock.
    fn mount_at(&self, t: i64) -> PoseAt {
        let (Some(first), Some(last)) = (self.poses.front(), self.poses.back()) else {
            return PoseAt::Wait;
        };
        if t > last.time_ns {
            return PoseAt::Wait;
        }
        if t < first.time_ns {
            return PoseAt::Refused(Refused::BeforePoses {
                by_ns: first.time_ns.abs_diff(t),
            });
        }
        // The first pose at or after t: one exists (t <= last) and, t >= first, it is either
        // at t or has one before it.
        let i = self.poses.partition_point(|p| p.time_ns < t);
        let after = self.poses[i];
        if after.time_ns == t {
            return PoseAt::Ready(after.pose);
        }
        let before = self.poses[i - 1];
        let gap_ns = after.time_ns.abs_diff(before.time_ns);
        if gap_ns > self.params.max_gap_ns {
            return PoseAt::Refused(Refused::Gap { gap_ns });
        }
        let s = t.abs_diff(before.time_ns) as f64 / gap_ns as f64;
        PoseAt::Ready(interpolate(&before.pose, &after.pose, s))
    }
}

/// The pose a fraction `s` of the way from `a` to `b`: the translation along the straight
/// line, the rotation along the shorter great arc (a quaternion and its negative are the same
/// rotation; the one nearer `a`'s is taken).
pub fn interpolate(a: &Isometry3<f64>, b: &Isometry3<f64>, s: f64) -> Isometry3<f64> {
    let ta = a.translation.vector;
    let tb = b.translation.vector;
    let (qa, mut qb) = (a.rotation, b.rotation);
    if qa.coords.dot(&qb.coords) < 0.0 {
        qb = UnitQuaternion::new_unchecked(-qb.into_inner());
    }
    // Nearly equal rotations: slerp's sine ratio is 0/0, and a straight blend is exact to
    // the rounding there.
    let rotation = qa
        .try_slerp(&qb, s, 1e-12)
        .unwrap_or_else(|| qa.nlerp(&qb, s));
    Isometry3::from_parts(Translation3::from(ta + (tb - ta) * s), rotation)
}
