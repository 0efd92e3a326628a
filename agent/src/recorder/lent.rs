//! Scan chunks lent to the writer: it lays a chunk's points out from the shared-memory sample
//! they arrived in, instead of from a copy the event loop made first. The copy was work on the
//! loop's one thread while the other core waited, and cost the agent's rate about twice its CPU
//! (README, "What a recording costs").
//!
//! A lent sample stays borrowed until both are done with it: the lifecycle, which holds a
//! chunk for its pose, processes it and lets it go (then [`Lent::give_back`] puts the sample on
//! the shelf), and the writer, which says so through [`Returns`]. Only then does the sample
//! go back to the scanner. At most [`LENT_CHUNKS`] are out at once; further chunks are copied,
//! so a writer that falls behind holds no more than that many of the scanner's samples.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use asbuilt_protocol::ScanPoint;

/// Chunks lent at once, at most. The chunk subscriber admits this many borrowed samples
/// besides the lifecycle's (`QueueSizes::lent_chunks`).
pub const LENT_CHUNKS: usize = 4;

/// A lent chunk's points, sent to the writer's thread.
pub(super) struct LentPoints {
    ptr: *const ScanPoint,
    len: usize,
    ticket: u64,
}

// SAFETY: the points are only read, and the sample they lie in stays borrowed until the writer
// has stored this ticket in `Returns::done` (or is gone): the shelf keeps the sample until then.
unsafe impl Send for LentPoints {}

impl LentPoints {
    /// The points; the writer reads them before it marks the ticket done.
    pub(super) fn points(&self) -> &[ScanPoint] {
        // SAFETY: the sample is borrowed and unchanged until `Returns::done` reaches this
        // ticket, which the writer stores only after this borrow ends.
        unsafe { std::slice::from_raw_parts(self.ptr, self.len) }
    }

    pub(super) fn ticket(&self) -> u64 {
        self.ticket
    }
}

/// What the writer tells the event loop: the last lent chunk it is done with, and whether it is
/// gone (finished or failed), after which it reads nothing.
#[derive(Debug, Default)]
pub(super) struct Returns {
    done: AtomicU64,
    gone: AtomicBool,
}

impl Returns {
    /// The writer is done with every chunk lent up to `ticket` (they are lent and written in
    /// order).
    pub(super) fn done_with(&self, ticket: u64) {
        self.done.fetch_max(ticket, Ordering::Release);
    }

    /// The writer reads no more.
    pub(super) fn gone(&self) {
        self.gone.store(true, Ordering::Release);
    }

    fn finished_with(&self, ticket: u64) -> bool {
        self.done.load(Ordering::Acquire) >= ticket || self.gone.load(Ordering::Acquire)
    }
}

/// On the event loop: samples (`S`: a scan chunk's shared-memory sample) the lifecycle is done
/// with that the writer may still read.
pub(super) struct Shelf<S> {
    samples: VecDeque<(u64, S)>,
    /// Chunks lent and not yet back with the scanner.
    out: usize,
    /// The last ticket issued.
    issued: u64,
    returns: std::sync::Arc<Returns>,
}

/// A chunk lent to the writer, held beside its sample until the lifecycle lets the sample go.
pub struct Lent<S> {
    ticket: u64,
    shelf: Rc<RefCell<Shelf<S>>>,
}

impl<S> Lent<S> {
    /// The lifecycle is done with the chunk: its sample goes back to the scanner once the
    /// writer is done with it too.
    pub fn give_back(self, sample: S) {
        let mut shelf = self.shelf.borrow_mut();
        if shelf.returns.finished_with(self.ticket) {
            shelf.out -= 1;
        } else {
            shelf.samples.push_back((self.ticket, sample));
        }
    }

    /// The chunk never reached the writer: as if it had not been lent.
    pub(super) fn cancel(self) {
        let mut shelf = self.shelf.borrow_mut();
        debug_assert_eq!(shelf.issued, self.ticket, "cancelled before the next lend");
        shelf.issued -= 1;
        shelf.out -= 1;
    }
}

impl<S> Shelf<S> {
    pub(super) fn new(returns: std::sync::Arc<Returns>) -> Rc<RefCell<Self>> {
        Rc::new(RefCell::new(Self {
            samples: VecDeque::with_capacity(LENT_CHUNKS),
            out: 0,
            issued: 0,
            returns,
        }))
    }

    /// Lends `points` (lying in a sample the caller holds) when fewer than [`LENT_CHUNKS`] are
    /// out: the token for the sample's holder, and the points for the writer.
    pub(super) fn lend(
        shelf: &Rc<RefCell<Self>>,
        points: &[ScanPoint],
    ) -> Option<(Lent<S>, LentPoints)> {
        let mut s = shelf.borrow_mut();
        s.release();
        if s.out >= LENT_CHUNKS {
            return None;
        }
        s.out += 1;
        s.issued += 1;
        let ticket = s.issued;
        Some((
            Lent {
                ticket,
                shelf: shelf.clone(),
            },
            LentPoints {
                ptr: points.as_ptr(),
                len: points.len(),
                ticket,
            },
        ))
    }

    /// Returns to the scanner the samples the writer is done with.
    pub(super) fn release(&mut self) {
        let before = self.samples.len();
        let returns = &self.returns;
        self.samples.retain(|(t, _)| !returns.finished_with(*t));
        self.out -= before - self.samples.len();
    }
}

impl<S> Drop for Shelf<S> {
    fn drop(&mut self) {
        // A sample the writer may still read is not returned before it is done or gone. The
        // recorder joins its writer before its shelf goes, so this waits only if a sample's
        // holder outlived the recorder.
        for (ticket, sample) in self.samples.drain(..) {
            while !self.returns.finished_with(ticket) {
                std::thread::sleep(Duration::from_millis(1));
            }
            drop(sample);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::Cell;
    use std::sync::Arc;

    /// Stands for a shared-memory sample: counts its returns to the scanner.
    struct Sample(Rc<Cell<usize>>);

    impl Drop for Sample {
        fn drop(&mut self) {
            self.0.set(self.0.get() + 1);
        }
    }

    type Fixture = (
        Rc<RefCell<Shelf<Sample>>>,
        Arc<Returns>,
        Rc<Cell<usize>>,
        Vec<ScanPoint>,
    );

    /// A shelf, its writer's returns, the count of samples back with the scanner, and points.
    fn setup() -> Fixture {
        let returns = Arc::new(Returns::default());
        let points = vec![ScanPoint::new(1.0, 2.0, 3.0); 5];
        (
            Shelf::new(returns.clone()),
            returns,
            Rc::new(Cell::new(0)),
            points,
        )
    }

    /// A sample goes back to the scanner only when both its holder and the writer are done,
    /// in either order.
    #[test]
    fn a_sample_returns_when_holder_and_writer_are_done() {
        let (shelf, returns, back, points) = setup();
        let (a, pa) = Shelf::lend(&shelf, &points).unwrap();
        let (b, pb) = Shelf::lend(&shelf, &points).unwrap();
        assert_eq!(
            pa.points(),
            &points[..],
            "the writer reads the points where they lie"
        );
        assert_eq!((pa.ticket(), pb.ticket()), (1, 2));
        // The holder is done first: the writer is not.
        a.give_back(Sample(back.clone()));
        assert_eq!(back.get(), 0);
        returns.done_with(1);
        shelf.borrow_mut().release();
        assert_eq!(back.get(), 1);
        // The writer is done first: the sample goes back as soon as its holder lets it go.
        returns.done_with(2);
        b.give_back(Sample(back.clone()));
        assert_eq!(back.get(), 2);
        assert_eq!(shelf.borrow().out, 0);
    }

    /// No more than LENT_CHUNKS are out; a slot frees when its sample returns, and a lend that
    /// never reached the writer is undone.
    #[test]
    fn lending_is_bounded_and_a_cancelled_lend_is_undone() {
        let (shelf, returns, back, points) = setup();
        let lent: Vec<_> = (0..LENT_CHUNKS)
            .map(|_| Shelf::lend(&shelf, &points).unwrap().0)
            .collect();
        assert!(
            Shelf::lend(&shelf, &points).is_none(),
            "the rest are copied"
        );
        for l in lent {
            l.give_back(Sample(back.clone()));
        }
        assert!(
            Shelf::lend(&shelf, &points).is_none(),
            "the writer still reads them"
        );
        returns.done_with(LENT_CHUNKS as u64);
        let (l, _) = Shelf::lend(&shelf, &points).expect("released on the next lend");
        assert_eq!(back.get(), LENT_CHUNKS);
        l.cancel();
        assert_eq!(shelf.borrow().out, 0);
        let (_, p) = Shelf::lend(&shelf, &points).unwrap();
        assert_eq!(
            p.ticket(),
            LENT_CHUNKS as u64 + 1,
            "the cancelled ticket is issued again"
        );
    }

    /// A writer that is gone reads nothing more: its samples go back at once.
    #[test]
    fn a_gone_writer_frees_every_sample() {
        let (shelf, returns, back, points) = setup();
        let (a, _) = Shelf::lend(&shelf, &points).unwrap();
        a.give_back(Sample(back.clone()));
        returns.gone();
        shelf.borrow_mut().release();
        assert_eq!(back.get(), 1);
    }

    /// A shelf dropped while the writer still reads waits for it, never returning a sample
    /// under the writer.
    #[test]
    fn a_dropped_shelf_waits_for_the_writer() {
        let (shelf, returns, back, points) = setup();
        let (a, _) = Shelf::lend(&shelf, &points).unwrap();
        a.give_back(Sample(back.clone()));
        let writer = {
            let returns = returns.clone();
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(50));
                returns.done_with(1);
            })
        };
        let start = std::time::Instant::now();
        drop(shelf);
        assert!(
            start.elapsed() >= Duration::from_millis(40),
            "{:?}",
            start.elapsed()
        );
        assert_eq!(back.get(), 1);
        writer.join().unwrap();
    }
}
