//! The iceoryx2 services of one print cell, named under a prefix:
//!
//! | service                    | payload                                 | direction      |
//! |----------------------------|-----------------------------------------|----------------|
//! | `P/robot/poses`            | `PoseSnapshot`                          | cell → agent   |
//! | `P/scanner/chunks`         | `ChunkHeader` + `[ScanPoint]`           | cell → agent   |
//! | `P/job/stations`           | `StationEvent`                          | cell → agent   |
//! | `P/agent/inbox`            | event: "input waiting"                  | cell → agent   |
//! | `P/agent/deviations`       | `DeviationHeader` + `[PointDeviation]`  | agent → cell   |
//! | `P/agent/reports`          | `StationReport`                         | agent → cell   |
//! | `P/agent/status`           | `AgentStatus`                           | agent → cell   |
//! | `P/agent/outbox`           | event: "output published"               | agent → cell   |
//!
//! Delivery, chosen so that nothing is lost silently:
//! - **Inputs** do not overflow. When the agent's queue is full, a publisher is held back
//!   (`RetryUntilDelivered`): the scanner driver waits instead of its chunks being overwritten.
//!   [`CellPorts`] gives up after a deadline and returns an error, so a dead agent never hangs
//!   the cell. The agent holds chunks whose pose has not arrived as borrowed samples, in a
//!   bounded buffer.
//! - **Outputs** never hold the agent back. A subscriber whose queue is full misses that sample,
//!   and the agent counts every such miss in its status (`output.deviation_chunks`,
//!   `output.reports`). Reports keep a history, so a monitor that connects late still gets the
//!   recent ones.
//! - **One agent per prefix**: the status service admits one publisher, so a second agent on
//!   the same services fails at start with a message naming the prefix.
//!
//! The agent creates the services with these settings; the cell side only opens them.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crate::{
    AgentStatus, ChunkHeader, DeviationHeader, FindingsHeader, LayerCorrection, MAX_FINDINGS_BYTES,
    PointDeviation, PoseSnapshot, ScanPoint, StationEvent, StationReport,
};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{BackpressureAction, BackpressureInfo};
use iceoryx2::prelude::*;

/// The iceoryx2 service kind: inter-process, shared memory.
pub type Ipc = ipc::Service;

/// A received scan chunk, still in shared memory.
pub type ChunkSample = iceoryx2::sample::Sample<Ipc, [ScanPoint], ChunkHeader>;
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

/// The names of a cell's services.
#[derive(Debug, Clone)]
pub struct ServiceNames {
    /// The prefix every name starts with.
    pub prefix: String,
    /// `PREFIX/robot/poses`: poses, cell to agent.
    pub poses: String,
    /// `PREFIX/scanner/chunks`: scan chunks, cell to agent.
    pub chunks: String,
    /// `PREFIX/job/stations`: station Begin and End, cell to agent.
    pub stations: String,
    /// `PREFIX/agent/inbox`: the event that wakes the agent.
    pub inbox: String,
    /// `PREFIX/agent/deviations`: deviation chunks, agent to cell.
    pub deviations: String,
    /// `PREFIX/agent/reports`: station reports, agent to cell.
    pub reports: String,
    /// `PREFIX/agent/findings`: findings, agent to cell.
    pub findings: String,
    /// `PREFIX/agent/corrections`: advice for the layers still to print, agent to cell.
    pub corrections: String,
    /// `PREFIX/agent/surface`: flatness, dimensions and plumb judged by a standard, agent to
    /// cell.
    pub surface: String,
    /// `PREFIX/agent/status`: the agent's health.
    pub status: String,
    /// `PREFIX/agent/outbox`: the event that wakes the cell.
    pub outbox: String,
}

impl ServiceNames {
    /// The names under `prefix`.
    pub fn new(prefix: &str) -> Self {
        let n = |s: &str| format!("{prefix}/{s}");
        Self {
            prefix: prefix.to_string(),
            poses: n("robot/poses"),
            chunks: n("scanner/chunks"),
            stations: n("job/stations"),
            inbox: n("agent/inbox"),
            deviations: n("agent/deviations"),
            reports: n("agent/reports"),
            findings: n("agent/findings"),
            corrections: n("agent/corrections"),
            surface: n("agent/surface"),
            status: n("agent/status"),
            outbox: n("agent/outbox"),
        }
    }
}

fn service_name(s: &str) -> Result<ServiceName, IpcError> {
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

/// Publishers of inputs (robot, scanner, job control) and of the agent's outputs.
const MAX_INPUT_PUBLISHERS: usize = 4;
/// The agent plus a recorder or monitor.
const MAX_INPUT_SUBSCRIBERS: usize = 2;
const MAX_OUTPUT_SUBSCRIBERS: usize = 4;
const DEVIATION_QUEUE: usize = 8;
const REPORT_QUEUE: usize = 64;
const REPORT_HISTORY: usize = 16;
const SMALL_QUEUE: usize = 64;
const MAX_NODES: usize = 16;

/// The latest station event and pose are kept for a subscriber that connects late: an agent
/// started again while a station sends learns that station's Begin and pose.
const CONTROL_HISTORY: usize = 1;

/// A subscriber on a small input service (poses, station events): never overflowing, so the
/// publisher is held back rather than a message lost.
fn control_subscriber<T: std::fmt::Debug + ZeroCopySend>(
    node: &Node<Ipc>,
    name: &str,
    exists: Exists<'_>,
) -> Result<Subscriber<Ipc, T, ()>, IpcError> {
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<T>()
        .max_publishers(MAX_INPUT_PUBLISHERS)
        .max_subscribers(MAX_INPUT_SUBSCRIBERS)
        .max_nodes(MAX_NODES)
        .subscriber_max_buffer_size(SMALL_QUEUE)
        .history_size(CONTROL_HISTORY)
        .enable_safe_overflow(false)
        .open_or_create()
        .map_err(|e| exists(name, e.into()))?
        .subscriber_builder()
        .buffer_size(SMALL_QUEUE)
        .create()
        .map_err(|e| IpcError::iceoryx(format!("cannot subscribe to {name}"), e))
}

/// The agent's side: it owns the services.
pub struct AgentPorts {
    /// Poses from the cell.
    pub poses: Subscriber<Ipc, PoseSnapshot, ()>,
    /// Scan chunks from the scanner.
    pub chunks: Subscriber<Ipc, [ScanPoint], ChunkHeader>,
    /// Station events from job control.
    pub stations: Subscriber<Ipc, StationEvent, ()>,
    /// Wakes the agent when an input arrives.
    pub inbox: Listener<Ipc>,
    /// Deviation chunks out.
    pub deviations: Publisher<Ipc, [PointDeviation], DeviationHeader>,
    /// Station reports out.
    pub reports: Publisher<Ipc, StationReport, ()>,
    /// Encoded [`crate::StationFindings`] behind their header.
    pub findings: Publisher<Ipc, [u8], FindingsHeader>,
    /// Advice for the layers still to print out (when `[corrections]` is on).
    pub corrections: Publisher<Ipc, LayerCorrection, ()>,
    /// Encoded [`crate::SurfaceFindings`] behind their header (when `[tolerances]` names a
    /// standard).
    pub surface: Publisher<Ipc, [u8], FindingsHeader>,
    /// The agent's health out.
    pub status: Publisher<Ipc, AgentStatus, ()>,
    /// Wakes the cell when an output is sent.
    pub outbox: Notifier<Ipc>,
    /// Deviation chunks and reports a full subscriber queue did not take.
    pub deviation_drops: Arc<AtomicU64>,
    /// Reports a full subscriber queue did not take.
    pub report_drops: Arc<AtomicU64>,
}

fn counting_handler(
    counter: Arc<AtomicU64>,
) -> impl Fn(&BackpressureInfo) -> BackpressureAction + Send + 'static {
    move |_| {
        counter.fetch_add(1, Ordering::Relaxed);
        BackpressureAction::DiscardData
    }
}

impl AgentPorts {
    /// Creates (or opens) every service under `names` with the agent's queue sizes.
    pub fn create(node: &Node<Ipc>, names: &ServiceNames, q: QueueSizes) -> Result<Self, IpcError> {
        let exists = |service: &str, source: IceoryxCause| IpcError::Incompatible {
            service: service.to_string(),
            prefix: names.prefix.clone(),
            source,
        };
        let status_service = node
            .service_builder(&service_name(&names.status)?)
            .publish_subscribe::<AgentStatus>()
            .max_publishers(1)
            .max_subscribers(MAX_OUTPUT_SUBSCRIBERS)
            .max_nodes(MAX_NODES)
            .history_size(1)
            .subscriber_max_buffer_size(4)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(|e| exists(&names.status, e.into()))?;
        let status =
            status_service
                .publisher_builder()
                .create()
                .map_err(|e| IpcError::AlreadyServed {
                    prefix: names.prefix.clone(),
                    source: e.into(),
                })?;

        let chunks = chunk_subscriber(node, names, q, &exists)?;
        let poses = control_subscriber::<PoseSnapshot>(node, &names.poses, &exists)?;
        let stations = control_subscriber::<StationEvent>(node, &names.stations, &exists)?;
        let inbox = node
            .service_builder(&service_name(&names.inbox)?)
            .event()
            .max_notifiers(MAX_INPUT_PUBLISHERS * 3)
            .max_listeners(2)
            .max_nodes(MAX_NODES)
            .open_or_create()
            .map_err(|e| exists(&names.inbox, e.into()))?
            .listener_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("cannot listen on the agent inbox", e))?;

        let deviation_drops = Arc::new(AtomicU64::new(0));
        let report_drops = Arc::new(AtomicU64::new(0));
        let deviations = deviation_publisher(node, names, q, &deviation_drops, &exists)?;
        let reports = message_publisher::<StationReport>(
            node,
            &names.reports,
            "reports",
            &report_drops,
            &exists,
        )?;
        let findings = bytes_publisher(
            node,
            &names.findings,
            MAX_FINDINGS_BYTES,
            &report_drops,
            &exists,
        )?;
        let surface = bytes_publisher(
            node,
            &names.surface,
            crate::MAX_SURVEY_BYTES,
            &report_drops,
            &exists,
        )?;
        let corrections = message_publisher::<LayerCorrection>(
            node,
            &names.corrections,
            "corrections",
            &report_drops,
            &exists,
        )?;
        let outbox = node
            .service_builder(&service_name(&names.outbox)?)
            .event()
            .max_notifiers(2)
            .max_listeners(MAX_OUTPUT_SUBSCRIBERS * 2)
            .max_nodes(MAX_NODES)
            .open_or_create()
            .map_err(|e| exists(&names.outbox, e.into()))?
            .notifier_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("cannot notify on the agent outbox", e))?;
        Ok(Self {
            poses,
            chunks,
            stations,
            inbox,
            deviations,
            reports,
            findings,
            corrections,
            surface,
            status,
            outbox,
            deviation_drops,
            report_drops,
        })
    }
}

/// The cell's side: what a robot controller, scanner driver and job control use to talk to a
/// running agent (and what `asbuilt publish`, the simulator and the tests use).
pub struct CellPorts {
    /// Poses to the agent.
    pub poses: Publisher<Ipc, PoseSnapshot, ()>,
    /// Scan chunks to the agent.
    pub chunks: Publisher<Ipc, [ScanPoint], ChunkHeader>,
    /// Station events to the agent.
    pub stations: Publisher<Ipc, StationEvent, ()>,
    /// Wakes the agent.
    pub inbox: Notifier<Ipc>,
    /// Deviation chunks from the agent.
    pub deviations: Subscriber<Ipc, [PointDeviation], DeviationHeader>,
    /// Station reports from the agent.
    pub reports: Subscriber<Ipc, StationReport, ()>,
    /// Encoded [`crate::StationFindings`] behind their header, from the agent.
    pub findings: Subscriber<Ipc, [u8], FindingsHeader>,
    /// Advice for the layers still to print, from the agent (when its `[corrections]` is on).
    pub corrections: Subscriber<Ipc, LayerCorrection, ()>,
    /// Encoded [`crate::SurfaceFindings`] behind their header, from the agent.
    pub surface: Subscriber<Ipc, [u8], FindingsHeader>,
    /// The agent's health.
    pub status: Subscriber<Ipc, AgentStatus, ()>,
    /// Wakes the cell when the agent sent something.
    pub outbox: Listener<Ipc>,
    chunk_service: PubSub<[ScanPoint], ChunkHeader>,
}

/// How long a chunk publisher waits for a full agent queue before it reports the agent stuck.
pub const DELIVERY_DEADLINE: Duration = Duration::from_secs(10);

/// The error for a service that cannot be opened or created with these settings.
type Exists<'a> = &'a dyn Fn(&str, IceoryxCause) -> IpcError;

/// The agent's deviation publisher: chunks a full subscriber does not take are dropped and
/// counted in `drops`, never waited for.
fn deviation_publisher(
    node: &Node<Ipc>,
    names: &ServiceNames,
    q: QueueSizes,
    drops: &Arc<AtomicU64>,
    exists: Exists<'_>,
) -> Result<Publisher<Ipc, [PointDeviation], DeviationHeader>, IpcError> {
    node.service_builder(&service_name(&names.deviations)?)
        .publish_subscribe::<[PointDeviation]>()
        .user_header::<DeviationHeader>()
        .max_publishers(1)
        .max_subscribers(MAX_OUTPUT_SUBSCRIBERS)
        .max_nodes(MAX_NODES)
        .history_size(0)
        .subscriber_max_buffer_size(DEVIATION_QUEUE)
        .subscriber_max_borrowed_samples(2)
        .enable_safe_overflow(false)
        .open_or_create()
        .map_err(|e| exists(&names.deviations, e.into()))?
        .publisher_builder()
        .initial_max_slice_len(q.max_points_per_chunk)
        .allocation_strategy(AllocationStrategy::Static)
        .backpressure_strategy(BackpressureStrategy::DiscardData)
        .set_backpressure_handler(counting_handler(drops.clone()))
        .create()
        .map_err(|e| IpcError::iceoryx("cannot publish deviations", e))
}

/// The agent's scan chunk subscriber: a full queue holds the publisher back (never drops), and
/// a station's chunks waiting for their pose stay borrowed.
fn chunk_subscriber(
    node: &Node<Ipc>,
    names: &ServiceNames,
    q: QueueSizes,
    exists: Exists<'_>,
) -> Result<Subscriber<Ipc, [ScanPoint], ChunkHeader>, IpcError> {
    node.service_builder(&service_name(&names.chunks)?)
        .publish_subscribe::<[ScanPoint]>()
        .user_header::<ChunkHeader>()
        .max_publishers(MAX_INPUT_PUBLISHERS)
        .max_subscribers(MAX_INPUT_SUBSCRIBERS)
        .max_nodes(MAX_NODES)
        .history_size(0)
        .subscriber_max_buffer_size(q.chunk_queue)
        .subscriber_max_borrowed_samples(q.pending_chunks + q.lent_chunks + 2)
        .enable_safe_overflow(false)
        .open_or_create()
        .map_err(|e| exists(&names.chunks, e.into()))?
        .subscriber_builder()
        .buffer_size(q.chunk_queue)
        .create()
        .map_err(|e| IpcError::iceoryx("cannot subscribe to scan chunks", e))
}

/// A publisher of one fixed-size message per station (reports, corrections): a late
/// subscriber gets the latest from the history; a full subscriber queue drops and counts in
/// `drops`, never makes the agent wait.
fn message_publisher<T: std::fmt::Debug + ZeroCopySend>(
    node: &Node<Ipc>,
    name: &str,
    what: &str,
    drops: &Arc<AtomicU64>,
    exists: Exists<'_>,
) -> Result<Publisher<Ipc, T, ()>, IpcError> {
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<T>()
        .max_publishers(1)
        .max_subscribers(MAX_OUTPUT_SUBSCRIBERS)
        .max_nodes(MAX_NODES)
        .history_size(REPORT_HISTORY)
        .subscriber_max_buffer_size(REPORT_QUEUE)
        .enable_safe_overflow(false)
        .open_or_create()
        .map_err(|e| exists(name, e.into()))?
        .publisher_builder()
        .backpressure_strategy(BackpressureStrategy::DiscardData)
        .set_backpressure_handler(counting_handler(drops.clone()))
        .create()
        .map_err(|e| IpcError::iceoryx(format!("cannot publish {what}"), e))
}

/// A publisher of encoded messages behind a [`FindingsHeader`] (findings, the surface's
/// judgement), samples of up to `max_bytes`, dropping and counting in `drops` as reports do.
fn bytes_publisher(
    node: &Node<Ipc>,
    name: &str,
    max_bytes: usize,
    drops: &Arc<AtomicU64>,
    exists: Exists<'_>,
) -> Result<Publisher<Ipc, [u8], FindingsHeader>, IpcError> {
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<[u8]>()
        .user_header::<FindingsHeader>()
        .max_publishers(1)
        .max_subscribers(MAX_OUTPUT_SUBSCRIBERS)
        .max_nodes(MAX_NODES)
        .history_size(REPORT_HISTORY)
        .subscriber_max_buffer_size(REPORT_QUEUE)
        .enable_safe_overflow(false)
        .open_or_create()
        .map_err(|e| exists(name, e.into()))?
        .publisher_builder()
        .initial_max_slice_len(max_bytes)
        .allocation_strategy(AllocationStrategy::Static)
        .backpressure_strategy(BackpressureStrategy::DiscardData)
        .set_backpressure_handler(counting_handler(drops.clone()))
        .create()
        .map_err(|e| IpcError::iceoryx(format!("cannot publish on {name}"), e))
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

/// A publisher on a small input service of a running agent.
fn control_publisher<T: std::fmt::Debug + ZeroCopySend>(
    node: &Node<Ipc>,
    name: &str,
) -> Result<Publisher<Ipc, T, ()>, IpcError> {
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

type PubSub<T, H> = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, T, H>;

/// The cell's subscriber on an output service of a running agent; `open` says what the service
/// carries (iceoryx2 opens sized and slice payloads through different builders).
fn output_subscriber<T, H>(
    node: &Node<Ipc>,
    name: &str,
    open: impl FnOnce(
        iceoryx2::service::builder::Builder<Ipc>,
    ) -> Result<
        PubSub<T, H>,
        iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError,
    >,
) -> Result<Subscriber<Ipc, T, H>, IpcError>
where
    T: std::fmt::Debug + IceoryxSend + ?Sized,
    H: std::fmt::Debug + ZeroCopySend,
{
    open(node.service_builder(&service_name(name)?))
        .map_err(|e| IpcError::iceoryx(name, e))?
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::iceoryx(format!("cannot subscribe to {name}"), e))
}

impl CellPorts {
    /// Opens the services of a running agent, waiting up to `wait` for it to appear.
    /// `max_points_per_chunk` sizes this publisher's chunk samples.
    pub fn open(
        node: &Node<Ipc>,
        names: &ServiceNames,
        max_points_per_chunk: usize,
        wait: Duration,
    ) -> Result<Self, IpcError> {
        let start = Instant::now();
        loop {
            match Self::try_open(node, names, max_points_per_chunk) {
                Ok(p) => return Ok(p),
                Err(e) if start.elapsed() >= wait => {
                    return Err(IpcError::NoAgent {
                        prefix: names.prefix.clone(),
                        waited_s: wait.as_secs_f64(),
                        last: Box::new(e),
                    });
                }
                Err(_) => std::thread::sleep(Duration::from_millis(20)),
            }
        }
    }

    fn try_open(
        node: &Node<Ipc>,
        names: &ServiceNames,
        max_points_per_chunk: usize,
    ) -> Result<Self, IpcError> {
        // The status publisher exists only while an agent is up; opening it first means the
        // agent has created every other service.
        let status_service = node
            .service_builder(&service_name(&names.status)?)
            .publish_subscribe::<AgentStatus>()
            .open()
            .map_err(|e| IpcError::iceoryx(&names.status, e))?;
        if status_service.dynamic_config().number_of_publishers() == 0 {
            return Err(IpcError::AgentNotUp);
        }
        let status = status_service
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("cannot subscribe to agent status", e))?;
        let chunk_service = node
            .service_builder(&service_name(&names.chunks)?)
            .publish_subscribe::<[ScanPoint]>()
            .user_header::<ChunkHeader>()
            .open()
            .map_err(|e| IpcError::iceoryx(&names.chunks, e))?;
        let chunks = chunk_service
            .publisher_builder()
            .initial_max_slice_len(max_points_per_chunk)
            .allocation_strategy(AllocationStrategy::Static)
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .set_backpressure_handler(deliver_or_fail)
            .create()
            .map_err(|e| IpcError::iceoryx("cannot publish scan chunks", e))?;
        let poses = control_publisher::<PoseSnapshot>(node, &names.poses)?;
        let stations = control_publisher::<StationEvent>(node, &names.stations)?;
        let inbox = node
            .service_builder(&service_name(&names.inbox)?)
            .event()
            .open()
            .map_err(|e| IpcError::iceoryx(&names.inbox, e))?
            .notifier_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("cannot notify the agent", e))?;
        let deviations = output_subscriber(node, &names.deviations, |b| {
            b.publish_subscribe::<[PointDeviation]>()
                .user_header::<DeviationHeader>()
                .open()
        })?;
        let reports = output_subscriber(node, &names.reports, |b| {
            b.publish_subscribe::<StationReport>().open()
        })?;
        let findings = output_subscriber(node, &names.findings, |b| {
            b.publish_subscribe::<[u8]>()
                .user_header::<FindingsHeader>()
                .open()
        })?;
        let corrections = output_subscriber(node, &names.corrections, |b| {
            b.publish_subscribe::<LayerCorrection>().open()
        })?;
        let surface = output_subscriber(node, &names.surface, |b| {
            b.publish_subscribe::<[u8]>()
                .user_header::<FindingsHeader>()
                .open()
        })?;
        let outbox = node
            .service_builder(&service_name(&names.outbox)?)
            .event()
            .open()
            .map_err(|e| IpcError::iceoryx(&names.outbox, e))?
            .listener_builder()
            .create()
            .map_err(|e| IpcError::iceoryx("cannot listen on the agent outbox", e))?;
        Ok(Self {
            poses,
            chunks,
            stations,
            inbox,
            deviations,
            reports,
            findings,
            corrections,
            surface,
            status,
            outbox,
            chunk_service,
        })
    }

    /// Subscribers of scan chunks right now (the agent, and a recorder if one runs).
    pub fn chunk_subscribers(&self) -> usize {
        self.chunk_service.dynamic_config().number_of_subscribers()
    }

    fn wake_agent(&self) -> Result<(), IpcError> {
        self.inbox
            .notify()
            .map(|_| ())
            .map_err(|e| IpcError::iceoryx("cannot notify the agent", e))
    }

    /// Sends a pose and wakes the agent.
    pub fn send_pose(&self, pose: &PoseSnapshot) -> Result<(), IpcError> {
        self.deliver("pose", || self.poses.send_copy(*pose))?;
        self.wake_agent()
    }

    /// Sends a station event and wakes the agent.
    pub fn send_event(&self, ev: &StationEvent) -> Result<(), IpcError> {
        self.deliver("station event", || self.stations.send_copy(*ev))?;
        self.wake_agent()
    }

    /// Sends one chunk; `header.point_count` is the caller's to set (the agent checks it).
    pub fn send_chunk(&self, header: &ChunkHeader, points: &[ScanPoint]) -> Result<(), IpcError> {
        // An agent that started since the last event or pose gets the station's Begin and pose
        // from their history before this chunk, not at the station's End.
        use iceoryx2::port::update_connections::UpdateConnections;
        for updated in [
            self.stations.update_connections(),
            self.poses.update_connections(),
        ] {
            if let Err(e) = updated {
                return Err(IpcError::iceoryx("cannot reach a new agent", e));
            }
        }
        self.deliver(&format!("chunk {}", header.sequence), || {
            let sample = self
                .chunks
                .loan_slice_uninit(points.len())
                .map_err(IceoryxCause::from)?;
            let mut sample = sample.write_from_slice(points);
            *sample.user_header_mut() = *header;
            sample.send().map_err(IceoryxCause::from)
        })?;
        self.wake_agent()
    }

    /// Sends until at least one subscriber took the message. A send can reach nobody without
    /// an error: iceoryx2 drops a message for a subscriber that has not yet attached to this
    /// publisher's connection when that connection's queue is already full (it cannot wait
    /// for a reader that may never come). An agent attaches on its next read, so the message
    /// is sent again, waking the agent, until [`DELIVERY_DEADLINE`].
    fn deliver<E: Into<IceoryxCause>>(
        &self,
        what: &str,
        mut send: impl FnMut() -> Result<usize, E>,
    ) -> Result<(), IpcError> {
        let start = Instant::now();
        loop {
            match send() {
                Ok(0) if start.elapsed() < DELIVERY_DEADLINE => {
                    self.wake_agent()?;
                    std::thread::sleep(Duration::from_millis(1));
                }
                Ok(0) => {
                    return Err(IpcError::NotTaken {
                        what: what.to_string(),
                        deadline_s: DELIVERY_DEADLINE.as_secs(),
                    });
                }
                Ok(_) => return Ok(()),
                Err(e) => {
                    return Err(IpcError::NotDelivered {
                        what: what.to_string(),
                        deadline_s: DELIVERY_DEADLINE.as_secs(),
                        source: e.into(),
                    });
                }
            }
        }
    }

    /// Waits up to `timeout` for the agent to publish something.
    pub fn wait_for_output(&self, timeout: Duration) -> Result<(), IpcError> {
        self.outbox
            .timed_wait(|_| {}, timeout)
            .map(|_| ())
            .map_err(|e| IpcError::iceoryx("waiting for the agent", e))
    }
}

/// A station sent straight to a running agent, stamped with the wall clock.
impl crate::StationSink for &CellPorts {
    type Error = IpcError;
    fn now_ns(&mut self, _points_sent: u64) -> u64 {
        crate::unix_time_ns()
    }
    fn event(&mut self, event: &StationEvent) -> Result<(), IpcError> {
        self.send_event(event)
    }
    fn pose(&mut self, pose: &PoseSnapshot) -> Result<(), IpcError> {
        self.send_pose(pose)
    }
    fn chunk(&mut self, header: &ChunkHeader, points: &[ScanPoint]) -> Result<(), IpcError> {
        self.send_chunk(header, points)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    fn node() -> Node<Ipc> {
        NodeBuilder::new().create::<Ipc>().unwrap()
    }

    /// A cell that fills the agent's chunk queue before the agent's first read must not lose
    /// what it sends next: iceoryx2 drops, without an error, a message for a subscriber that
    /// has not attached to the connection yet when the queue is full.
    #[test]
    fn chunks_sent_before_the_agent_first_reads_all_arrive() {
        const QUEUE: usize = 2;
        const CHUNKS: u64 = 7;
        let names = ServiceNames::new(&format!("asbuilt-ipc-test/{}", std::process::id()));
        let (ready_tx, ready_rx) = mpsc::channel();
        let agent_names = names.clone();
        let agent = std::thread::spawn(move || {
            let node = node();
            let sizes = QueueSizes {
                max_points_per_chunk: 4,
                chunk_queue: QUEUE,
                pending_chunks: 1,
                lent_chunks: 0,
            };
            let ports = AgentPorts::create(&node, &agent_names, sizes).unwrap();
            ready_tx.send(()).unwrap();
            // The cell fills the queue and goes on sending while the agent is busy.
            std::thread::sleep(Duration::from_millis(300));
            let mut got = Vec::new();
            let start = Instant::now();
            while got.len() < CHUNKS as usize && start.elapsed() < Duration::from_secs(20) {
                match ports.chunks.receive().unwrap() {
                    Some(s) => got.push(s.user_header().sequence),
                    None => std::thread::sleep(Duration::from_millis(1)),
                }
            }
            got
        });
        ready_rx.recv().unwrap();
        let node = node();
        let cell = CellPorts::open(&node, &names, 4, Duration::from_secs(5)).unwrap();
        for sequence in 0..CHUNKS {
            let points = [ScanPoint::new(1.0, 2.0, 3.0)];
            cell.send_chunk(&ChunkHeader::new(1, 0, sequence, 1), &points)
                .unwrap();
        }
        assert_eq!(agent.join().unwrap(), (0..CHUNKS).collect::<Vec<_>>());
    }
}
