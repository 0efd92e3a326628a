//! Chunk sequence numbers of one station: which chunks to process, which are repeats, and how
//! many went missing. Memory is fixed: a 64-chunk window behind the highest sequence seen, so a
//! late chunk within that window is still used once, and one older than that is counted as out
//! of order and dropped.

use asbuilt_protocol::ChunkCounts;

/// How far behind the newest chunk a late one is still accepted.
const WINDOW: u64 = 64;

/// What to do with a chunk, by its sequence number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChunkVerdict {
    /// Process it.
    Accept,
    /// Arrived late, but within the window and not seen before: process it.
    AcceptLate,
    /// Already processed: drop it, count it.
    Duplicate,
    /// Too late to tell whether it is new: drop it, count it.
    TooOld,
}

/// One station's chunk sequence numbers: the highest accepted and a window behind it.
#[derive(Debug, Clone, Default)]
pub struct SequenceTracker {
    /// One past the highest sequence accepted.
    next: u64,
    /// Bit i set: sequence `next - 1 - i` was accepted.
    seen: u64,
    counts: ChunkCounts,
}

impl SequenceTracker {
    /// A tracker that has seen no chunk.
    pub fn new() -> Self {
        Self::default()
    }

    /// The verdict on chunk `sequence`, counted.
    pub fn offer(&mut self, sequence: u64) -> ChunkVerdict {
        let verdict = if sequence >= self.next {
            let shift = sequence - self.next + 1;
            self.seen = if shift >= 64 { 0 } else { self.seen << shift };
            self.seen |= 1;
            self.next = sequence + 1;
            ChunkVerdict::Accept
        } else {
            let behind = self.next - 1 - sequence;
            if behind >= WINDOW {
                ChunkVerdict::TooOld
            } else if self.seen & (1 << behind) != 0 {
                ChunkVerdict::Duplicate
            } else {
                self.seen |= 1 << behind;
                ChunkVerdict::AcceptLate
            }
        };
        match verdict {
            ChunkVerdict::Accept => self.counts.received += 1,
            ChunkVerdict::AcceptLate => {
                self.counts.received += 1;
                self.counts.out_of_order += 1;
            }
            ChunkVerdict::Duplicate => self.counts.duplicate += 1,
            ChunkVerdict::TooOld => self.counts.out_of_order += 1,
        }
        verdict
    }

    /// Counts at station end. `expected` is the chunk count the End event announced (0 if
    /// unknown); without it, gaps below the highest sequence are still missing chunks.
    pub fn finish(&self, expected: u64) -> ChunkCounts {
        let mut c = self.counts;
        c.expected = expected;
        let span = self.next.max(expected);
        c.missing = span.saturating_sub(c.received);
        c
    }

    /// True when every announced chunk arrived exactly once, in whatever order.
    pub fn is_complete(&self, expected: u64) -> bool {
        let c = self.finish(expected);
        c.missing == 0 && c.duplicate == 0 && (expected == 0 || c.received == expected)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn in_order_stream_is_complete() {
        let mut t = SequenceTracker::new();
        for s in 0..10 {
            assert_eq!(t.offer(s), ChunkVerdict::Accept);
        }
        assert!(t.is_complete(10));
        let c = t.finish(10);
        assert_eq!((c.received, c.missing, c.duplicate), (10, 0, 0));
    }

    /// A tracker offered each sequence in turn, every verdict checked.
    fn offered(offers: &[(u64, ChunkVerdict)]) -> SequenceTracker {
        let mut t = SequenceTracker::new();
        for &(sequence, verdict) in offers {
            assert_eq!(t.offer(sequence), verdict, "sequence {sequence}");
        }
        t
    }

    #[test]
    fn duplicates_gaps_and_late_chunks_are_told_apart() {
        use ChunkVerdict::*;
        let t = offered(&[
            (0, Accept),
            (2, Accept),
            (2, Duplicate),
            (1, AcceptLate),
            (1, Duplicate),
            (5, Accept),
        ]);
        let c = t.finish(7);
        assert_eq!(c.received, 4);
        assert_eq!(c.duplicate, 2);
        assert_eq!(c.out_of_order, 1);
        // 3, 4 never came; 6 was announced and never came.
        assert_eq!(c.missing, 3);
        assert!(!t.is_complete(7));
    }

    #[test]
    fn chunks_older_than_the_window_are_counted_not_trusted() {
        use ChunkVerdict::*;
        let t = offered(&[(0, Accept), (200, Accept), (100, TooOld), (199, AcceptLate)]);
        let c = t.finish(0);
        assert_eq!(c.received, 3);
        assert_eq!(c.missing, 201 - 3);
    }
}
