//! The open stations and the chunks that wait for them: a slot per station, a bounded buffer of
//! chunks held for a pose or a printed height, and what happens to a chunk of no known station.

use super::*;

/// How many closed stations are remembered, to tell a late chunk from one of an unknown station.
pub(super) const CLOSED_MEMORY: usize = 64;

pub(super) struct OpenStation {
    pub(super) key: StationKey,
    /// Which try at the station this is (1 the first).
    pub(super) attempt: u16,
    pub(super) begin: Option<StationEvent>,
    pub(super) end: Option<StationEvent>,
    pub(super) pose: Option<PoseSnapshot>,
    /// Sequence of a chunk flagged `last`.
    pub(super) last_sequence: Option<u64>,
    /// When the scanner first said it is done (End event or a chunk flagged last).
    pub(super) finished_at: Option<Instant>,
    pub(super) inspector: StationInspector,
    /// The design as printed when this station scanned (the whole design until told).
    pub(super) design: Arc<PrintedDesign>,
    /// The printed height whose design is being prepared for this station; its chunks wait.
    pub(super) awaiting: Option<f64>,
    /// A pass's findings judge the design from this height up (the profiler's reach).
    pub(super) floor: Option<f64>,
    /// Whether the findings stage took this station (decided at its first chunk).
    pub(super) findings: Option<bool>,
    pub(super) tracker: SequenceTracker,
    pub(super) empty: u64,
    pub(super) oversized: u64,
    pub(super) last_activity: Instant,
    /// A line profiler's pass: profile chunks came, each placed by its own pose.
    pub(super) profiled: bool,
    /// The pass's placed profiles not yet compared.
    pub(super) profiles: Option<super::profiles::PassBuffer>,
}

impl OpenStation {
    pub(super) fn expected_chunks(&self) -> u64 {
        let announced = self
            .end
            .or(self.begin)
            .map(|e| e.expected_chunks as u64)
            .unwrap_or(0);
        if announced > 0 {
            announced
        } else {
            self.last_sequence.map(|s| s + 1).unwrap_or(0)
        }
    }

    pub(super) fn expected_points(&self) -> u64 {
        self.end
            .map(|e| e.expected_points)
            .filter(|&n| n > 0)
            .or(self.begin.map(|e| e.expected_points))
            .unwrap_or(0)
    }

    /// The scanner said it is done (End event or a chunk flagged last).
    pub(super) fn finished_sending(&self) -> bool {
        self.end.is_some() || self.last_sequence.is_some()
    }

    pub(super) fn name(&self) -> String {
        self.begin
            .or(self.end)
            .map(|e| e.name.as_str().to_string())
            .filter(|n| !n.is_empty())
            .unwrap_or_else(|| format!("station-{}", self.key.1))
    }
}

pub(super) struct Pending<C> {
    pub(super) chunk: C,
    pub(super) since: Instant,
}

impl<C: ChunkSource> Lifecycle<C> {
    pub(super) fn find(&self, key: &StationKey) -> Option<usize> {
        self.open.iter().position(|s| &s.key == key)
    }

    pub(super) fn open_slot(
        &mut self,
        key: StationKey,
        attempt: u16,
        now: Instant,
        out: &mut impl Outputs,
    ) -> usize {
        if let Some(i) = self.find(&key) {
            return i;
        }
        if self.open.len() == self.limits.open_stations {
            let oldest = (0..self.open.len())
                .min_by_key(|&i| self.open[i].last_activity)
                .expect("at least one station is open");
            let s = &self.open[oldest];
            warn!(
                "more than {} stations open: closing job {} station {} early to make room",
                self.limits.open_stations, s.key.0, s.key.1
            );
            self.close(oldest, Some(StationStatus::Incomplete), out);
        }
        self.open.push(OpenStation {
            key,
            attempt,
            begin: None,
            end: None,
            pose: None,
            last_sequence: None,
            finished_at: None,
            inspector: StationInspector::new(
                self.designs.full().clone(),
                nalgebra::Isometry3::identity(),
                self.config,
            ),
            design: self.designs.full().clone(),
            awaiting: None,
            floor: None,
            findings: None,
            tracker: SequenceTracker::new(),
            empty: 0,
            oversized: 0,
            last_activity: now,
            profiled: false,
            profiles: None,
        });
        self.open.len() - 1
    }

    pub(super) fn hold(&mut self, chunk: C, now: Instant) {
        let h = *chunk.header();
        if self.pending.len() == self.limits.pending_chunks {
            match self.pending.pop_front() {
                Some(old) => {
                    self.counters.input.chunks_pending_overflow += 1;
                    let oh = *old.chunk.header();
                    warn!(
                        "job {} station {}: chunk {} waited for a pose in a full buffer and was \
                         pushed out ({} points)",
                        oh.job,
                        oh.station,
                        oh.sequence,
                        old.chunk.points().len()
                    );
                    self.reject_held(old.chunk);
                }
                None => {
                    // No buffer at all (pending_chunks = 0): reject at once.
                    self.counters.input.chunks_pending_overflow += 1;
                    self.reject_held(chunk);
                    return;
                }
            }
        }
        if let Some(i) = self.find(&(h.job, h.station)) {
            self.open[i].last_activity = now;
        }
        self.pending.push_back(Pending { chunk, since: now });
    }

    /// A held chunk that will never be processed: counted against its station when it is open.
    pub(super) fn reject_held(&mut self, chunk: C) {
        let h = *chunk.header();
        match self.find(&(h.job, h.station)) {
            Some(i) => {
                let s = &mut self.open[i];
                s.tracker.offer(h.sequence);
                s.inspector
                    .reject(chunk.points().len() as u64, |r| &mut r.without_pose);
            }
            None => self.drop_unknown(&chunk),
        }
    }

    /// Removes the first held chunk of a station, keeping the others in arrival order.
    pub(super) fn take_pending(&mut self, key: StationKey) -> Option<Pending<C>> {
        let at = self.pending.iter().position(|p| {
            let h = p.chunk.header();
            (h.job, h.station) == key
        })?;
        self.pending.remove(at)
    }

    pub(super) fn drop_unknown(&mut self, chunk: &C) {
        let h = chunk.header();
        self.counters.input.chunks_unknown_station += 1;
        warn!(
            "job {} station {}: chunk {} dropped, the station never began (no Begin event or \
             pose) ({} points)",
            h.job,
            h.station,
            h.sequence,
            chunk.points().len()
        );
    }

    /// Processes the held chunks of a station that just became ready, in arrival order.
    pub(super) fn release_pending(
        &mut self,
        key: StationKey,
        now: Instant,
        out: &mut impl Outputs,
    ) {
        let Some(i) = self.find(&key) else { return };
        if !self.ready(i) {
            return;
        }
        while let Some(p) = self.take_pending(key) {
            self.process(i, &p.chunk, now, out);
        }
        self.close_if_complete(i, out);
    }
}
