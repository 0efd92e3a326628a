//! What each message from the cell means for its station: a Begin, an End, a pose, a chunk;
//! and what the printer says it applied, for the advice.

use super::*;

/// What the cell sends the agent, as the lifecycle takes it: live from the cell's services
/// (`daemon`) or read back from a recording (`replay`). A new input of the cell is a variant
/// here and an arm of [`Lifecycle::take`].
pub enum Input<C> {
    /// A station's Begin or End.
    Event(StationEvent),
    /// A robot pose.
    Pose(PoseSnapshot),
    /// A scan chunk.
    Chunk(C),
    /// What the printer applied to a layer it printed.
    Applied(LayerApplied),
    /// A robot pose of a line profiler's mount.
    MountPose(asbuilt_protocol::MountPose),
    /// A chunk of a line profiler's profiles.
    Profiles(
        Box<asbuilt_protocol::ProfileHeader>,
        Vec<asbuilt_protocol::ProfilePoint>,
    ),
}

impl<C: ChunkSource> Lifecycle<C> {
    /// Takes one input of the cell at `now`.
    pub fn take(&mut self, input: Input<C>, now: Instant, out: &mut impl Outputs) {
        match input {
            Input::Event(ev) => self.on_event(&ev, now, out),
            Input::Pose(pose) => self.on_pose(&pose, now, out),
            Input::Chunk(chunk) => self.on_chunk(chunk, now, out),
            Input::Applied(a) => self.on_applied(&a),
            Input::MountPose(m) => self.on_mount_pose(&m, now, out),
            Input::Profiles(h, p) => self.on_profiles(&h, &p, now, out),
        }
    }

    /// Takes what the printer applied to a layer: the next advice builds on it. Counted as a
    /// bad input when its values are not usable; nothing to do without `[corrections]`.
    pub fn on_applied(&mut self, a: &LayerApplied) {
        if !self.readable::<LayerApplied>(a.version, format_args!("applied layer {}", a.layer)) {
            return;
        }
        if let Some(k) = self.corrector.as_mut()
            && !k.applied(a)
        {
            self.counters.input.events_invalid += 1;
            warn!(
                "job {} layer {}: the printer's answer is not usable (z {}, flow {}, path {:?}); \
                 the layer is taken as printed as designed",
                a.job, a.layer, a.z_offset, a.flow, a.path_offset
            );
        }
    }

    /// Counts and logs a message of another version; true when it can be read.
    pub(super) fn readable<M: Message>(
        &mut self,
        version: u16,
        what: std::fmt::Arguments<'_>,
    ) -> bool {
        match asbuilt_protocol::check_version::<M>(version) {
            Ok(()) => true,
            Err(e) => {
                self.counters.input.version_mismatch += 1;
                warn!("{what} ignored: {e}");
                false
            }
        }
    }

    /// Takes a station's Begin or End.
    pub fn on_event(&mut self, ev: &StationEvent, now: Instant, out: &mut impl Outputs) {
        if !self.readable::<StationEvent>(ev.version, format_args!("station event")) {
            return;
        }
        let key = (ev.job, ev.station);
        let attempt = attempt_of(ev.attempt.into());
        if !self.take_print(ev, out) {
            return;
        }
        if ev.kind() == Some(StationEventKind::Begin)
            && self.closed.is_sent_anew(key, attempt, ev.timestamp_ns)
        {
            // A cell process started again does not know its predecessor's attempts.
            info!(
                "job {} station {} attempt {attempt}: begins anew, later than the reported one \
                 (a cell started again); served again",
                key.0, key.1
            );
            self.closed.forget(key);
        }
        if self.is_over(key, attempt, out) {
            // An End after a chunk flagged last closed the station is the usual order.
            if ev.kind() != Some(StationEventKind::End) {
                info!(
                    "job {} station {} attempt {attempt}: Begin of an attempt already reported \
                     or given up (a repeat, or the service's history), ignored",
                    key.0, key.1
                );
            }
            return;
        }
        match ev.kind() {
            Some(StationEventKind::Begin) => {
                let i = self.open_slot(key, attempt, now, out);
                self.print_height(i, ev.printed_height, now);
                let s = &mut self.open[i];
                if s.begin.is_some() {
                    warn!("job {} station {}: Begin repeated", key.0, key.1);
                }
                s.begin = Some(*ev);
                s.last_activity = now;
                info!(
                    "job {} station {} ({}) begins, layer {}{}",
                    key.0,
                    key.1,
                    s.name(),
                    ev.layer,
                    attempt_text(attempt)
                );
                self.release_pending(key, now, out);
            }
            Some(StationEventKind::End) => match self.find(&key) {
                Some(i) => {
                    let s = &mut self.open[i];
                    s.end = Some(*ev);
                    s.last_activity = now;
                    s.finished_at.get_or_insert(now);
                    self.close_if_complete(i, out);
                }
                None if self.closed.last_attempt(key).is_some() => {
                    // Closed already by a chunk flagged last: nothing to add.
                }
                None => {
                    self.counters.input.events_invalid += 1;
                    warn!(
                        "job {} station {}: End for a station that is not open, ignored",
                        key.0, key.1
                    );
                }
            },
            None => {
                self.counters.input.events_invalid += 1;
                warn!(
                    "job {} station {}: station event of unknown kind {} ignored",
                    key.0, key.1, ev.kind
                );
            }
        }
    }

    /// Takes a station's pose; the chunks waiting for it are processed.
    pub fn on_pose(&mut self, pose: &PoseSnapshot, now: Instant, out: &mut impl Outputs) {
        if !self.readable::<PoseSnapshot>(pose.version, format_args!("pose")) {
            return;
        }
        let key = (pose.job, pose.station);
        let attempt = attempt_of(pose.attempt.into());
        if self.is_over(key, attempt, out) {
            info!(
                "job {} station {} attempt {attempt}: pose for an attempt already reported or \
                 given up, ignored",
                key.0, key.1
            );
            return;
        }
        let t = match self.frames.t_design_scanner(pose) {
            Ok(t) => t,
            Err(e) => {
                self.counters.input.poses_invalid += 1;
                warn!("job {} station {}: pose rejected: {e}", key.0, key.1);
                return;
            }
        };
        let i = self.open_slot(key, attempt, now, out);
        let s = &mut self.open[i];
        if s.pose.is_some() {
            warn!(
                "job {} station {}: a new pose replaces the previous one for the chunks that follow",
                key.0, key.1
            );
        }
        s.pose = Some(*pose);
        s.inspector.set_pose(t);
        s.last_activity = now;
        self.release_pending(key, now, out);
    }

    /// Takes a scan chunk: processed now, held for its station's pose, or rejected and counted.
    pub fn on_chunk(&mut self, chunk: C, now: Instant, out: &mut impl Outputs) {
        let h = *chunk.header();
        let n = chunk.points().len();
        if !self.readable::<ChunkHeader>(h.version, format_args!("scan chunk ({n} points)")) {
            return;
        }
        let key = (h.job, h.station);
        let attempt = attempt_of(h.attempt);
        if self.is_over(key, attempt, out) {
            self.counters.input.chunks_after_close += 1;
            warn!(
                "job {} station {} attempt {attempt}: chunk {} arrived after the attempt's \
                 report, dropped ({} points)",
                key.0,
                key.1,
                h.sequence,
                chunk.points().len()
            );
            return;
        }
        match self.find(&key) {
            Some(i) if self.ready(i) => {
                self.process(i, &chunk, now, out);
                self.close_if_complete(i, out);
            }
            None if h.sequence > 0 && !self.holds_any_of(key) => {
                self.began_before_us(chunk, attempt, out)
            }
            _ => self.hold(chunk, now),
        }
    }

    /// Whether a message of `attempt` of `key` comes too late: that attempt (or a later one)
    /// was reported, or a later one is open. A message of a later attempt than the open one
    /// means the cell gave up on the open one: it closes as interrupted.
    pub(super) fn is_over(
        &mut self,
        key: StationKey,
        attempt: u16,
        out: &mut impl Outputs,
    ) -> bool {
        if self.closed.covers(key, attempt) {
            return true;
        }
        match self.find(&key) {
            Some(i) if self.open[i].attempt > attempt => true,
            Some(i) if self.open[i].attempt < attempt => {
                info!(
                    "job {} station {}: attempt {attempt} begins while attempt {} is open; the \
                     cell gave that one up",
                    key.0, key.1, self.open[i].attempt
                );
                self.close(i, Some(StationStatus::Interrupted), out);
                false
            }
            _ => false,
        }
    }

    /// Whether a chunk of `key` waits for its station's pose.
    pub(super) fn holds_any_of(&self, key: StationKey) -> bool {
        self.pending.iter().any(|p| {
            let h = p.chunk.header();
            (h.job, h.station) == key
        })
    }

    /// A chunk past the first of a station this agent never saw begin: the station began
    /// before this agent started (it replaced one that stopped), so its first chunks went to
    /// the one before and are lost. Holding the chunk for a Begin that will not come would
    /// keep the cell waiting for the station timeout: the chunk is dropped at once and counted,
    /// and the attempt is reported interrupted so that the cell sends the station again.
    pub(super) fn began_before_us(&mut self, chunk: C, attempt: u16, out: &mut impl Outputs) {
        let h = *chunk.header();
        self.counters.input.chunks_unknown_station += 1;
        warn!(
            "job {} station {} attempt {attempt}: chunk {} arrived without its station's Begin \
             and first chunks (the station began before this agent started); dropped, and the \
             attempt is reported interrupted",
            h.job, h.station, h.sequence
        );
        let mut report = StationReport::new(h.job, h.station);
        report.points_received = chunk.points().len() as u64;
        report.rejected.without_pose = chunk.points().len() as u64;
        // Its Begin was sent before this chunk: a later one is the station sent anew.
        self.report_interrupted(report, attempt, h.timestamp_ns, out);
    }
}
