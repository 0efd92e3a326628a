//! The iceoryx2 services of one print cell, named under a prefix `P`: one per row of the
//! message table (`table.rs`: `P/robot/poses`, `P/scanner/chunks`, `P/job/stations` from the
//! cell; `P/agent/status`, `…/reports`, `…/findings`, `…/corrections`, `…/surface`,
//! `…/deviations` from the agent), and two events, `P/agent/inbox` ("input waiting") and
//! `P/agent/outbox` ("output published"). The ports of both sides follow from the table; this
//! module sends on the cell's.
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

use std::time::{Duration, Instant};

pub use crate::services::{
    ChunkSample, DELIVERY_DEADLINE, DeviationSample, IceoryxCause, Ipc, IpcError, ProfileSample,
    QueueSizes,
};
pub use crate::table::{AgentPorts, CellPorts, ServiceNames};
use crate::{
    ChunkHeader, LayerApplied, MountPose, PoseSnapshot, ProfileHeader, ProfilePoint, ScanPoint,
    StationEvent, StationReport,
};
use iceoryx2::prelude::*;

impl CellPorts {
    /// The cell's side of a running agent's services on a node of its own, waiting up to `wait`
    /// for the agent to come up. The node must outlive the ports: it comes with them. What
    /// nodes that died left in the services is removed first, as before each Begin.
    pub fn connect(
        names: &ServiceNames,
        max_points_per_chunk: usize,
        wait: Duration,
    ) -> Result<(Node<Ipc>, Self), IpcError> {
        set_log_level_from_env_or(LogLevel::Error);
        let node = NodeBuilder::new()
            .create::<Ipc>()
            .map_err(|e| IpcError::iceoryx("cannot create an iceoryx2 node", e))?;
        forget_dead_nodes();
        let ports = Self::open(&node, names, max_points_per_chunk, wait)?;
        Ok((node, ports))
    }

    /// The reports of `job` that are news, after waiting up to `wait` for the agent to publish;
    /// `reports` keeps each station's latest. Reports come at least once (an agent resuming its
    /// job publishes them again); a later attempt of a station replaces an earlier one. The
    /// reports' history can hold an older report of the same attempt (a cell before this one
    /// sent the station): the newer stands, and one identical to a report in hand is not news.
    /// The deviations, which are for other subscribers, are drained so their queue never fills.
    pub fn take_reports(
        &self,
        job: u64,
        reports: &mut Vec<StationReport>,
        wait: Duration,
    ) -> Result<Vec<StationReport>, IpcError> {
        if !wait.is_zero() {
            self.wait_for_output(wait)?;
        }
        let mut news = Vec::new();
        while let Some(r) = self
            .reports
            .receive()
            .map_err(|e| IpcError::iceoryx("cannot read reports", e))?
        {
            let r = *r.payload();
            if r.job != job
                || reports
                    .iter()
                    .any(|x| x.station == r.station && (x.attempt > r.attempt || *x == r))
            {
                continue;
            }
            reports.retain(|x| x.station != r.station);
            reports.push(r);
            news.push(r);
        }
        while let Ok(Some(_)) = self.deviations.receive() {}
        Ok(news)
    }

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

    /// Sends what the printer applied to a layer and wakes the agent.
    pub fn send_applied(&self, applied: &LayerApplied) -> Result<(), IpcError> {
        self.deliver("applied layer", || self.applied.send_copy(*applied))?;
        self.wake_agent()
    }

    /// Sends a station event and wakes the agent. Before a Begin, what agents that died left
    /// in the services is removed: iceoryx2 takes a dead agent's queue for a reader until
    /// someone removes it, and a station sent into it would be lost; without it, the station
    /// waits (up to [`DELIVERY_DEADLINE`]) for the agent that replaces the dead one.
    pub fn send_event(&self, ev: &StationEvent) -> Result<(), IpcError> {
        if ev.kind() == Some(crate::StationEventKind::Begin) {
            forget_dead_nodes();
        }
        self.deliver("station event", || self.stations.send_copy(*ev))?;
        self.wake_agent()
    }

    /// Sends one chunk; `header.point_count` is the caller's to set (the agent checks it).
    pub fn send_chunk(&self, header: &ChunkHeader, points: &[ScanPoint]) -> Result<(), IpcError> {
        // An agent that started since the last event or pose gets the station's Begin and pose
        // (and the printer's latest answers) from their history before this chunk, not at the
        // station's End.
        use iceoryx2::port::update_connections::UpdateConnections;
        for updated in [
            self.applied.update_connections(),
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

    /// Sends a robot pose of a line profiler's mount and wakes the agent.
    pub fn send_mount_pose(&self, pose: &MountPose) -> Result<(), IpcError> {
        self.deliver("mount pose", || self.mount_poses.send_copy(*pose))?;
        self.wake_agent()
    }

    /// Sends one chunk of a line profiler's profiles; the header's counts are the caller's
    /// to set (the agent checks them).
    pub fn send_profiles(
        &self,
        header: &ProfileHeader,
        points: &[ProfilePoint],
    ) -> Result<(), IpcError> {
        self.deliver(&format!("profile chunk {}", header.sequence), || {
            let sample = self
                .profiles
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

/// Removes the resources of every dead iceoryx2 node (a killed agent's ports among them). What
/// cannot be removed now (another process is at it, no permission) is left: it only means a
/// lost station, which the agent reports and the cell sends again.
fn forget_dead_nodes() {
    let _ = Node::<Ipc>::list(Config::global_config(), |state| {
        if let NodeState::Dead(view) = state {
            let _ = view.try_remove_stale_resources();
        }
        CallbackProgression::Continue
    });
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
