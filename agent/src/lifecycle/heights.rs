//! Printed heights: the design as printed at a station's height, prepared on a worker thread
//! while the station's chunks wait, and taken up by the loop when it is ready.

use super::*;

pub(super) fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// A printed height prepared on a worker thread, with how long its section and (for findings)
/// its cut mesh and its scan layer's findings state took.
pub(super) struct Prepared {
    pub(super) design: Arc<PrintedDesign>,
    /// The section, and with findings the cut mesh and its sharp edges beside it.
    pub(super) section: Duration,
    /// The findings' design samples, M3C2 and coverage over them.
    pub(super) mesh: Option<Duration>,
    pub(super) epoch: Option<crate::findings::Epoch>,
}

/// A printed height being prepared on a worker thread.
pub(super) struct Preparation {
    pub(super) height: f64,
    pub(super) since: Instant,
    pub(super) done: mpsc::Receiver<Result<Prepared, CutError>>,
}

impl<C: ChunkSource> Lifecycle<C> {
    /// True when a chunk with this header can be processed now (its station is open with a
    /// pose). The daemon reads the event and pose queues before giving up on a chunk.
    pub fn is_ready_for(&self, h: &ChunkHeader) -> bool {
        self.find(&(h.job, h.station))
            .is_some_and(|i| self.ready(i))
    }

    /// Whether this chunk's station waits for its printed design.
    pub fn awaits_design(&self, h: &ChunkHeader) -> bool {
        self.find(&(h.job, h.station))
            .is_some_and(|i| self.open[i].awaiting.is_some())
    }

    /// Whether a line profiler's pass waits for its printed design.
    pub fn pass_awaits_design(&self, job: u64, pass: u32) -> bool {
        self.find(&(job, pass))
            .is_some_and(|i| self.open[i].awaiting.is_some())
    }

    /// Whether a line profiler's pass can be compared now: it began and its printed design
    /// is ready (a pass not open yet can: its first chunk opens it).
    pub fn pass_is_ready(&self, job: u64, pass: u32) -> bool {
        self.find(&(job, pass)).is_none_or(|i| self.ready(i))
    }

    /// A station's chunks can be compared: it has its pose and its printed design.
    pub(super) fn ready(&self, i: usize) -> bool {
        let s = &self.open[i];
        // A pass is placed profile by profile; its Begin says its printed height.
        let placed = s.pose.is_some() || (s.profiled && s.begin.is_some());
        placed && s.awaiting.is_none()
    }

    /// Whether a printed height is being prepared: the event loop then wakes often enough to
    /// take it up as soon as it is done.
    pub fn is_preparing(&self) -> bool {
        !self.preparing.is_empty()
    }

    /// Takes up the printed heights prepared since the last call: their stations compare with
    /// them from now on and the chunks they held are processed.
    pub fn poll_designs(&mut self, now: Instant, out: &mut impl Outputs) {
        self.take_prepared(now, out, false);
    }

    /// Waits for every printed height being prepared and takes them up: for a reader of a
    /// recording, which has no robot to keep serving.
    pub fn wait_designs(&mut self, now: Instant, out: &mut impl Outputs) {
        self.take_prepared(now, out, true);
    }

    pub(super) fn take_prepared(&mut self, now: Instant, out: &mut impl Outputs, block: bool) {
        let mut k = 0;
        while k < self.preparing.len() {
            let received = if block {
                self.preparing[k]
                    .done
                    .recv()
                    .map_err(|_| mpsc::TryRecvError::Disconnected)
            } else {
                self.preparing[k].done.try_recv()
            };
            let result = match received {
                Ok(r) => r.map_err(|e| e.to_string()),
                Err(mpsc::TryRecvError::Empty) => {
                    k += 1;
                    continue;
                }
                Err(mpsc::TryRecvError::Disconnected) => {
                    Err("the preparing thread stopped without a result".to_string())
                }
            };
            let p = self.preparing.swap_remove(k);
            let design = match result {
                Ok(prepared) => {
                    let d = prepared.design;
                    if let (Some(e), Some(stage)) = (prepared.epoch, self.findings.as_mut()) {
                        stage.adopt(e);
                    }
                    let (cut, samples) = match prepared.mesh {
                        Some(m) => (
                            " and the cut mesh with its edges",
                            format!(
                                ", then the findings' samples, M3C2 and coverage {:.1} ms",
                                ms(m)
                            ),
                        ),
                        None => ("", String::new()),
                    };
                    info!(
                        "design at printed height {:.3} m ready in {:.1} ms (section of {} \
                         triangles{cut} {:.1} ms{samples})",
                        p.height,
                        ms(now.saturating_duration_since(p.since)),
                        d.section().map_or(0, |s| s.triangles()),
                        ms(prepared.section),
                    );
                    self.designs.insert(d.clone());
                    d
                }
                Err(e) => {
                    warn!(
                        "printed height {} m: {e}; comparing with the whole design",
                        p.height
                    );
                    self.designs.full().clone()
                }
            };
            let waiting: Vec<StationKey> = self
                .open
                .iter()
                .filter(|s| s.awaiting == Some(p.height))
                .map(|s| s.key)
                .collect();
            for key in waiting {
                if let Some(i) = self.find(&key) {
                    let s = &mut self.open[i];
                    s.inspector.set_index(design.clone());
                    s.design = design.clone();
                    s.awaiting = None;
                    self.release_pending(key, now, out);
                }
            }
        }
    }

    /// Compares station `i` with the design cut at the printed height, if the station has not
    /// compared any point yet. A height not seen recently is prepared on a worker thread (the
    /// loop goes on reading, timing out and reporting); the station's chunks wait for it.
    pub(super) fn print_height(&mut self, i: usize, height: f64, now: Instant) {
        if !height.is_finite() || self.open[i].inspector.tally().points_received > 0 {
            return;
        }
        let floor = self.pass_floor(self.open[i].key.0, height, self.open[i].profiled);
        self.open[i].floor = floor;
        if let Some(d) = self.designs.cached(height) {
            let s = &mut self.open[i];
            s.inspector.set_index(d.clone());
            s.design = d;
            s.awaiting = None;
            return;
        }
        self.open[i].awaiting = Some(height);
        if self.preparing.iter().any(|p| p.height == height) {
            return;
        }
        let (tx, done) = mpsc::channel();
        let preparer = self.designs.preparer();
        // Findings sample the printed design as a mesh and set up the scan layer's M3C2 and
        // coverage over the samples: make those off the loop too.
        let maker = self.findings.as_ref().map(|f| f.maker());
        let job = self.open[i].key.0;
        let spawned = std::thread::Builder::new()
            .name("design-height".into())
            .spawn(move || {
                let started = Instant::now();
                // With findings, the cut mesh they sample is made beside the section.
                let prepared = preparer.prepare(height, maker.is_some()).map(|design| {
                    let section = started.elapsed();
                    let design = Arc::new(design);
                    let epoch = maker.as_ref().and_then(|m| m.make(job, &design, floor));
                    let mesh = maker.is_some().then(|| started.elapsed() - section);
                    Prepared {
                        design,
                        section,
                        mesh,
                        epoch,
                    }
                });
                let _ = tx.send(prepared);
            });
        match spawned {
            Ok(_) => self.preparing.push(Preparation {
                height,
                since: now,
                done,
            }),
            Err(e) => {
                let key = self.open[i].key;
                warn!(
                    "job {} station {}: cannot start preparing printed height {height} m ({e}); \
                     comparing with the whole design",
                    key.0, key.1
                );
                self.open[i].awaiting = None;
            }
        }
    }
}
