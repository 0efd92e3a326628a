use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::message::Message;

/// How the robot's pose is to be read: all six degrees of freedom, or the translation alone with
/// the scanner's calibrated orientation (a scanner whose azimuth zero never turns).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum PoseMode {
    /// Translation and rotation of the flange in the robot base frame are both used.
    SixDof = 0,
    /// Only the translation is used; the orientation is the calibrated one (Z+F fixed azimuth).
    FixedOrientation = 1,
    /// The snapshot already is `T_design_scanner` (offline scans, tripod stations).
    DesignScanner = 2,
}

impl PoseMode {
    /// `None` for a value no known sender writes.
    pub fn from_u8(v: u8) -> Option<Self> {
        match v {
            0 => Some(Self::SixDof),
            1 => Some(Self::FixedOrientation),
            2 => Some(Self::DesignScanner),
            _ => None,
        }
    }
}

/// Where the robot held the scanner when a station was scanned: `T_base_flange` from the
/// controller, or `T_design_scanner` directly when `mode` says so.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
#[type_name("asbuilt.PoseSnapshot.v2")]
#[repr(C)]
pub struct PoseSnapshot {
    /// The message's version ([`Message::VERSION`] when written by this build).
    pub version: u16,
    /// A [`PoseMode`] as `u8`; read it with [`PoseSnapshot::mode`].
    pub mode: u8,
    /// The station's attempt this pose places (see [`crate::StationEvent::attempt`]).
    pub attempt: u8,
    /// The station this pose places, as its Begin numbered it.
    pub station: u32,
    /// The job (one print) the station belongs to.
    pub job: u64,
    /// Counts the poses a cell sends, for its own ordering; the agent does not read it.
    pub sequence: u64,
    /// When the controller sampled the pose, nanoseconds since the Unix epoch.
    pub timestamp_ns: u64,
    /// Metres.
    pub translation: [f64; 3],
    /// Unit quaternion, scalar last.
    pub rotation_xyzw: [f64; 4],
    /// One-sigma position uncertainty of the scanner origin, metres (about 1e-3 robot-mounted).
    pub position_sigma: f64,
}

crate::message::message!(PoseSnapshot, "asbuilt.PoseSnapshot.v2", 2, oldest 1);

impl PoseSnapshot {
    /// `None` for a value no known sender writes.
    pub fn mode(&self) -> Option<PoseMode> {
        PoseMode::from_u8(self.mode)
    }

    /// An identity pose of the given mode, with the robot's usual 1 mm position sigma.
    pub fn new(job: u64, station: u32, mode: PoseMode) -> Self {
        Self {
            version: Self::VERSION,
            mode: mode as u8,
            attempt: 1,
            station,
            job,
            sequence: 0,
            timestamp_ns: 0,
            translation: [0.0; 3],
            rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
            position_sigma: 1e-3,
        }
    }
}
