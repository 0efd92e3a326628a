//! A line profiler scanning while printing: each profile is placed by the pose its mount had at
//! the moment the profile was taken, interpolated between the robot's poses that bracket it.
//!
//! Poses come from the robot at its own rate and clock, profiles at theirs: a profile's sensor
//! timestamp plus the configured clock offset is a time on the robot's clock. Between the two
//! poses that bracket it, the mount's translation is interpolated linearly and its rotation by
//! slerp (exact for a constant velocity and turn rate between them; along a curve of radius R
//! the linear chord is off by at most s²/8R for a step s between poses: 0.2 mm/ms steps of
//! 0.8 mm on a 0.5 m curve are 0.16 µm off). A profile with no later pose yet waits; one whose
//! bracketing poses are further apart than the allowed gap, or that would need a pose older
//! than those kept (extrapolation), is refused with its reason. The poses kept are a fixed
//! number, and so are the profiles waiting ([`Placer`]): memory stays flat however long the
//! print, and however late or dead the robot's pose stream.

mod placer;
mod sweep;
mod track;

pub use placer::{Placed, Placer, PlacerCounts};
pub use sweep::{Sweep, SweepParams};
pub use track::{MountPose, PoseAt, PoseRefused, PoseTrack, PoseTrackParams, Refused, interpolate};

#[cfg(test)]
mod tests;
