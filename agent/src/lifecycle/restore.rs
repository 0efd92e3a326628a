//! Taking a job up again after a restart: the advice given, what the printer applied, the scan
//! layer's state, the attempts already reported.

use super::*;

impl<C: ChunkSource> Lifecycle<C> {
    /// Takes up advice the agent before this one gave (from its recording), in order.
    pub fn restore_correction(&mut self, c: &LayerCorrection) {
        if let Some(k) = self.corrector.as_mut() {
            k.restore(c);
        }
    }

    /// Takes up the scan layer of `job` at `printed_height` (NaN: the whole design) from the
    /// state the agent before recorded after its last station: the printed design is prepared
    /// here and now, and the layer's next stations go on from that state. `last` is that
    /// station and the state recorded before it first closed (`None`: it was the layer's first),
    /// so that it can be sent again (see [`FindingsStage`]). `profiled`: the job is printed with
    /// a line profiler, whose passes judge the design within its range only.
    pub fn restore_scan_layer(
        &mut self,
        job: u64,
        printed_height: f64,
        state: &ScanLayerState,
        last: Option<(u32, Option<&ScanLayerState>)>,
        profiled: bool,
    ) -> Result<(), RestoreError> {
        let floor = self.pass_floor(job, printed_height, profiled);
        let design = if printed_height.is_finite() {
            self.designs.at(printed_height)?
        } else {
            self.designs.full().clone()
        };
        let stage = self.findings.as_mut().ok_or(RestoreError::FindingsOff)?;
        if stage.restore(job, &design, state, last, floor) {
            Ok(())
        } else {
            Err(RestoreError::DoesNotFit)
        }
    }

    /// Remembers that `attempt` of `key` was reported by the agent before this one (from its
    /// recording), so that its repeats and late messages change nothing.
    /// `begun_ns` is when that attempt's Begin was sent (0 when unknown).
    pub fn remember_reported(&mut self, key: StationKey, attempt: u16, begun_ns: u64) {
        if !self.closed.covers(key, attempt) {
            self.closed.push(key, attempt_of(attempt), begun_ns);
        }
    }
}
