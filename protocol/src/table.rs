//! The message table: every stream between the cell and the agent, declared once. From each
//! row follow the service's name, both sides' ports ([`AgentPorts`], [`CellPorts`]), the
//! recording's channel ([`Channel`]), its decoded form ([`Recorded`]) and, for the agent's
//! per-station results, Foxglove's JSON channel.
//!
//! A row reads: the channel, the port's field, the service under the cell's prefix, the kind
//! of service ([`crate::services`]: who sends it and how it is queued), then the recorded
//! variant and what it holds. Messages come first, then chunk streams (a header and points).
//! The payload's [`Record`](crate::Record) or [`ChunkRecord`](crate::ChunkRecord) (in
//! `records.rs`) says how it is recorded.
//!
//! Adding a message: its type (a file of its own, with `message!`), its record in
//! `records.rs`, one row here, and its handling in the agent. ARCHITECTURE.md says the same;
//! `tests::a_row_is_a_message_end_to_end` adds one that way.

use crate::{
    AgentStatus, ChunkHeader, DeviationHeader, LayerApplied, LayerCorrection, MAX_FINDINGS_BYTES,
    MAX_SURVEY_BYTES, MountPose, PointDeviation, PoseSnapshot, ProfileHeader, ProfilePoint,
    ScanPoint, StationEvent, StationFindings, StationReport, SurfaceFindings,
};

/// The type a recorded variant holds: boxed when the row says so (large messages keep
/// [`Recorded`] small).
macro_rules! held {
    (boxed $t:ty) => { Box<$t> };
    ($t:ty) => { $t };
}

/// A decoded message as its recorded variant holds it.
macro_rules! hold {
    (boxed $e:expr) => {
        Box::new($e)
    };
    ($e:expr) => {
        $e
    };
}

/// Makes the types of a message table: `ServiceNames`, `Channel`, `Recorded`, `AgentPorts` and
/// `CellPorts`. Invoked once below for the cell's services; a test invokes it with a row more.
macro_rules! messages {
    (
        messages {
            $( $(#[$doc:meta])* $ch:ident $field:ident $service:literal : $kind:ty
                => $var:ident($ty:ty) $($boxed:ident)? ; )*
        }
        chunks {
            $( $(#[$cdoc:meta])* $cch:ident $cfield:ident $cservice:literal : $ckind:ty
                => $cvar:ident($h:ty, [$p:ty]) $($cboxed:ident)? ; )*
        }
    ) => {
        /// The names of a cell's services: `PREFIX/` and the service of each row, and the two
        /// events that wake either side.
        #[derive(Debug, Clone)]
        pub struct ServiceNames {
            /// The prefix every name starts with.
            pub prefix: String,
            $( $(#[$doc])* pub $field: String, )*
            $( $(#[$cdoc])* pub $cfield: String, )*
            /// `PREFIX/agent/inbox`: the event that wakes the agent.
            pub inbox: String,
            /// `PREFIX/agent/outbox`: the event that wakes the cell.
            pub outbox: String,
        }

        impl ServiceNames {
            /// The names under `prefix`.
            pub fn new(prefix: &str) -> Self {
                Self {
                    prefix: prefix.to_string(),
                    $( $field: format!("{prefix}/{}", $service), )*
                    $( $cfield: format!("{prefix}/{}", $cservice), )*
                    inbox: format!("{prefix}/agent/inbox"),
                    outbox: format!("{prefix}/agent/outbox"),
                }
            }
        }

        /// The channels of a recording, one per service.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub enum Channel {
            $( $(#[$doc])* $ch, )*
            $( $(#[$cdoc])* $cch, )*
        }

        impl Channel {
            /// Every channel, in the order a recording declares them.
            pub const ALL: [Channel; [$(stringify!($ch),)* $(stringify!($cch),)*].len()] =
                [$(Channel::$ch,)* $(Channel::$cch,)*];

            /// The service under the cell's prefix, e.g. `robot/poses`.
            pub fn service(self) -> &'static str {
                match self {
                    $( Channel::$ch => $service, )*
                    $( Channel::$cch => $cservice, )*
                }
            }

            /// The MCAP topic of the channel: the service without its prefix
            /// (`/robot/poses`).
            pub fn topic(self) -> &'static str {
                match self {
                    $( Channel::$ch => concat!("/", $service), )*
                    $( Channel::$cch => concat!("/", $cservice), )*
                }
            }

            /// The channel of an MCAP topic; `None` for a topic asbuilt does not write.
            pub fn from_topic(topic: &str) -> Option<Self> {
                Self::ALL.into_iter().find(|c| c.topic() == topic)
            }

            /// Whether the cell sends it: an input of the agent, what a replay sends again.
            pub fn is_input(self) -> bool {
                match self {
                    $( Channel::$ch => <$kind as $crate::services::Stream>::FROM_CELL, )*
                    $( Channel::$cch => <$ckind as $crate::services::Stream>::FROM_CELL, )*
                }
            }

            /// Whether it is one of the agent's per-station results, which the cell or the
            /// printer acts on: recorded and flushed before it is sent.
            pub fn is_per_station(self) -> bool {
                match self {
                    $( Channel::$ch => <$kind as $crate::services::Stream>::PER_STATION, )*
                    $( Channel::$cch => <$ckind as $crate::services::Stream>::PER_STATION, )*
                }
            }

            /// The MCAP schema name of the channel's messages.
            pub fn schema_name(self) -> &'static str {
                match self {
                    $( Channel::$ch => <$ty as $crate::Record>::SCHEMA_NAME, )*
                    $( Channel::$cch => <$h as $crate::ChunkRecord>::SCHEMA_NAME, )*
                }
            }

            /// The schema data of the channel: its fields, in encoding order, with units.
            pub fn schema_text(self) -> &'static str {
                match self {
                    $( Channel::$ch => <$ty as $crate::Record>::SCHEMA_TEXT, )*
                    $( Channel::$cch => <$h as $crate::ChunkRecord>::SCHEMA_TEXT, )*
                }
            }

            /// Whether Foxglove's channels repeat it as JSON.
            pub fn foxglove_json(self) -> bool {
                match self {
                    $( Channel::$ch => <$ty as $crate::Record>::FOXGLOVE_JSON, )*
                    $( Channel::$cch => false, )*
                }
            }
        }

        /// One decoded message of a recording.
        #[derive(Debug, Clone, PartialEq)]
        pub enum Recorded {
            $( $(#[$doc])* $var(held!($($boxed)? $ty)), )*
            $( $(#[$cdoc])* $cvar(held!($($cboxed)? $h), Vec<$p>), )*
        }

        impl Recorded {
            /// The channel the message is recorded on.
            pub fn channel(&self) -> Channel {
                match self {
                    $( Recorded::$var(_) => Channel::$ch, )*
                    $( Recorded::$cvar(..) => Channel::$cch, )*
                }
            }

            /// A record of `channel` back into its message.
            pub fn decode(channel: Channel, bytes: &[u8]) -> Result<Self, $crate::DecodeError> {
                Ok(match channel {
                    $( Channel::$ch => Recorded::$var(hold!($($boxed)?
                        <$ty as $crate::Record>::decode(bytes)?)), )*
                    $( Channel::$cch => {
                        let (h, p) = <$h as $crate::ChunkRecord>::decode(bytes)?;
                        Recorded::$cvar(hold!($($cboxed)? h), p)
                    } )*
                })
            }

            /// The message as its channel records it.
            pub fn encode(&self) -> Vec<u8> {
                match self {
                    $( Recorded::$var(m) => <$ty as $crate::Record>::encode(m), )*
                    $( Recorded::$cvar(h, p) => <$h as $crate::ChunkRecord>::encode(h, p), )*
                }
            }

            /// The message's own timestamp, nanoseconds since the Unix epoch (0 when it has
            /// none).
            pub fn timestamp_ns(&self) -> u64 {
                match self {
                    $( Recorded::$var(m) => <$ty as $crate::Record>::timestamp_ns(m), )*
                    $( Recorded::$cvar(h, _) => <$h as $crate::ChunkRecord>::timestamp_ns(h), )*
                }
            }

            /// The message as JSON, when Foxglove's channels repeat it.
            pub fn foxglove_json(&self) -> Option<Vec<u8>> {
                if !self.channel().foxglove_json() {
                    return None;
                }
                match self {
                    $( Recorded::$var(m) => serde_json::to_vec(m).ok(), )*
                    $( Recorded::$cvar(..) => None, )*
                }
            }
        }

        /// The agent's side: it owns the services.
        pub struct AgentPorts {
            $( $(#[$doc])* pub $field: <$kind as $crate::services::Stream>::AgentPort, )*
            $( $(#[$cdoc])* pub $cfield: <$ckind as $crate::services::Stream>::AgentPort, )*
            /// Wakes the agent when an input arrives.
            pub inbox: iceoryx2::port::listener::Listener<$crate::services::Ipc>,
            /// Wakes the cell when an output is sent.
            pub outbox: iceoryx2::port::notifier::Notifier<$crate::services::Ipc>,
            /// Deviation chunks a full subscriber queue did not take.
            pub deviation_drops: std::sync::Arc<std::sync::atomic::AtomicU64>,
            /// Reports, findings, advice and surface judgements a full subscriber queue did
            /// not take.
            pub report_drops: std::sync::Arc<std::sync::atomic::AtomicU64>,
        }

        impl AgentPorts {
            /// Creates (or opens) every service under `names` with the agent's queue sizes,
            /// in the table's order (the health first: a second agent fails there).
            pub fn create(
                node: &iceoryx2::node::Node<$crate::services::Ipc>,
                names: &ServiceNames,
                queues: $crate::services::QueueSizes,
            ) -> Result<Self, $crate::services::IpcError> {
                use $crate::services::Stream;
                let setup = $crate::services::Setup::new(node, &names.prefix, queues);
                $( let $field = <$kind>::agent_port(&setup, &names.$field)?; )*
                $( let $cfield = <$ckind>::agent_port(&setup, &names.$cfield)?; )*
                Ok(Self {
                    $( $field, )*
                    $( $cfield, )*
                    inbox: setup.inbox(&names.inbox)?,
                    outbox: setup.outbox(&names.outbox)?,
                    deviation_drops: setup.deviation_drops,
                    report_drops: setup.report_drops,
                })
            }
        }

        /// The cell's side: what a robot controller, scanner driver and job control use to
        /// talk to a running agent (and what `asbuilt publish`, the simulator and the tests
        /// use).
        pub struct CellPorts {
            $( $(#[$doc])* pub $field: <$kind as $crate::services::Stream>::CellPort, )*
            $( $(#[$cdoc])* pub $cfield: <$ckind as $crate::services::Stream>::CellPort, )*
            /// Wakes the agent.
            pub inbox: iceoryx2::port::notifier::Notifier<$crate::services::Ipc>,
            /// Wakes the cell when the agent sent something.
            pub outbox: iceoryx2::port::listener::Listener<$crate::services::Ipc>,
        }

        impl CellPorts {
            /// Opens every service of a running agent once, in the table's order (the health
            /// first: it exists only while an agent is up).
            pub fn try_open(
                node: &iceoryx2::node::Node<$crate::services::Ipc>,
                names: &ServiceNames,
                max_points_per_chunk: usize,
            ) -> Result<Self, $crate::services::IpcError> {
                use $crate::services::Stream;
                let m = max_points_per_chunk;
                Ok(Self {
                    $( $field: <$kind>::cell_port(node, &names.$field, m)?, )*
                    $( $cfield: <$ckind>::cell_port(node, &names.$cfield, m)?, )*
                    inbox: $crate::services::cell_inbox(node, &names.inbox)?,
                    outbox: $crate::services::cell_outbox(node, &names.outbox)?,
                })
            }
        }
    };
}
#[cfg(test)]
pub(crate) use messages;

use crate::services::{
    ANSWER_HISTORY, Control, DeviationChunks, Encoded, Health, PerStation, ProfileChunks,
    ScanChunks as ScanChunkStream,
};

messages! {
    messages {
        /// `agent/status`: the agent's health ([`AgentStatus`]), agent to cell.
        Status status "agent/status": Health => Status(AgentStatus) boxed;
        /// `robot/poses`: robot poses ([`PoseSnapshot`]), cell to agent.
        Poses poses "robot/poses": Control<PoseSnapshot> => Pose(PoseSnapshot);
        /// `robot/mount_poses`: a line profiler's mount poses ([`MountPose`]), cell to agent.
        MountPoses mount_poses "robot/mount_poses": Control<MountPose> => MountPose(MountPose);
        /// `job/stations`: a station's Begin and End ([`StationEvent`]), cell to agent.
        StationEvents stations "job/stations": Control<StationEvent> => Event(StationEvent);
        /// `printer/applied`: what the printer applied to each layer it printed
        /// ([`LayerApplied`]), cell to agent.
        Applied applied "printer/applied": Control<LayerApplied, ANSWER_HISTORY>
            => Applied(LayerApplied);
        /// `agent/reports`: station reports ([`StationReport`]), agent to cell.
        Reports reports "agent/reports": PerStation<StationReport>
            => Report(StationReport) boxed;
        /// `agent/findings`: a station's findings ([`StationFindings`], encoded behind their
        /// header on the wire), agent to cell.
        Findings findings "agent/findings": Encoded<MAX_FINDINGS_BYTES>
            => Findings(StationFindings) boxed;
        /// `agent/corrections`: advice for the layers still to print ([`LayerCorrection`]),
        /// agent to cell.
        Corrections corrections "agent/corrections": PerStation<LayerCorrection>
            => Correction(LayerCorrection) boxed;
        /// `agent/surface`: flatness, dimensions and plumb judged by a standard
        /// ([`SurfaceFindings`], encoded behind their header on the wire), agent to cell.
        Surface surface "agent/surface": Encoded<MAX_SURVEY_BYTES>
            => Surface(SurfaceFindings) boxed;
    }
    chunks {
        /// `scanner/chunks`: scan chunks ([`ChunkHeader`] and points), cell to agent.
        ScanChunks chunks "scanner/chunks": ScanChunkStream
            => Chunk(ChunkHeader, [ScanPoint]);
        /// `scanner/profiles`: a line profiler's profile chunks ([`ProfileHeader`] and
        /// points), cell to agent.
        Profiles profiles "scanner/profiles": ProfileChunks
            => Profiles(ProfileHeader, [ProfilePoint]) boxed;
        /// `agent/deviations`: deviation chunks ([`DeviationHeader`] and one deviation per
        /// scan point), agent to cell.
        Deviations deviations "agent/deviations": DeviationChunks
            => Deviations(DeviationHeader, [PointDeviation]);
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use iceoryx2::prelude::*;
    use serde::{Deserialize, Serialize};

    use crate::services::{Control, DeviationChunks, Health, Ipc, PerStation, QueueSizes};
    use crate::{
        AgentStatus, ChunkHeader, DecodeError, DeviationHeader, PointDeviation, PoseSnapshot,
        Record, ScanPoint, codec,
    };

    /// A new message, declared as a newcomer would: its type with `message!`, its record.
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ZeroCopySend)]
    #[type_name("asbuilt.Ping.v1")]
    #[repr(C)]
    pub struct Ping {
        version: u16,
        _reserved: [u8; 6],
        count: u64,
    }
    crate::message::message!(Ping, "asbuilt.Ping.v1", 1);

    impl Record for Ping {
        const SCHEMA_NAME: &'static str = "asbuilt.Ping.v1";
        const SCHEMA_TEXT: &'static str = "asbuilt.Ping v1, postcard: version u16, count u64";
        fn encode(&self) -> Vec<u8> {
            codec::encode(self)
        }
        fn decode(bytes: &[u8]) -> Result<Self, DecodeError> {
            codec::decode(bytes)
        }
    }

    // The table as it is, trimmed to a few rows, and one row more. (Some of what it makes is
    // not used here.)
    #[allow(dead_code)]
    mod table {
        use super::*;
        super::super::messages! {
            messages {
                /// Health.
                Status status "agent/status": Health => Status(AgentStatus) boxed;
                /// Poses.
                Poses poses "robot/poses": Control<PoseSnapshot> => Pose(PoseSnapshot);
                /// The new message, agent to cell.
                Pings pings "agent/pings": PerStation<Ping> => Ping(Ping);
            }
            chunks {
                /// Deviations.
                Deviations deviations "agent/deviations": DeviationChunks
                    => Deviations(DeviationHeader, [PointDeviation]);
            }
        }
    }
    use table::*;

    #[test]
    fn a_row_is_a_message_end_to_end() {
        // Its name, channel and record.
        let prefix = format!("asbuilt-table-test/{}", std::process::id());
        let names = ServiceNames::new(&prefix);
        assert_eq!(names.pings, format!("{prefix}/agent/pings"));
        assert_eq!(Channel::from_topic("/agent/pings"), Some(Channel::Pings));
        assert_eq!(Channel::Pings.schema_name(), "asbuilt.Ping.v1");
        assert!(!Channel::Pings.is_input() && Channel::Poses.is_input());
        assert!(Channel::Pings.is_per_station() && !Channel::Status.is_per_station());
        assert_eq!(Channel::ALL.len(), 4);
        let ping = Ping {
            version: 1,
            _reserved: [0; 6],
            count: 7,
        };
        let bytes = Recorded::Ping(ping).encode();
        assert_eq!(
            Recorded::decode(Channel::Pings, &bytes),
            Ok(Recorded::Ping(ping))
        );
        assert!(Recorded::decode(Channel::Poses, &bytes).is_err());

        // Both sides' ports: the agent sends it, the cell gets it.
        let node = NodeBuilder::new().create::<Ipc>().unwrap();
        let queues = QueueSizes {
            max_points_per_chunk: 4,
            chunk_queue: 2,
            pending_chunks: 1,
            lent_chunks: 0,
        };
        let agent = AgentPorts::create(&node, &names, queues).unwrap();
        let cell = CellPorts::try_open(&node, &names, 4).unwrap();
        agent.pings.send_copy(ping).unwrap();
        let got = cell.pings.receive().unwrap().map(|s| *s.payload());
        assert_eq!(got, Some(ping));
        // The rest of the table is there too: a second agent on the prefix is refused.
        assert!(matches!(
            AgentPorts::create(&node, &names, queues),
            Err(crate::services::IpcError::AlreadyServed { .. })
        ));
        let _ = (ChunkHeader::default(), ScanPoint::new(0.0, 0.0, 0.0));
        std::thread::sleep(Duration::from_millis(1));
    }
}
