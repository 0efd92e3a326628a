//! Profiles placed as the robot's poses come: a profile taken before the robot's next pose
//! arrives waits for it, in a wait of fixed size, and every profile ends placed or refused
//! with its reason, counted.

use std::collections::VecDeque;

use nalgebra::Isometry3;

use super::track::{MountPose, PoseAt, PoseRefused, PoseTrack, PoseTrackParams, Refused};

/// What a placer did, since it was made.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PlacerCounts {
    /// Profiles placed.
    pub placed: u64,
    /// Of those, placed after waiting for a later pose.
    pub waited: u64,
    /// Profiles refused: their bracketing poses too far apart.
    pub refused_gap: u64,
    /// Profiles refused: older than the poses kept.
    pub refused_before_poses: u64,
    /// Profiles refused: a timestamp out of range.
    pub refused_bad_time: u64,
    /// Profiles refused: the wait was full.
    pub refused_wait_full: u64,
    /// Profiles refused: their pass ended before a later pose came.
    pub refused_no_later_pose: u64,
    /// Poses refused (out of order, not rigid).
    pub poses_refused: u64,
}

impl PlacerCounts {
    /// Every profile refused, whatever the reason.
    pub fn refused(&self) -> u64 {
        self.refused_gap
            + self.refused_before_poses
            + self.refused_bad_time
            + self.refused_wait_full
            + self.refused_no_later_pose
    }

    fn refuse(&mut self, why: Refused) {
        *match why {
            Refused::Gap { .. } => &mut self.refused_gap,
            Refused::BeforePoses { .. } => &mut self.refused_before_poses,
            Refused::BadTime => &mut self.refused_bad_time,
            Refused::WaitFull => &mut self.refused_wait_full,
            Refused::NoLaterPose => &mut self.refused_no_later_pose,
        } += 1;
    }
}

/// Where each profile goes: placed with its sensor's pose, or refused with why.
pub trait Placed<P> {
    /// `profile` was taken from `sensor` (`T_frame_sensor`).
    fn placed(&mut self, profile: P, sensor: &Isometry3<f64>);
    /// `profile` cannot be placed.
    fn refused(&mut self, profile: P, why: Refused);
}

/// A [`PoseTrack`] and the profiles waiting for their later pose: at most `wait` of them, so
/// memory stays fixed whatever the robot does.
#[derive(Debug)]
pub struct Placer<P> {
    track: PoseTrack,
    waiting: VecDeque<(u64, P)>,
    wait: usize,
    counts: PlacerCounts,
}

impl<P> Placer<P> {
    /// A placer over a track of `params`, holding at most `wait` profiles (at least 1) for
    /// their later pose.
    pub fn new(params: PoseTrackParams, wait: usize) -> Self {
        let wait = wait.max(1);
        Self {
            track: PoseTrack::new(params),
            waiting: VecDeque::with_capacity(wait),
            wait,
            counts: PlacerCounts::default(),
        }
    }

    /// What it did so far.
    pub fn counts(&self) -> &PlacerCounts {
        &self.counts
    }

    /// Profiles waiting now.
    pub fn waiting(&self) -> usize {
        self.waiting.len()
    }

    /// Places the next profiles with the sensor at `mount_sensor` on the mount (a new
    /// calibration); the profiles waiting, taken under the old one, are refused.
    pub fn set_mount_sensor(&mut self, mount_sensor: Isometry3<f64>, out: &mut impl Placed<P>) {
        self.end_pass(out);
        self.track.set_mount_sensor(mount_sensor);
    }

    /// Whether any profile waiting now is one `is` picks.
    pub fn any_waiting(&self, is: impl Fn(&P) -> bool) -> bool {
        self.waiting.iter().any(|(_, p)| is(p))
    }

    /// The poses it places by.
    pub fn track(&self) -> &PoseTrack {
        &self.track
    }

    /// Takes the robot's next pose, then places the waiting profiles it brackets, in the order
    /// they came. A refused pose is counted and returned; the profiles go on waiting.
    pub fn pose(&mut self, pose: MountPose, out: &mut impl Placed<P>) -> Result<(), PoseRefused> {
        if let Err(e) = self.track.push(pose) {
            self.counts.poses_refused += 1;
            return Err(e);
        }
        // The profiles came in time order (a profiler's do); the first still waiting keeps
        // the rest waiting, so their order out is their order in.
        while let Some((t, _)) = self.waiting.front() {
            let at = self.track.at(*t);
            if at == PoseAt::Wait {
                break;
            }
            let (_, p) = self.waiting.pop_front().expect("a front was seen");
            match at {
                PoseAt::Ready(sensor) => {
                    self.counts.placed += 1;
                    self.counts.waited += 1;
                    out.placed(p, &sensor);
                }
                PoseAt::Refused(why) => {
                    self.counts.refuse(why);
                    out.refused(p, why);
                }
                PoseAt::Wait => unreachable!("stopped above"),
            }
        }
        Ok(())
    }

    /// Takes a profile stamped `sensor_ns` on the profiler's clock: placed now if the poses
    /// bracket it, else waiting (the oldest waiting is refused when the wait is full), or
    /// refused.
    pub fn profile(&mut self, sensor_ns: u64, profile: P, out: &mut impl Placed<P>) {
        // Behind a waiting profile it waits too, so profiles leave in the order they came.
        let at = if self.waiting.is_empty() {
            self.track.at(sensor_ns)
        } else {
            PoseAt::Wait
        };
        match at {
            PoseAt::Ready(sensor) => {
                self.counts.placed += 1;
                out.placed(profile, &sensor);
            }
            PoseAt::Refused(why) => {
                self.counts.refuse(why);
                out.refused(profile, why);
            }
            PoseAt::Wait => {
                if self.waiting.len() == self.wait
                    && let Some((_, oldest)) = self.waiting.pop_front()
                {
                    self.counts.refuse(Refused::WaitFull);
                    out.refused(oldest, Refused::WaitFull);
                }
                self.waiting.push_back((sensor_ns, profile));
            }
        }
    }

    /// The pass is over: the profiles still waiting are refused (no later pose came).
    pub fn end_pass(&mut self, out: &mut impl Placed<P>) {
        while let Some((_, p)) = self.waiting.pop_front() {
            self.counts.refuse(Refused::NoLaterPose);
            out.refused(p, Refused::NoLaterPose);
        }
    }
}
