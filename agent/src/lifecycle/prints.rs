//! Which print a job number names: a cell that starts a new print under a number it used before
//! (a restart, a counter that wrapped) says so with a new `job_started_ns` in its Begins. What
//! the agent kept of the last print under that number (reported attempts, findings, faces,
//! advice) must not decide anything about the new one.

use super::*;

/// The jobs seen most recently and when each started, in fixed memory.
pub(super) const PRINTS_MEMORY: usize = 16;

/// The start stamp of the latest print under each recent job number (0: not said).
#[derive(Debug, Clone, Default)]
pub(super) struct Prints {
    ring: VecDeque<(u64, u64)>,
}

impl Prints {
    /// When the latest print under `job` started, if the job is remembered.
    pub(super) fn started(&self, job: u64) -> Option<u64> {
        self.ring.iter().find(|&&(j, _)| j == job).map(|&(_, s)| s)
    }

    /// Remembers that the print under `job` started at `started`.
    pub(super) fn note(&mut self, job: u64, started: u64) {
        self.ring.retain(|&(j, _)| j != job);
        if self.ring.len() == PRINTS_MEMORY {
            self.ring.pop_front();
        }
        self.ring.push_back((job, started));
    }
}

impl<C: ChunkSource> Lifecycle<C> {
    /// Takes up the print a station event names; false for an event of an older print than
    /// the one the agent knows under its number (a service's history), which is ignored. A
    /// Begin of a print that started later begins a new print: the old print's open stations
    /// close as interrupted (its cell is gone), and its reported attempts, findings, faces and
    /// advice are forgotten. An event that does not say (a version 2 sender) changes nothing.
    pub(super) fn take_print(&mut self, ev: &StationEvent, out: &mut impl Outputs) -> bool {
        let (job, started) = (ev.job, ev.job_started_ns);
        let before = self.prints.started(job).unwrap_or(0);
        if started == 0 || started == before {
            return true;
        }
        if started < before {
            info!(
                "job {job} station {}: an event of an earlier print under this number (started \
                 at {started} ns, the current one at {before} ns), ignored",
                ev.station
            );
            return false;
        }
        if ev.kind() != Some(StationEventKind::Begin) {
            return true;
        }
        self.prints.note(job, started);
        if before == 0 {
            return true;
        }
        info!(
            "job {job}: a new print under the same number (started at {started} ns, the last one \
             at {before} ns); what the agent kept of the last one is forgotten"
        );
        while let Some(i) = self
            .open
            .iter()
            .position(|s| s.key.0 == job && s.begin.is_none_or(|b| b.job_started_ns != started))
        {
            self.close(i, Some(StationStatus::Interrupted), out);
        }
        self.closed.forget_job(job);
        if let Some(f) = &mut self.findings {
            f.forget_job(job);
        }
        if let Some(s) = &mut self.survey {
            s.forget_job(job);
        }
        if let Some(c) = &mut self.corrector {
            c.forget_job(job);
        }
        true
    }

    /// Remembers the print the agent resumes, so that a new print under its number is told
    /// from it.
    pub fn resumes_print(&mut self, job: u64, started: u64) {
        if started != 0 {
            self.prints.note(job, started);
        }
    }
}
