//! Closing a station: its chunks processed, its report, then its scan layer's findings, the
//! advice after them and the survey; a station cut off is reported interrupted.

use super::*;
use asbuilt_core::coverage::Viewpoint;

impl<C: ChunkSource> Lifecycle<C> {
    /// Findings out, then the advice they lead to.
    pub(super) fn findings_out(
        &mut self,
        f: &StationFindings,
        report: &StationReport,
        out: &mut impl Outputs,
    ) {
        out.findings(f);
        if let Some(k) = self.corrector.as_mut() {
            let c = k.advise(f, report.attempt.max(1), report.position_sigma);
            info!(
                "job {} station {}: advice from layer {}: z {:+.2} mm a layer ({} layers), then \
                 {:+.2}; flow {:.3}; path ({:+.1}, {:+.1}) mm",
                c.job,
                c.station,
                c.from_layer,
                c.z_first * 1e3,
                c.first_layers,
                c.z_then * 1e3,
                c.flow,
                c.path_offset[0] * 1e3,
                c.path_offset[1] * 1e3
            );
            out.correction(&c);
        }
    }

    /// Reports an attempt that is not open here as interrupted (`report` says what is known
    /// of it), and remembers it as over; `begun_ns` is when its Begin was sent, or before.
    pub(super) fn report_interrupted(
        &mut self,
        mut report: StationReport,
        attempt: u16,
        begun_ns: u64,
        out: &mut impl Outputs,
    ) {
        report.attempt = attempt.min(u8::MAX.into()) as u8;
        report.status = StationStatus::Interrupted as u8;
        self.counters.rejected_points += report.rejected;
        self.counters.stations_reported += 1;
        out.report(&report);
        self.closed
            .push((report.job, report.station), attempt, begun_ns);
    }

    /// Closes `attempt` of `key` as interrupted: the agent that had it open stopped (a resumed
    /// agent after replaying its recording, a reader of a recording where the resumed agent
    /// said so). An attempt not open here is reported interrupted all the same.
    /// `begin` names the attempt: its job, station and attempt, and the name, layer and printed
    /// height the report carries when the station is not open here.
    pub fn interrupt(&mut self, begin: &StationEvent, out: &mut impl Outputs) {
        let key = (begin.job, begin.station);
        let attempt = attempt_of(begin.attempt.into());
        if self.closed.covers(key, attempt) {
            return;
        }
        match self.find(&key) {
            Some(i) if self.open[i].attempt == attempt => {
                self.close(i, Some(StationStatus::Interrupted), out)
            }
            Some(i) if self.open[i].attempt > attempt => {}
            found => {
                if let Some(i) = found {
                    self.close(i, Some(StationStatus::Interrupted), out);
                }
                let mut report = StationReport::new(key.0, key.1);
                report.name = begin.name;
                report.layer = begin.layer;
                report.printed_height = begin.printed_height;
                self.report_interrupted(report, attempt, asbuilt_protocol::unix_time_ns(), out);
            }
        }
    }

    /// Closes every open station as interrupted (an agent resuming from its recording: the
    /// stations it replayed that never ended were open when the agent before it stopped), but
    /// a line profiler's passes, which go on with what the cell sends.
    pub fn interrupt_open(&mut self, out: &mut impl Outputs) -> Vec<StationKey> {
        let mut keys = Vec::new();
        let mut i = 0;
        while i < self.open.len() {
            // A line profiler's pass goes on: its layer cannot be scanned again.
            if self.open[i].profiled {
                i += 1;
                continue;
            }
            keys.push(self.open[i].key);
            self.close(i, Some(StationStatus::Interrupted), out);
        }
        keys
    }

    /// Publishes the findings the station of `report` drew when it closed, drawn again from its
    /// scan layer's state: the agent before this one stopped before they were on disk.
    pub fn findings_after(&mut self, report: &StationReport, out: &mut impl Outputs) {
        let design = if report.printed_height.is_finite() {
            match self.designs.at(report.printed_height) {
                Ok(d) => d,
                Err(_) => return,
            }
        } else {
            self.designs.full().clone()
        };
        if let Some(f) = self
            .findings
            .as_ref()
            .and_then(|s| s.findings_after(&design, report))
        {
            self.findings_out(&f, report, out);
        }
    }

    /// The input queues are empty: a station whose scanner said it is done, at least
    /// [`END_GRACE`] ago, closes now, even if chunks are missing.
    pub fn on_idle(&mut self, now: Instant, out: &mut impl Outputs) {
        let mut i = 0;
        while i < self.open.len() {
            let s = &self.open[i];
            // A station waiting for its printed design has its chunks still queued.
            let settled = s
                .finished_at
                .is_some_and(|t| now.saturating_duration_since(t) >= END_GRACE);
            if settled && s.awaiting.is_none() {
                self.close(i, None, out);
            } else {
                i += 1;
            }
        }
    }

    /// Closes stations and drops held chunks that have waited longer than the station timeout.
    pub fn on_tick(&mut self, now: Instant, out: &mut impl Outputs) {
        let timeout = self.limits.station_timeout;
        let mut i = 0;
        while i < self.open.len() {
            if now.duration_since(self.open[i].last_activity) > timeout {
                let s = &self.open[i];
                warn!(
                    "job {} station {}: no message for {:.1} s, closing it as timed out",
                    s.key.0,
                    s.key.1,
                    timeout.as_secs_f64()
                );
                self.close(i, Some(StationStatus::TimedOut), out);
            } else {
                i += 1;
            }
        }
        while self
            .pending
            .front()
            .is_some_and(|p| now.duration_since(p.since) > timeout)
        {
            let p = self.pending.pop_front().expect("checked non-empty");
            self.drop_unknown(&p.chunk);
        }
    }

    /// Shutdown: every open station gets a partial report; held chunks without a station are
    /// counted.
    pub fn shutdown(&mut self, out: &mut impl Outputs) {
        while !self.open.is_empty() {
            self.close(0, Some(StationStatus::Partial), out);
        }
        while let Some(p) = self.pending.pop_front() {
            self.drop_unknown(&p.chunk);
        }
    }

    pub(super) fn process(&mut self, i: usize, chunk: &C, now: Instant, out: &mut impl Outputs) {
        let h = *chunk.header();
        let points = chunk.points();
        let n = points.len();
        let s = &mut self.open[i];
        s.last_activity = now;
        if h.last != 0 {
            s.last_sequence = Some(h.sequence);
            s.finished_at.get_or_insert(now);
        }
        let input = &mut self.counters.input;
        if h.point_count as usize != n {
            input.chunks_malformed += 1;
            s.tracker.offer(h.sequence);
            s.inspector.reject(n as u64, |r| &mut r.in_rejected_chunks);
            warn!(
                "job {} station {}: chunk {} declares {} points but carries {}, rejected",
                h.job, h.station, h.sequence, h.point_count, n
            );
            return;
        }
        let verdict = s.tracker.offer(h.sequence);
        match verdict {
            ChunkVerdict::Duplicate | ChunkVerdict::TooOld => {
                if verdict == ChunkVerdict::Duplicate {
                    input.chunks_duplicate += 1;
                } else {
                    input.chunks_out_of_order += 1;
                }
                s.inspector.reject(n as u64, |r| &mut r.in_rejected_chunks);
                warn!(
                    "job {} station {}: chunk {} {}, dropped",
                    h.job,
                    h.station,
                    h.sequence,
                    if verdict == ChunkVerdict::Duplicate {
                        "repeated"
                    } else {
                        "too far out of order to tell whether it is new"
                    }
                );
                return;
            }
            ChunkVerdict::Accept | ChunkVerdict::AcceptLate => {}
        }
        if n == 0 {
            input.chunks_empty += 1;
            s.empty += 1;
            return;
        }
        if n > self.limits.max_points_per_chunk {
            input.chunks_oversized += 1;
            s.oversized += 1;
            s.inspector.reject(n as u64, |r| &mut r.in_rejected_chunks);
            warn!(
                "job {} station {}: chunk {} has {} points, more than limits.max_points_per_chunk \
                 = {}, rejected",
                h.job, h.station, h.sequence, n, self.limits.max_points_per_chunk
            );
            return;
        }
        self.counters.chunks_processed += 1;
        self.inspect(
            i,
            (h.job, h.station, h.sequence, h.timestamp_ns),
            points,
            now,
            out,
        );
    }

    /// Whether station `i` is part of its scan layer's findings, decided at its first points.
    pub(super) fn begin_findings(&mut self, i: usize) -> bool {
        let s = &mut self.open[i];
        match (s.findings, self.findings.as_mut()) {
            (Some(taken), _) => taken,
            (None, Some(st)) => *s.findings.insert(st.begin(s.key, &s.design, s.floor)),
            (None, None) => false,
        }
    }

    /// Compares points of station `i` (in its scanner's frame, or the design's for a pass)
    /// and sends their deviations as chunk `(job, station, sequence, timestamp)`.
    pub(super) fn inspect(
        &mut self,
        i: usize,
        (job, station, sequence, timestamp_ns): (u64, u32, u64, u64),
        points: &[ScanPoint],
        now: Instant,
        out: &mut impl Outputs,
    ) {
        let n = points.len();
        let in_findings = self.begin_findings(i);
        let s = &mut self.open[i];
        s.last_activity = now;
        let stage = &mut self.findings;
        let inspector = &mut s.inspector;
        let survey = &mut self.survey;
        let height = s.design.height;
        let view = asbuilt_core::flatness::StationView {
            key: (job, station),
            origin: s
                .pose
                .filter(|_| survey.is_some())
                .and_then(|p| self.frames.t_design_scanner(&p).ok())
                .map(|t| nalgebra::Point3::from(t.translation.vector)),
            position_sigma: s.pose.map_or(f64::NAN, |p| p.position_sigma),
        };
        out.deviations(n, &mut |buf| {
            let outcome = inspector.process(points, buf);
            if in_findings && let Some(st) = stage.as_mut() {
                st.ingest((job, station), buf);
            }
            if let Some(sv) = survey.as_mut() {
                sv.ingest(job, height, &view, buf);
            }
            let mut d = DeviationHeader::new(job, station, sequence);
            d.timestamp_ns = timestamp_ns;
            d.point_count = n as u32;
            d.rejected = outcome.rejected;
            d.no_match = outcome.no_match;
            d.out_of_tolerance = outcome.out_of_tolerance;
            d
        });
        self.counters.points_processed += n as u64;
    }

    pub(super) fn close_if_complete(&mut self, i: usize, out: &mut impl Outputs) {
        let s = &self.open[i];
        // A pass's last profiles may still wait for the pose after them, or for its design.
        let waits = s.profiled && (self.profiles_wait_for(s.key) || !self.ready(i));
        if s.finished_sending() && s.tracker.is_complete(s.expected_chunks()) && !waits {
            self.close(i, None, out);
        }
    }

    pub(super) fn close(
        &mut self,
        i: usize,
        forced: Option<StationStatus>,
        out: &mut impl Outputs,
    ) {
        let key = self.open[i].key;
        if self.open[i].profiled {
            let now = self.open[i].last_activity;
            self.end_pass(i, now, out);
        }
        // Held chunks of this station will never get a pose now.
        while let Some(p) = self.take_pending(key) {
            self.reject_held(p.chunk);
        }
        let s = self.open.swap_remove(i);
        let mut report = station_report(&s, forced);
        if s.profiled {
            report.position_sigma = self.profiler_sigma();
        }
        let interrupted = report.status() == Some(StationStatus::Interrupted);
        let drawn = self.draw_findings(&s, &report, interrupted, out);
        out.tally(s.inspector.tally());
        out.report(&report);
        if !interrupted && let Some(sv) = &self.survey {
            out.surface(&sv.judge(key, report.layer, report.printed_height));
        }
        if let Some(f) = drawn {
            info!(
                "job {} station {}: findings over {} station(s) of layer {}: top {:+.1} mm, {} \
                 layer(s) out of tolerance, {} region(s), {} missing area(s)",
                key.0,
                key.1,
                f.stations,
                f.layer,
                f.top_height_deviation * 1e3,
                f.layers_out_of_tolerance().count(),
                f.regions.len(),
                f.missing.len()
            );
            self.findings_out(&f, &report, out);
            if let Some(stage) = self.findings.as_ref()
                && !stage.samples().is_empty()
            {
                out.samples(&f, stage.samples());
            }
        }
        self.counters.stations_reported += 1;
        self.counters.rejected_points += report.rejected;
        let begun = s
            .begin
            .map_or_else(asbuilt_protocol::unix_time_ns, |b| b.timestamp_ns);
        self.closed.push(key, s.attempt, begun);
        log_closed(&report, s.attempt);
    }

    /// The station's end in its scan layer's findings: the findings drawn after it (none for
    /// an interrupted try, which adds nothing: its next attempt scans the station again). The
    /// scan layer's state goes out before the report: a report on disk means its layer's state
    /// is too, for an agent that resumes the job.
    fn draw_findings(
        &mut self,
        s: &OpenStation,
        report: &StationReport,
        interrupted: bool,
        out: &mut impl Outputs,
    ) -> Option<StationFindings> {
        if s.findings != Some(true) {
            return None;
        }
        let stage = self.findings.as_mut()?;
        if interrupted {
            stage.abandon(s.key);
            return None;
        }
        let view = if s.profiled {
            Some(Viewpoint::Swept)
        } else {
            s.pose
                .and_then(|p| self.frames.t_design_scanner(&p).ok())
                .map(|t| Viewpoint::Origin(nalgebra::Point3::from(t.translation.vector)))
        };
        let drawn = stage.end(s.key, view, report);
        if drawn.is_some()
            && out.wants_scan_layer_state()
            && let Some(state) = stage.layer_state(s.key.0, &s.design)
        {
            out.scan_layer_state(report, &state);
        }
        drawn
    }
}

/// A closing station's report: its statistics, chunks, layer and pose σ, and its status (the
/// `forced` one, else complete when its pose, every chunk and every point came).
fn station_report(s: &OpenStation, forced: Option<StationStatus>) -> StationReport {
    let key = s.key;
    let expected = s.expected_chunks();
    let mut report = s.inspector.report(key.0, key.1, &s.name());
    report.attempt = s.attempt.min(u8::MAX.into()) as u8;
    let mut chunks = s.tracker.finish(expected);
    chunks.empty = s.empty;
    chunks.oversized = s.oversized;
    report.chunks = chunks;
    if let Some(e) = s.begin.or(s.end) {
        report.layer = e.layer;
        report.printed_height = e.printed_height;
    }
    report.position_sigma = s.pose.map(|p| p.position_sigma).unwrap_or(f64::NAN);
    let expected_points = s.expected_points();
    let complete = (s.pose.is_some() || s.profiled)
        && s.tracker.is_complete(expected)
        && (expected_points == 0 || report.points_received == expected_points)
        && s.finished_sending();
    let status = forced.unwrap_or(if complete {
        StationStatus::Complete
    } else {
        StationStatus::Incomplete
    });
    report.status = status as u8;
    report
}

/// The log line of a closed station.
fn log_closed(report: &StationReport, attempt: u16) {
    let (st, chunks) = (&report.stats, &report.chunks);
    info!(
        "job {} station {} ({}){} {:?}: {} points, {} matched, {} rejected, {} no match; chunks \
         {} received / {} expected, {} missing; median |d| {:.3} mm, p95 {:.3} mm",
        report.job,
        report.station,
        report.name.as_str(),
        attempt_text(attempt),
        report.status().unwrap_or(StationStatus::Incomplete),
        report.points_received,
        st.count,
        report.rejected.total(),
        report.no_match,
        chunks.received,
        chunks.expected,
        chunks.missing,
        st.median_abs * 1e3,
        st.p95_abs * 1e3
    );
}

/// " attempt n" after a station's name, for a second try or later.
pub(super) fn attempt_text(attempt: u16) -> String {
    if attempt > 1 {
        format!(" attempt {attempt}")
    } else {
        String::new()
    }
}
