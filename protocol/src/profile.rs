//! A line profiler's messages: the robot's poses of the sensor's mount, each with the
//! calibrated mount-to-sensor transform, and chunks of profiles, each profile stamped on the
//! sensor's own clock. A pass (one layer's run of profiles) is a station: its Begin and End
//! are [`crate::StationEvent`]s numbered as the pass, its profile chunks count as its chunks.

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::message::Message;

/// A robot pose of the profiler's mount, as the controller sampled it on its own clock.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.MountPose.v1")]
#[repr(C)]
pub struct MountPose {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// Zero; keeps the layout free of padding.
    pub _reserved: [u8; 2],
    /// The pass being printed when the pose was sampled (its layer); informative: poses form
    /// one track across passes.
    pub pass: u32,
    /// The job (one print).
    pub job: u64,
    /// Counts the poses the robot sends, from 0.
    pub sequence: u64,
    /// When the controller sampled the pose, nanoseconds on the robot's clock (the clock the
    /// agent's `[profiler] clock_offset_ns` relates the sensor's to).
    pub time_ns: u64,
    /// The mount in the robot's base frame (`T_base_mount`), metres.
    pub translation: [f64; 3],
    /// Its rotation, unit quaternion, scalar last.
    pub rotation_xyzw: [f64; 4],
    /// The sensor in the mount's frame (`T_mount_sensor`) from calibration, metres: it travels
    /// with each pose so a recording carries what placed its points.
    pub mount_sensor_translation: [f64; 3],
    /// Its rotation, unit quaternion, scalar last.
    pub mount_sensor_rotation_xyzw: [f64; 4],
}

crate::message::message!(MountPose, "asbuilt.MountPose.v1", 1);

/// Required by iceoryx2 to loan a sample; a real pose comes from `new`.
impl Default for MountPose {
    fn default() -> Self {
        Self::new(0, 0, 0, 0)
    }
}

impl MountPose {
    /// Pose `sequence` of a job at robot time `time_ns`, at the base's origin, the sensor at
    /// the mount.
    pub fn new(job: u64, pass: u32, sequence: u64, time_ns: u64) -> Self {
        Self {
            version: Self::VERSION,
            _reserved: [0; 2],
            pass,
            job,
            sequence,
            time_ns,
            translation: [0.0; 3],
            rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
            mount_sensor_translation: [0.0; 3],
            mount_sensor_rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
        }
    }
}

/// Profiles a chunk carries at most: 32 keeps a chunk under 66,000 points at 2,048 a profile,
/// and is the most serde encodes as a fixed array.
pub const MAX_PROFILES_PER_CHUNK: usize = 32;

/// The user header of a profile chunk; the points of its profiles follow, profile after
/// profile, as a `[ProfilePoint]` slice payload.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.ProfileHeader.v1")]
#[repr(C)]
pub struct ProfileHeader {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// The pass's attempt (see [`crate::StationEvent::attempt`]).
    pub attempt: u16,
    /// The pass (a station) the profiles belong to, as its Begin numbered it.
    pub pass: u32,
    /// The job.
    pub job: u64,
    /// Starts at 0 for each pass and counts up by one; gaps and repeats are detected.
    pub sequence: u64,
    /// When the sensor sent the chunk, nanoseconds since the Unix epoch.
    pub timestamp_ns: u64,
    /// Points in the slice that follows: the sum of `profile_points`.
    pub point_count: u32,
    /// Profiles in the chunk, at most [`MAX_PROFILES_PER_CHUNK`].
    pub profile_count: u16,
    /// Set on the last chunk of a pass.
    pub last: u8,
    /// Zero; keeps the layout free of padding.
    pub _reserved: u8,
    /// Each profile's timestamp, nanoseconds on the sensor's clock.
    pub sensor_ns: [u64; MAX_PROFILES_PER_CHUNK],
    /// Each profile's points in the slice, in order.
    pub profile_points: [u32; MAX_PROFILES_PER_CHUNK],
}

crate::message::message!(ProfileHeader, "asbuilt.ProfileHeader.v1", 1);

/// Required by iceoryx2 to loan a sample with this header; a real header comes from `new`.
impl Default for ProfileHeader {
    fn default() -> Self {
        Self::new(0, 0, 0)
    }
}

/// Why a profile chunk's header does not describe its points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ProfileShapeError {
    /// More profiles than a chunk holds.
    #[error("{0} profiles, more than the {MAX_PROFILES_PER_CHUNK} a chunk holds")]
    TooManyProfiles(u16),
    /// The profiles' points do not add up to the points carried.
    #[error("its profiles hold {declared} points but it carries {carried}")]
    PointsDisagree {
        /// The sum of `profile_points`.
        declared: u64,
        /// Points in the slice.
        carried: usize,
    },
}

impl ProfileHeader {
    /// The header of chunk `sequence` of a pass, no profiles yet, not last.
    pub fn new(job: u64, pass: u32, sequence: u64) -> Self {
        Self {
            version: Self::VERSION,
            attempt: 1,
            pass,
            job,
            sequence,
            timestamp_ns: 0,
            point_count: 0,
            profile_count: 0,
            last: 0,
            _reserved: 0,
            sensor_ns: [0; MAX_PROFILES_PER_CHUNK],
            profile_points: [0; MAX_PROFILES_PER_CHUNK],
        }
    }

    /// Adds a profile of `points` points taken at `sensor_ns`; false when the chunk is full.
    pub fn push(&mut self, sensor_ns: u64, points: u32) -> bool {
        let i = self.profile_count as usize;
        if i == MAX_PROFILES_PER_CHUNK {
            return false;
        }
        self.sensor_ns[i] = sensor_ns;
        self.profile_points[i] = points;
        self.profile_count += 1;
        self.point_count += points;
        true
    }

    /// Each profile's timestamp and its range in `points` (`points.len()` points carried),
    /// or why the header does not describe them.
    pub fn profiles(
        &self,
        carried: usize,
    ) -> Result<impl Iterator<Item = (u64, std::ops::Range<usize>)> + '_, ProfileShapeError> {
        let n = self.profile_count as usize;
        if n > MAX_PROFILES_PER_CHUNK {
            return Err(ProfileShapeError::TooManyProfiles(self.profile_count));
        }
        let declared: u64 = self.profile_points[..n].iter().map(|&c| c as u64).sum();
        if declared != carried as u64 {
            return Err(ProfileShapeError::PointsDisagree { declared, carried });
        }
        let mut start = 0usize;
        Ok((0..n).map(move |i| {
            let end = start + self.profile_points[i] as usize;
            let r = start..end;
            start = end;
            (self.sensor_ns[i], r)
        }))
    }
}

/// One point of a profile in the sensor's frame: along the laser line (x) and along the view
/// (z); the laser's plane is the sensor's y = 0. Metres; NaN where the line had no return.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.ProfilePoint.v1")]
#[repr(C)]
pub struct ProfilePoint {
    /// Along the laser line, metres.
    pub x: f32,
    /// Along the view, metres.
    pub z: f32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profiles_split_the_points_as_the_header_says() {
        let mut h = ProfileHeader::new(1, 2, 0);
        assert!(h.push(100, 3) && h.push(200, 0) && h.push(300, 2));
        let ranges: Vec<_> = h.profiles(5).unwrap().collect();
        assert_eq!(ranges, vec![(100, 0..3), (200, 3..3), (300, 3..5)]);
        assert_eq!(
            h.profiles(4).err(),
            Some(ProfileShapeError::PointsDisagree {
                declared: 5,
                carried: 4
            })
        );
        h.profile_count = 40;
        assert_eq!(
            h.profiles(5).err(),
            Some(ProfileShapeError::TooManyProfiles(40))
        );
        let mut full = ProfileHeader::new(1, 2, 0);
        for i in 0..MAX_PROFILES_PER_CHUNK {
            assert!(full.push(i as u64, 1));
        }
        assert!(!full.push(99, 1), "a full chunk takes no more");
    }
}
