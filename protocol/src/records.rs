//! What a recording holds of each message of the table (`table.rs`): its schema, its record's
//! bytes ([`codec`]) and its time. A new message's record goes here, beside the others.

use crate::codec;
use crate::message::{ChunkRecord, DecodeError, Message, Record};
use crate::{
    AgentStatus, ChunkHeader, DeviationHeader, LayerApplied, LayerCorrection, MountPose,
    PointDeviation, PoseSnapshot, ProfileHeader, ProfilePoint, ScanPoint, StationEvent,
    StationFindings, StationReport, SurfaceFindings,
};

/// A message's record: its codec record and its type name as the schema's; `stamped` when
/// its own `timestamp_ns` is its time, `json` when Foxglove's channels repeat it.
macro_rules! record {
    ($ty:ty, $kind:ident, $text:expr) => {
        impl Record for $ty {
            const SCHEMA_NAME: &'static str = <$ty>::TYPE_NAME;
            const SCHEMA_TEXT: &'static str = $text;
            const FOXGLOVE_JSON: bool = record!(@json $kind);
            fn encode(&self) -> Vec<u8> {
                codec::encode(self)
            }
            fn decode(bytes: &[u8]) -> Result<Self, DecodeError> {
                codec::decode(bytes)
            }
            fn timestamp_ns(&self) -> u64 {
                record!(@time $kind, self)
            }
        }
    };
    (@json json) => { true };
    (@json $other:ident) => { false };
    (@time stamped, $m:expr) => { $m.timestamp_ns };
    (@time $other:ident, $m:expr) => { 0 };
}

record!(
    AgentStatus,
    stamped,
    "asbuilt.AgentStatus v1, postcard: the fields of asbuilt-protocol's AgentStatus in \
             declaration order (points/s, queues, rejects and drops by reason)"
);

record!(
    PoseSnapshot,
    stamped,
    "asbuilt.PoseSnapshot v2, postcard: version u16 (varint, also first), mode u8 \
             (0 flange in base, 1 fixed orientation, 2 scanner in design), attempt u8, \
             station u32, job u64, sequence u64, timestamp_ns u64, translation [f64; 3] m, \
             rotation_xyzw [f64; 4] unit quaternion scalar last, position_sigma f64 m"
);

impl Record for StationEvent {
    const SCHEMA_NAME: &'static str = <StationEvent>::TYPE_NAME;
    const SCHEMA_TEXT: &'static str = "asbuilt.StationEvent v3, postcard: version u16 (varint, \
             also first), kind u8 (0 begin, 1 end), attempt u8 (1 the first try), station u32, \
             job u64, job_started_ns u64 (0: not said), timestamp_ns u64, layer u32, \
             expected_chunks u32, expected_points u64, printed_height f64 m (NaN: not \
             printing), name [u8; 48] with length u8. Records led by 1 or 2 lack job_started_ns.";
    fn encode(&self) -> Vec<u8> {
        codec::encode(self)
    }
    fn decode(bytes: &[u8]) -> Result<Self, DecodeError> {
        codec::decode_or_older::<Self, crate::station::StationEventV2>(bytes, 2)
    }
    fn timestamp_ns(&self) -> u64 {
        self.timestamp_ns
    }
}

record!(
    StationReport,
    json,
    "asbuilt.StationReport v2, postcard: the fields of asbuilt-protocol's \
             StationReport in declaration order (statistics in metres, counts, histogram)"
);

record!(
    StationFindings,
    json,
    "asbuilt.StationFindings v2, postcard: the fields of asbuilt-protocol's \
             StationFindings in declaration order (per-layer width, shift and top height, \
             regions out of tolerance and missing material, each with its expanded \
             uncertainty (k = 2); metres, design frame)"
);

record!(
    LayerCorrection,
    json,
    "asbuilt.LayerCorrection v1, postcard: the fields of asbuilt-protocol's \
             LayerCorrection in declaration order (z offset per layer for the first layers and \
             after, drift per layer, flow factor, path offset; each measured error with its \
             sigma and samples; metres, design frame)"
);

record!(
    LayerApplied,
    stamped,
    "asbuilt.LayerApplied v1, postcard: the fields of asbuilt-protocol's LayerApplied in \
             declaration order (the layer printed and the advice it followed; the z offset, flow \
             factor and path offset the printer applied to it; metres, design frame)"
);

record!(
    SurfaceFindings,
    json,
    "asbuilt.SurfaceFindings v3, postcard: the fields of asbuilt-protocol's \
             SurfaceFindings in declaration order (the standards' keys, the governing gap and \
             the deepest within each table distance per face and direction with the distance \
             between its supports, dimensions and plumb, the largest abrupt offset per face and \
             direction (ACI 117), each with its limit, expanded \
             uncertainty (k = 2) and verdict by the decision rule; metres, design frame)"
);

impl ChunkRecord for ChunkHeader {
    type Point = ScanPoint;
    const SCHEMA_NAME: &'static str = "asbuilt.ScanChunk.v3";
    const SCHEMA_TEXT: &'static str = "asbuilt.ScanChunk v3: layout u16 (varint; 3), then ChunkHeader in postcard { \
             version u16, attempt u16, station u32, job u64, sequence u64, timestamp_ns u64, \
             point_count u32, last u8, _reserved2 [u8; 3] }, then point_count ScanPoints as 20 \
             byte planes of point_count bytes each: plane 4w+j holds byte j (little-endian) of \
             word w of every point, the words being x, y, z (f32 m scanner frame), intensity \
             (f32), then flags u16 (bit 0 invalid), returns u8, _reserved u8. Layout 1 or 2: \
             the points follow the header as a postcard sequence (varint length) of ScanPoint";
    fn encode(&self, points: &[ScanPoint]) -> Vec<u8> {
        codec::encode_scan_chunk(self, points)
    }
    fn decode(bytes: &[u8]) -> Result<(Self, Vec<ScanPoint>), DecodeError> {
        codec::decode_scan_chunk(bytes)
    }
    fn timestamp_ns(&self) -> u64 {
        self.timestamp_ns
    }
}

record!(
    MountPose,
    unstamped,
    "asbuilt.MountPose v1, postcard: version u16 (varint, also first), _reserved [u8; 2], \
             pass u32, job u64, sequence u64, time_ns u64 (robot clock), translation [f64; 3] \
             m and rotation_xyzw [f64; 4] (T_base_mount, unit quaternion scalar last), \
             mount_sensor_translation [f64; 3] m and mount_sensor_rotation_xyzw [f64; 4] \
             (T_mount_sensor from calibration)"
);

impl ChunkRecord for ProfileHeader {
    type Point = ProfilePoint;
    const SCHEMA_NAME: &'static str = "asbuilt.ProfileChunk.v1";
    const SCHEMA_TEXT: &'static str = "asbuilt.ProfileChunk v1, postcard: version u16 (varint), then ProfileHeader { \
             version u16, attempt u16, pass u32, job u64, sequence u64, timestamp_ns u64, \
             point_count u32, profile_count u16, last u8, _reserved u8, sensor_ns [u64; 32] \
             (sensor clock), profile_points [u32; 32] }, then a sequence (varint length) of \
             ProfilePoint { x f32 m along the laser line, z f32 m along the view }, profile \
             after profile";
    fn encode(&self, points: &[ProfilePoint]) -> Vec<u8> {
        codec::encode_profile_chunk(self, points)
    }
    fn decode(bytes: &[u8]) -> Result<(Self, Vec<ProfilePoint>), DecodeError> {
        codec::decode_profile_chunk(bytes)
    }
    fn timestamp_ns(&self) -> u64 {
        self.timestamp_ns
    }
}

impl ChunkRecord for DeviationHeader {
    type Point = PointDeviation;
    const SCHEMA_NAME: &'static str = "asbuilt.DeviationChunk.v1";
    const SCHEMA_TEXT: &'static str = "asbuilt.DeviationChunk v1, postcard: version u16 (varint), then DeviationHeader, \
             then a sequence (varint length) of PointDeviation { position [f64; 3] m design \
             frame, distance f64 m signed (NaN: no match), triangle u32, feature u8, flags u8 }; \
             see asbuilt-protocol's deviation.rs for the header's fields";
    fn encode(&self, points: &[PointDeviation]) -> Vec<u8> {
        codec::encode_deviation_chunk(self, points)
    }
    fn decode(bytes: &[u8]) -> Result<(Self, Vec<PointDeviation>), DecodeError> {
        codec::decode_deviation_chunk(bytes)
    }
    fn timestamp_ns(&self) -> u64 {
        self.timestamp_ns
    }
}
