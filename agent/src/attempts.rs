//! Station attempts: a cell scans or sends a station again after an `Interrupted` (or otherwise
//! unfinished) report, as the station's next attempt. Every message of a station carries its
//! attempt; the agent processes each attempt once, and a message of an attempt already reported
//! (a service's history after a restart, a late chunk of a try the cell gave up on) changes
//! nothing.

use std::collections::VecDeque;

/// A station: (job, station number).
pub type StationKey = (u64, u32);

/// The attempt a message names: version 1 senders wrote 0 there, which is the first try.
pub fn attempt_of(raw: u16) -> u16 {
    raw.max(1)
}

/// The stations reported recently, their last reported attempt and when its Begin was sent, in
/// fixed memory: the oldest is forgotten first.
#[derive(Debug, Clone)]
pub struct ClosedStations {
    ring: VecDeque<(StationKey, u16, u64)>,
    capacity: usize,
}

impl ClosedStations {
    /// Remembers at most `capacity` stations.
    pub fn new(capacity: usize) -> Self {
        Self {
            ring: VecDeque::with_capacity(capacity),
            capacity,
        }
    }

    /// The last attempt of `key` that was reported, if it is remembered.
    pub fn last_attempt(&self, key: StationKey) -> Option<u16> {
        self.ring
            .iter()
            .rev()
            .find(|(k, ..)| *k == key)
            .map(|&(_, a, _)| a)
    }

    /// Whether a Begin of `attempt` of `key` sent at `sent_ns` is a new send of an attempt
    /// already reported: a cell process started again (it does not know the attempts its
    /// predecessor made) sends the station anew, later than the reported attempt's Begin. A
    /// repeat of that Begin (a service's history) has its time and is not new.
    pub fn is_sent_anew(&self, key: StationKey, attempt: u16, sent_ns: u64) -> bool {
        self.ring
            .iter()
            .rev()
            .find(|(k, ..)| *k == key)
            .is_some_and(|&(_, a, begun)| a == attempt && sent_ns > begun)
    }

    /// Forgets `key` (its attempt is sent anew).
    pub fn forget(&mut self, key: StationKey) {
        self.ring.retain(|(k, ..)| *k != key);
    }

    /// Forgets every station of `job` (a new print under its number).
    pub fn forget_job(&mut self, job: u64) {
        self.ring.retain(|((j, _), ..)| *j != job);
    }

    /// Whether `attempt` of `key` (or a later one) was reported.
    pub fn covers(&self, key: StationKey, attempt: u16) -> bool {
        self.last_attempt(key).is_some_and(|a| a >= attempt)
    }

    /// Remembers that `attempt` of `key`, begun at `begun_ns` (its Begin's time; 0 unknown),
    /// was reported.
    pub fn push(&mut self, key: StationKey, attempt: u16, begun_ns: u64) {
        if let Some(at) = self.ring.iter().position(|(k, ..)| *k == key) {
            self.ring.remove(at);
        } else if self.ring.len() == self.capacity {
            self.ring.pop_front();
        }
        self.ring.push_back((key, attempt, begun_ns));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_later_attempt_is_new_and_an_earlier_one_is_covered() {
        let mut c = ClosedStations::new(2);
        c.push((1, 5), 1, 100);
        assert!(c.covers((1, 5), 1));
        assert!(!c.covers((1, 5), 2));
        // The same Begin again is a repeat; a later one is the station sent anew.
        assert!(!c.is_sent_anew((1, 5), 1, 100));
        assert!(c.is_sent_anew((1, 5), 1, 101));
        c.push((1, 5), 2, 200);
        assert_eq!(c.last_attempt((1, 5)), Some(2));
        assert!(c.covers((1, 5), 1));
        // One entry per station, and the oldest station goes first.
        c.push((1, 6), 1, 0);
        c.push((1, 7), 1, 0);
        assert_eq!(c.last_attempt((1, 5)), None);
        assert_eq!(c.last_attempt((1, 6)), Some(1));
        assert_eq!(attempt_of(0), 1);
        assert_eq!(attempt_of(3), 3);
    }
}
