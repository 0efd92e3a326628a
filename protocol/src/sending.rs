//! One station's messages in the order a cell sends them: Begin, the pose, the chunks with the
//! last one flagged, End with what was sent. `asbuilt publish`, `asbuilt pack`, the simulated
//! cell and the tests all send through [`StationSender`]; where the messages go (the cell's
//! iceoryx2 ports, an MCAP recording) is the [`StationSink`] they give it.

use crate::{ChunkHeader, PoseSnapshot, ScanPoint, StationEvent, StationEventKind};

/// Where a station's messages go, and the clock that stamps them.
pub trait StationSink {
    /// What the destination fails with.
    type Error;
    /// The timestamp for a message sent after `points_sent` points of this station.
    fn now_ns(&mut self, points_sent: u64) -> u64;
    /// Sends a station event (Begin or End).
    fn event(&mut self, event: &StationEvent) -> Result<(), Self::Error>;
    /// Sends the station's pose.
    fn pose(&mut self, pose: &PoseSnapshot) -> Result<(), Self::Error>;
    /// Sends one chunk of points with its header.
    fn chunk(&mut self, header: &ChunkHeader, points: &[ScanPoint]) -> Result<(), Self::Error>;
}

/// Sends one station. A chunk is held back until the next one (or [`StationSender::finish`])
/// shows whether it is the last, so the last goes out flagged and End can count what went.
#[derive(Debug)]
pub struct StationSender {
    begin: StationEvent,
    held: Vec<ScanPoint>,
    holding: bool,
    sequence: u64,
    points: u64,
}

impl StationSender {
    /// Sends `begin` (its kind set to Begin; name, layer, printed height, attempt and what is
    /// expected as given) and then `pose`, both stamped now. The pose and every chunk carry
    /// the Begin's job, station and attempt.
    pub fn start<S: StationSink>(
        mut begin: StationEvent,
        mut pose: PoseSnapshot,
        sink: &mut S,
    ) -> Result<Self, S::Error> {
        begin.kind = StationEventKind::Begin as u8;
        begin.timestamp_ns = sink.now_ns(0);
        sink.event(&begin)?;
        pose.job = begin.job;
        pose.station = begin.station;
        pose.attempt = begin.attempt;
        pose.timestamp_ns = sink.now_ns(0);
        sink.pose(&pose)?;
        Ok(Self {
            begin,
            held: Vec::new(),
            holding: false,
            sequence: 0,
            points: 0,
        })
    }

    /// Takes the scanner's next chunk; sends the one held before it.
    pub fn chunk<S: StationSink>(
        &mut self,
        points: &[ScanPoint],
        sink: &mut S,
    ) -> Result<(), S::Error> {
        if self.holding {
            self.send_held(false, sink)?;
        }
        self.held.clear();
        self.held.extend_from_slice(points);
        self.holding = true;
        Ok(())
    }

    /// Sends the held chunk flagged last, then End with the chunks and points sent.
    pub fn finish<S: StationSink>(mut self, sink: &mut S) -> Result<StationEvent, S::Error> {
        if self.holding {
            self.send_held(true, sink)?;
        }
        let mut end = self.begin;
        end.kind = StationEventKind::End as u8;
        end.expected_chunks = self.sequence as u32;
        end.expected_points = self.points;
        end.timestamp_ns = sink.now_ns(self.points);
        sink.event(&end)?;
        Ok(end)
    }

    /// Points sent so far.
    pub fn points_sent(&self) -> u64 {
        self.points
    }

    fn send_held<S: StationSink>(&mut self, last: bool, sink: &mut S) -> Result<(), S::Error> {
        let b = &self.begin;
        let mut h = ChunkHeader::new(b.job, b.station, self.sequence, self.held.len() as u32);
        h.last = u8::from(last);
        h.attempt = u16::from(b.attempt);
        self.points += self.held.len() as u64;
        h.timestamp_ns = sink.now_ns(self.points);
        sink.chunk(&h, &self.held)?;
        self.sequence += 1;
        self.holding = false;
        Ok(())
    }
}

/// A sink held to a scanner's rate: after each chunk it waits until the points sent through
/// it are due at `rate` points per second from `started`, so an agent sees them come as a
/// scanner would send them. Without a rate it sends as fast as the sink takes them.
#[derive(Debug)]
pub struct Paced<S> {
    /// Where the messages go.
    pub inner: S,
    rate: Option<f64>,
    started: std::time::Instant,
    sent: u64,
}

impl<S> Paced<S> {
    /// `inner` at `rate` points per second, counted from `started` with `sent_before` points
    /// already sent (a job's earlier stations).
    pub fn new(inner: S, rate: Option<f64>, started: std::time::Instant, sent_before: u64) -> Self {
        Self {
            inner,
            rate,
            started,
            sent: sent_before,
        }
    }
}

impl<S: StationSink> StationSink for Paced<S> {
    type Error = S::Error;
    fn now_ns(&mut self, points_sent: u64) -> u64 {
        self.inner.now_ns(points_sent)
    }
    fn event(&mut self, event: &StationEvent) -> Result<(), S::Error> {
        self.inner.event(event)
    }
    fn pose(&mut self, pose: &PoseSnapshot) -> Result<(), S::Error> {
        self.inner.pose(pose)
    }
    fn chunk(&mut self, header: &ChunkHeader, points: &[ScanPoint]) -> Result<(), S::Error> {
        self.inner.chunk(header, points)?;
        self.sent += points.len() as u64;
        if let Some(rate) = self.rate.filter(|r| *r > 0.0 && r.is_finite()) {
            let due = std::time::Duration::from_secs_f64(self.sent as f64 / rate);
            if let Some(ahead) = due.checked_sub(self.started.elapsed()) {
                std::thread::sleep(ahead);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PoseMode;

    #[derive(Default)]
    struct Log(Vec<String>);

    impl StationSink for Log {
        type Error = ();
        fn now_ns(&mut self, points_sent: u64) -> u64 {
            1000 + points_sent
        }
        fn event(&mut self, e: &StationEvent) -> Result<(), ()> {
            self.0.push(format!(
                "{:?} chunks {} points {} at {}",
                e.kind(),
                e.expected_chunks,
                e.expected_points,
                e.timestamp_ns
            ));
            Ok(())
        }
        fn pose(&mut self, p: &PoseSnapshot) -> Result<(), ()> {
            self.0.push(format!(
                "pose {} {} at {}",
                p.job, p.station, p.timestamp_ns
            ));
            Ok(())
        }
        fn chunk(&mut self, h: &ChunkHeader, pts: &[ScanPoint]) -> Result<(), ()> {
            self.0.push(format!(
                "chunk {} of {} last {} at {}",
                h.sequence,
                pts.len(),
                h.last,
                h.timestamp_ns
            ));
            Ok(())
        }
    }

    #[test]
    fn the_last_chunk_goes_flagged_and_end_counts_what_went() {
        let mut log = Log::default();
        let mut begin = StationEvent::new(StationEventKind::End, 4, 2);
        begin.expected_chunks = 3;
        let pose = PoseSnapshot::new(0, 0, PoseMode::DesignScanner);
        let mut s = StationSender::start(begin, pose, &mut log).unwrap();
        for n in [5, 5, 2] {
            s.chunk(&vec![ScanPoint::new(0.0, 0.0, 0.0); n], &mut log)
                .unwrap();
        }
        let end = s.finish(&mut log).unwrap();
        assert_eq!((end.expected_chunks, end.expected_points), (3, 12));
        assert_eq!(
            log.0,
            [
                "Some(Begin) chunks 3 points 0 at 1000",
                "pose 4 2 at 1000",
                "chunk 0 of 5 last 0 at 1005",
                "chunk 1 of 5 last 0 at 1010",
                "chunk 2 of 2 last 1 at 1012",
                "Some(End) chunks 3 points 12 at 1012",
            ]
        );
        // A station without points: Begin, pose, End.
        let mut log = Log::default();
        let s = StationSender::start(begin, pose, &mut log).unwrap();
        s.finish(&mut log).unwrap();
        assert_eq!(log.0.len(), 3);
    }

    #[test]
    fn a_paced_sink_sends_no_faster_than_its_rate() {
        let started = std::time::Instant::now();
        // 1,000 points already sent and 1,000 now at 20,000 points/s: due at 0.1 s.
        let mut paced = Paced::new(Log::default(), Some(20_000.0), started, 1_000);
        let h = ChunkHeader::new(1, 0, 0, 1_000);
        paced.chunk(&h, &vec![ScanPoint::default(); 1_000]).unwrap();
        assert!(started.elapsed() >= std::time::Duration::from_millis(100));
        assert_eq!(paced.inner.0.len(), 1, "the chunk went through");
        // Without a rate nothing waits: a station far ahead of any clock goes at once.
        let mut free = Paced::new(
            Log::default(),
            None,
            std::time::Instant::now(),
            u64::MAX / 2,
        );
        let t = std::time::Instant::now();
        free.chunk(&h, &[ScanPoint::default()]).unwrap();
        assert!(t.elapsed() < std::time::Duration::from_secs(5));
    }
}
