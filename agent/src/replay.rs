//! A recording's inputs fed to the station lifecycle as the agent took them: `asbuilt report`
//! and `asbuilt replay` read a job back this way, and a resuming agent takes up its job this way.

use std::time::Instant;

use asbuilt_protocol::recording::Recorded;
use asbuilt_protocol::{ChunkHeader, ScanPoint, StationEvent, StationEventKind, StationStatus};

use crate::lifecycle::{ChunkSource, Input, Lifecycle, Outputs};

/// Feeds one recorded message: station events, poses, scan chunks, a line profiler's mount
/// poses and profiles, and the printer's answers as the agent took them,
/// and an `Interrupted` report where a resumed agent said a station attempt was cut off. Other
/// outputs (reports, findings, deviations, status) change nothing: the lifecycle computes its
/// own.
pub fn feed<C>(lifecycle: &mut Lifecycle<C>, m: Recorded, now: Instant, out: &mut impl Outputs)
where
    C: ChunkSource + From<(ChunkHeader, Vec<ScanPoint>)>,
{
    match m {
        Recorded::Event(e) => lifecycle.take(Input::Event(e), now, out),
        Recorded::Pose(p) => lifecycle.take(Input::Pose(p), now, out),
        Recorded::Applied(a) => lifecycle.take(Input::Applied(a), now, out),
        Recorded::MountPose(m) => lifecycle.take(Input::MountPose(m), now, out),
        Recorded::Profiles(h, pts) => {
            // As a chunk: the same batches whether the design was ready or not.
            if lifecycle.pass_awaits_design(h.job, h.pass) {
                lifecycle.wait_designs(now, out);
            }
            lifecycle.take(Input::Profiles(h, pts), now, out);
        }
        Recorded::Chunk(h, pts) => {
            // The live agent's chunks waited while their printed height was prepared.
            if lifecycle.awaits_design(&h) {
                lifecycle.wait_designs(now, out);
            }
            lifecycle.take(Input::Chunk(C::from((h, pts))), now, out);
        }
        Recorded::Report(r) if r.status() == Some(StationStatus::Interrupted) => {
            let mut begin = StationEvent::new(StationEventKind::Begin, r.job, r.station);
            begin.attempt = r.attempt;
            begin.name = r.name;
            begin.layer = r.layer;
            begin.printed_height = r.printed_height;
            lifecycle.interrupt(&begin, out);
        }
        _ => {}
    }
}
