//! How each kind of service is made: what an agent creates and a cell opens, with which
//! queues and which delivery. The message table (`table.rs`) names a kind for each service;
//! the ports of both sides follow from it. See `ipc.rs` for the delivery rules these settings
//! implement.

use std::marker::PhantomData;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{BackpressureAction, BackpressureInfo};
use iceoryx2::prelude::*;

use crate::{
    AgentStatus, ChunkHeader, DeviationHeader, FindingsHeader, PointDeviation, ProfileHeader,
    ProfilePoint, ScanPoint,
};

/// The iceoryx2 service kind: inter-process, shared memory.
pub type Ipc = ipc::Service;

/// A received scan chunk, still in shared memory.
pub type ChunkSample = iceoryx2::sample::Sample<Ipc, [ScanPoint], ChunkHeader>;

/// A received profile chunk, still in shared memory.
pub type ProfileSample = iceoryx2::sample::Sample<Ipc, [ProfilePoint], ProfileHeader>;
/// A received deviation chunk, still in shared memory.
pub type DeviationSample = iceoryx2::sample::Sample<Ipc, [PointDeviation], DeviationHeader>;

/// What iceoryx2 said when a call failed.
pub type IceoryxCause = Box<dyn std::error::Error + Send + Sync + 'static>;

/// A service, port or node could not be made or used; each case says which and what to do.
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    /// An iceoryx2 call failed; `what` names the call.
    #[error("{what}")]
    Iceoryx {
        /// What was being done.
        what: String,
        /// iceoryx2's error.
        #[source]
        source: IceoryxCause,
    },
    /// A service exists with settings other than this build's.
    #[error(
        "cannot open or create service {service}. If an earlier agent or publisher used other \
         settings on prefix {prefix:?}, stop every asbuilt process on that prefix (or choose \
         another services.prefix) and start the agent first"
    )]
    Incompatible {
        /// The service.
        service: String,
        /// The prefix of the cell's services.
        prefix: String,
        /// iceoryx2's error.
        #[source]
        source: IceoryxCause,
    },
    /// A second agent on the same services.
    #[error(
        "another asbuilt-agent is already serving prefix {prefix:?}: stop it first, or give \
         this one another services.prefix"
    )]
    AlreadyServed {
        /// The prefix of the cell's services.
        prefix: String,
        /// iceoryx2's error.
        #[source]
        source: IceoryxCause,
    },
    /// The agent's services exist, but its status publisher is not up (yet, or any more).
    #[error("the agent's status publisher is not up")]
    AgentNotUp,
    /// No agent appeared on the prefix within the wait.
    #[error(
        "no asbuilt-agent is serving prefix {prefix:?} (waited {waited_s:.1} s). Start one with \
         `asbuilt-agent --config agent.toml` and check that its services.prefix matches; the \
         last try said"
    )]
    NoAgent {
        /// The prefix of the cell's services.
        prefix: String,
        /// How long the cell waited, seconds.
        waited_s: f64,
        /// Why the last try failed.
        #[source]
        last: Box<IpcError>,
    },
    /// A message reached no agent within [`DELIVERY_DEADLINE`].
    #[error(
        "{what} not delivered: no agent took it within {deadline_s} s. Check that asbuilt-agent \
         is running and printing its health lines"
    )]
    NotTaken {
        /// The message.
        what: String,
        /// The deadline, seconds.
        deadline_s: u64,
    },
    /// A message could not be sent (a full agent queue is waited for up to the deadline).
    #[error(
        "{what} not delivered (a full agent queue is waited for up to {deadline_s} s). Check \
         that asbuilt-agent is running and printing its health lines"
    )]
    NotDelivered {
        /// The message.
        what: String,
        /// The deadline, seconds.
        deadline_s: u64,
        /// iceoryx2's error.
        #[source]
        source: IceoryxCause,
    },
}

impl IpcError {
    /// iceoryx2 failed at `what` with `e`.
    pub fn iceoryx(what: impl std::fmt::Display, e: impl Into<IceoryxCause>) -> Self {
        Self::Iceoryx {
            what: what.to_string(),
            source: e.into(),
        }
    }
}

pub(crate) fn service_name(s: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(s)
        .map_err(|e| IpcError::iceoryx(format!("{s:?} is not a valid service name"), e))
}

/// Sizes of the agent's queues and samples.
#[derive(Debug, Clone, Copy)]
pub struct QueueSizes {
    /// Points per chunk sample, at most.
    pub max_points_per_chunk: usize,
    /// Scan chunks a subscriber queues.
    pub chunk_queue: usize,
    /// Chunks held while their station's pose has not arrived.
    pub pending_chunks: usize,
    /// Chunks the agent's recorder may keep borrowed while its writer reads them where they
    /// arrived.
    pub lent_chunks: usize,
}

/// How many ports, nodes and queued samples the services admit (the chunk queue is the
/// agent's `[limits]`).
struct Admits {
    /// Publishers of an input (robot, scanner, job control).
    input_publishers: usize,
    /// Subscribers of an input: the agent plus a recorder or monitor.
    input_subscribers: usize,
    /// Subscribers of an output.
    output_subscribers: usize,
    /// Deviation chunks a subscriber queues.
    deviation_queue: usize,
    /// Per-station results a subscriber queues, and how many the history keeps.
    report_queue: usize,
    report_history: usize,
    /// Poses and station events a subscriber queues.
    small_queue: usize,
    /// Processes on one service.
    nodes: usize,
}

const ADMITS: Admits = Admits {
    input_publishers: 4,
    input_subscribers: 2,
    output_subscribers: 4,
    deviation_queue: 8,
    report_queue: 64,
    report_history: 16,
    small_queue: 64,
    nodes: 16,
};

/// The latest station event and pose are kept for a subscriber that connects late: an agent
/// started again while a station sends learns that station's Begin and pose.
pub const CONTROL_HISTORY: usize = 1;

/// The printer's answers kept for an agent that connects late: more than the layers printed
/// between two scans, so an agent killed while the printer answered learns them all.
pub const ANSWER_HISTORY: usize = 64;

/// How long a chunk publisher waits for a full agent queue before it reports the agent stuck.
pub const DELIVERY_DEADLINE: std::time::Duration = std::time::Duration::from_secs(10);

/// What creating the agent's ports needs: its node, the prefix for errors, its queue sizes and
/// the counters of what full subscriber queues did not take.
pub struct Setup<'a> {
    /// The agent's node.
    pub node: &'a Node<Ipc>,
    /// The prefix of the cell's services.
    pub prefix: &'a str,
    /// The agent's queue sizes.
    pub queues: QueueSizes,
    /// Deviation chunks a full subscriber queue did not take.
    pub deviation_drops: Arc<AtomicU64>,
    /// Reports (and findings, advice, surface judgements) a full subscriber queue did not take.
    pub report_drops: Arc<AtomicU64>,
}

impl<'a> Setup<'a> {
    /// The agent's setup on `node` with queues `queues`, counters at zero.
    pub fn new(node: &'a Node<Ipc>, prefix: &'a str, queues: QueueSizes) -> Self {
        Self {
            node,
            prefix,
            queues,
            deviation_drops: Arc::default(),
            report_drops: Arc::default(),
        }
    }

    /// The error for a service that exists with settings other than this build's.
    fn incompatible(&self, service: &str, source: impl Into<IceoryxCause>) -> IpcError {
        IpcError::Incompatible {
            service: service.to_string(),
            prefix: self.prefix.to_string(),
            source: source.into(),
        }
    }

    fn builder(&self, name: &str) -> Result<iceoryx2::service::builder::Builder<Ipc>, IpcError> {
        Ok(self.node.service_builder(&service_name(name)?))
    }

    /// The agent's inbox: the event that wakes it when an input arrives.
    pub fn inbox(&self, name: &str) -> Result<Listener<Ipc>, IpcError> {
        self.builder(name)?
            .event()
            .max_notifiers(ADMITS.input_publishers * 3)
            .max_listeners(2)
            .max_nodes(ADMITS.nodes)
            .open_or_create()
            .map_err(|e| self.incompatible(name, e))?
            .listener_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("cannot listen on the agent inbox", e))
    }

    /// The agent's outbox: the event that wakes the cell when an output is sent.
    pub fn outbox(&self, name: &str) -> Result<Notifier<Ipc>, IpcError> {
        self.builder(name)?
            .event()
            .max_notifiers(2)
            .max_listeners(ADMITS.output_subscribers * 2)
            .max_nodes(ADMITS.nodes)
            .open_or_create()
            .map_err(|e| self.incompatible(name, e))?
            .notifier_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("cannot notify on the agent outbox", e))
    }
}

type EventService = iceoryx2::service::port_factory::event::PortFactory<Ipc>;

/// An event service of a running agent.
fn open_event(node: &Node<Ipc>, name: &str) -> Result<EventService, IpcError> {
    node.service_builder(&service_name(name)?)
        .event()
        .open()
        .map_err(|e| IpcError::iceoryx(name, e))
}

/// The cell's end of the agent's inbox.
pub fn cell_inbox(node: &Node<Ipc>, name: &str) -> Result<Notifier<Ipc>, IpcError> {
    let service = open_event(node, name)?;
    let notifier = service.notifier_builder().create();
    notifier.map_err(|e| IpcError::iceoryx("cannot notify the agent", e))
}

/// The cell's end of the agent's outbox.
pub fn cell_outbox(node: &Node<Ipc>, name: &str) -> Result<Listener<Ipc>, IpcError> {
    let service = open_event(node, name)?;
    let listener = service.listener_builder().create();
    listener.map_err(|e| IpcError::iceoryx("cannot listen on the agent outbox", e))
}

/// A kind of service: who sends, and each side's port with its settings.
pub trait Stream {
    /// Whether the cell sends it (an input of the agent; what a replay sends again).
    const FROM_CELL: bool;
    /// Whether it is one of the agent's per-station results, which the cell or the printer
    /// acts on: recorded and flushed before it is sent, and kept in the service's history.
    const PER_STATION: bool = false;
    /// The agent's port.
    type AgentPort;
    /// The cell's port.
    type CellPort;
    /// Creates (or opens) the service `name` and the agent's port on it.
    fn agent_port(setup: &Setup<'_>, name: &str) -> Result<Self::AgentPort, IpcError>;
    /// Opens the service `name` of a running agent and the cell's port on it; chunk publishers
    /// are sized for `max_points_per_chunk`.
    fn cell_port(
        node: &Node<Ipc>,
        name: &str,
        max_points_per_chunk: usize,
    ) -> Result<Self::CellPort, IpcError>;
}

/// The agent's health: one publisher per prefix, so a second agent fails at start; the cell
/// opens it first, since it exists only while an agent is up.
pub struct Health;

/// A small input of fixed-size messages (poses, station events): never overflowing, so the
/// publisher is held back rather than a message lost; the latest `HISTORY` are kept for a
/// subscriber that connects late (an agent started again while a station sends learns its
/// Begin and pose; the printer's answers since the last scan, sent while it was down).
pub struct Control<T, const HISTORY: usize = CONTROL_HISTORY>(PhantomData<T>);

/// Chunks of an input, a header `H` and a slice of `P` (scan chunks, profile chunks): a full
/// agent queue holds the publisher back (never drops), and a station's chunks waiting for
/// their pose stay borrowed.
pub struct InputChunks<H, P>(PhantomData<(H, P)>);

/// Scan chunks ([`ChunkHeader`] and [`ScanPoint`]s).
pub type ScanChunks = InputChunks<ChunkHeader, ScanPoint>;

/// A line profiler's chunks ([`ProfileHeader`] and [`ProfilePoint`]s).
pub type ProfileChunks = InputChunks<ProfileHeader, ProfilePoint>;

/// Deviation chunks: what a full subscriber does not take is dropped and counted, never
/// waited for.
pub struct DeviationChunks;

/// One fixed-size message per station (reports, advice): a late subscriber gets the latest
/// from the history; a full subscriber queue drops and counts, never makes the agent wait.
pub struct PerStation<T>(PhantomData<T>);

/// One encoded message per station behind a [`FindingsHeader`] (findings, the surface's
/// judgement), in samples of up to `MAX` bytes, kept and dropped as [`PerStation`].
pub struct Encoded<const MAX: usize>;

impl Stream for Health {
    const FROM_CELL: bool = false;
    type AgentPort = Publisher<Ipc, AgentStatus, ()>;
    type CellPort = Subscriber<Ipc, AgentStatus, ()>;

    fn agent_port(setup: &Setup<'_>, name: &str) -> Result<Self::AgentPort, IpcError> {
        setup
            .builder(name)?
            .publish_subscribe::<AgentStatus>()
            .max_publishers(1)
            .max_subscribers(ADMITS.output_subscribers)
            .max_nodes(ADMITS.nodes)
            .history_size(1)
            .subscriber_max_buffer_size(4)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(|e| setup.incompatible(name, e))?
            .publisher_builder()
            .create()
            .map_err(|e| IpcError::AlreadyServed {
                prefix: setup.prefix.to_string(),
                source: e.into(),
            })
    }

    fn cell_port(node: &Node<Ipc>, name: &str, _: usize) -> Result<Self::CellPort, IpcError> {
        let service = node
            .service_builder(&service_name(name)?)
            .publish_subscribe::<AgentStatus>()
            .open()
            .map_err(|e| IpcError::iceoryx(name, e))?;
        if service.dynamic_config().number_of_publishers() == 0 {
            return Err(IpcError::AgentNotUp);
        }
        service
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("cannot subscribe to agent status", e))
    }
}

impl<T: std::fmt::Debug + ZeroCopySend + 'static, const HISTORY: usize> Stream
    for Control<T, HISTORY>
{
    const FROM_CELL: bool = true;
    type AgentPort = Subscriber<Ipc, T, ()>;
    type CellPort = Publisher<Ipc, T, ()>;

    fn agent_port(setup: &Setup<'_>, name: &str) -> Result<Self::AgentPort, IpcError> {
        setup
            .builder(name)?
            .publish_subscribe::<T>()
            .max_publishers(ADMITS.input_publishers)
            .max_subscribers(ADMITS.input_subscribers)
            .max_nodes(ADMITS.nodes)
            .subscriber_max_buffer_size(ADMITS.small_queue)
            .history_size(HISTORY)
            .enable_safe_overflow(false)
            .open_or_create()
            .map_err(|e| setup.incompatible(name, e))?
            .subscriber_builder()
            .buffer_size(ADMITS.small_queue)
            .create()
            .map_err(|e| IpcError::iceoryx(format!("cannot subscribe to {name}"), e))
    }

    fn cell_port(node: &Node<Ipc>, name: &str, _: usize) -> Result<Self::CellPort, IpcError> {
        node.service_builder(&service_name(name)?)
            .publish_subscribe::<T>()
            .open()
            .map_err(|e| IpcError::iceoryx(name, e))?
            .publisher_builder()
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .set_backpressure_handler(deliver_or_fail)
            .create()
            .map_err(|e| IpcError::iceoryx(format!("cannot publish on {name}"), e))
    }
}

impl<H, P> Stream for InputChunks<H, P>
where
    H: std::fmt::Debug + Default + ZeroCopySend + 'static,
    P: std::fmt::Debug + Default + ZeroCopySend + 'static,
{
    const FROM_CELL: bool = true;
    type AgentPort = Subscriber<Ipc, [P], H>;
    type CellPort = Publisher<Ipc, [P], H>;

    fn agent_port(setup: &Setup<'_>, name: &str) -> Result<Self::AgentPort, IpcError> {
        let q = setup.queues;
        setup
            .builder(name)?
            .publish_subscribe::<[P]>()
            .user_header::<H>()
            .max_publishers(ADMITS.input_publishers)
            .max_subscribers(ADMITS.input_subscribers)
            .max_nodes(ADMITS.nodes)
            .history_size(0)
            .subscriber_max_buffer_size(q.chunk_queue)
            .subscriber_max_borrowed_samples(q.pending_chunks + q.lent_chunks + 2)
            .enable_safe_overflow(false)
            .open_or_create()
            .map_err(|e| setup.incompatible(name, e))?
            .subscriber_builder()
            .buffer_size(q.chunk_queue)
            .create()
            .map_err(|e| IpcError::iceoryx(format!("cannot subscribe to {name}"), e))
    }

    fn cell_port(
        node: &Node<Ipc>,
        name: &str,
        max_points_per_chunk: usize,
    ) -> Result<Self::CellPort, IpcError> {
        node.service_builder(&service_name(name)?)
            .publish_subscribe::<[P]>()
            .user_header::<H>()
            .open()
            .map_err(|e| IpcError::iceoryx(name, e))?
            .publisher_builder()
            .initial_max_slice_len(max_points_per_chunk)
            .allocation_strategy(AllocationStrategy::Static)
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .set_backpressure_handler(deliver_or_fail)
            .create()
            .map_err(|e| IpcError::iceoryx(format!("cannot publish on {name}"), e))
    }
}

/// The settings of an agent's output of one message per station: one publisher, kept for a
/// late subscriber, never overflowing a subscriber's queue (the publisher drops instead).
macro_rules! per_station_settings {
    ($builder:expr) => {
        $builder
            .max_publishers(1)
            .max_subscribers(ADMITS.output_subscribers)
            .max_nodes(ADMITS.nodes)
            .history_size(ADMITS.report_history)
            .subscriber_max_buffer_size(ADMITS.report_queue)
            .enable_safe_overflow(false)
    };
}

/// An agent's publisher that drops what a full subscriber does not take and counts it in
/// `drops`, never waiting.
macro_rules! dropping_publisher {
    ($publisher:expr, $drops:expr, $name:expr) => {
        $publisher
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .set_backpressure_handler(counting_handler($drops.clone()))
            .create()
            .map_err(|e| IpcError::iceoryx(format!("cannot publish on {}", $name), e))
    };
}

/// The cell's subscriber on an output service of a running agent; `$builder` says what the
/// service carries (iceoryx2 opens sized and slice payloads through different builders).
macro_rules! cell_subscriber {
    ($builder:expr, $name:expr) => {
        $builder
            .open()
            .map_err(|e| IpcError::iceoryx($name, e))?
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::iceoryx(format!("cannot subscribe to {}", $name), e))
    };
}

impl Stream for DeviationChunks {
    const FROM_CELL: bool = false;
    type AgentPort = Publisher<Ipc, [PointDeviation], DeviationHeader>;
    type CellPort = Subscriber<Ipc, [PointDeviation], DeviationHeader>;

    fn agent_port(setup: &Setup<'_>, name: &str) -> Result<Self::AgentPort, IpcError> {
        let service = setup
            .builder(name)?
            .publish_subscribe::<[PointDeviation]>()
            .user_header::<DeviationHeader>()
            .max_publishers(1)
            .max_subscribers(ADMITS.output_subscribers)
            .max_nodes(ADMITS.nodes)
            .history_size(0)
            .subscriber_max_buffer_size(ADMITS.deviation_queue)
            .subscriber_max_borrowed_samples(2)
            .enable_safe_overflow(false)
            .open_or_create()
            .map_err(|e| setup.incompatible(name, e))?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(setup.queues.max_points_per_chunk)
            .allocation_strategy(AllocationStrategy::Static);
        dropping_publisher!(publisher, setup.deviation_drops, name)
    }

    fn cell_port(node: &Node<Ipc>, name: &str, _: usize) -> Result<Self::CellPort, IpcError> {
        let builder = node
            .service_builder(&service_name(name)?)
            .publish_subscribe::<[PointDeviation]>()
            .user_header::<DeviationHeader>();
        cell_subscriber!(builder, name)
    }
}

impl<T: std::fmt::Debug + ZeroCopySend + 'static> Stream for PerStation<T> {
    const FROM_CELL: bool = false;
    const PER_STATION: bool = true;
    type AgentPort = Publisher<Ipc, T, ()>;
    type CellPort = Subscriber<Ipc, T, ()>;

    fn agent_port(setup: &Setup<'_>, name: &str) -> Result<Self::AgentPort, IpcError> {
        let service = per_station_settings!(setup.builder(name)?.publish_subscribe::<T>())
            .open_or_create()
            .map_err(|e| setup.incompatible(name, e))?;
        dropping_publisher!(service.publisher_builder(), setup.report_drops, name)
    }

    fn cell_port(node: &Node<Ipc>, name: &str, _: usize) -> Result<Self::CellPort, IpcError> {
        let builder = node
            .service_builder(&service_name(name)?)
            .publish_subscribe::<T>();
        cell_subscriber!(builder, name)
    }
}

impl<const MAX: usize> Stream for Encoded<MAX> {
    const FROM_CELL: bool = false;
    const PER_STATION: bool = true;
    type AgentPort = Publisher<Ipc, [u8], FindingsHeader>;
    type CellPort = Subscriber<Ipc, [u8], FindingsHeader>;

    fn agent_port(setup: &Setup<'_>, name: &str) -> Result<Self::AgentPort, IpcError> {
        let builder = setup
            .builder(name)?
            .publish_subscribe::<[u8]>()
            .user_header::<FindingsHeader>();
        let service = per_station_settings!(builder)
            .open_or_create()
            .map_err(|e| setup.incompatible(name, e))?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(MAX)
            .allocation_strategy(AllocationStrategy::Static);
        dropping_publisher!(publisher, setup.report_drops, name)
    }

    fn cell_port(node: &Node<Ipc>, name: &str, _: usize) -> Result<Self::CellPort, IpcError> {
        let builder = node
            .service_builder(&service_name(name)?)
            .publish_subscribe::<[u8]>()
            .user_header::<FindingsHeader>();
        cell_subscriber!(builder, name)
    }
}

fn counting_handler(
    counter: Arc<AtomicU64>,
) -> impl Fn(&BackpressureInfo) -> BackpressureAction + Send + 'static {
    move |_| {
        counter.fetch_add(1, Ordering::Relaxed);
        BackpressureAction::DiscardData
    }
}

/// Inputs wait for a full agent queue, but not forever: a stuck agent becomes an error.
fn deliver_or_fail(info: &BackpressureInfo) -> BackpressureAction {
    if info.elapsed_time < DELIVERY_DEADLINE {
        std::thread::yield_now();
        BackpressureAction::Retry
    } else {
        BackpressureAction::DiscardDataAndFail
    }
}
