//! The lifecycle against plain vectors of messages.

use super::*;
use asbuilt_core::C2mParams;
use asbuilt_core::design::shapes;
use asbuilt_protocol::{PoseMode, ScanPointFlags};

struct Owned(ChunkHeader, Vec<ScanPoint>);
impl ChunkSource for Owned {
    fn header(&self) -> &ChunkHeader {
        &self.0
    }
    fn points(&self) -> &[ScanPoint] {
        &self.1
    }
}

#[derive(Default)]
struct Collect {
    deviations: Vec<(DeviationHeader, Vec<PointDeviation>)>,
    reports: Vec<StationReport>,
}
impl Outputs for Collect {
    fn deviations(
        &mut self,
        n: usize,
        fill: &mut dyn FnMut(&mut [PointDeviation]) -> DeviationHeader,
    ) {
        let mut buf = vec![PointDeviation::default(); n];
        let h = fill(&mut buf);
        self.deviations.push((h, buf));
    }
    fn report(&mut self, r: &StationReport) {
        self.reports.push(*r);
    }
}

/// A 1 m cube centred at the origin; points on its top face, 2 mm above it.
fn cube() -> PrintedDesigns {
    let d = shapes::cuboid(
        nalgebra::Point3::new(-0.5, -0.5, -0.5),
        nalgebra::Point3::new(0.5, 0.5, 0.5),
    );
    PrintedDesigns::new(d, C2mParams::within(0.05)).unwrap()
}

fn limits() -> LifecycleLimits {
    LifecycleLimits {
        max_points_per_chunk: 100,
        pending_chunks: 4,
        open_stations: 2,
        station_timeout: Duration::from_secs(10),
    }
}

fn chunk(station: u32, seq: u64, n: usize) -> Owned {
    let pts = (0..n)
        .map(|i| ScanPoint::new(-0.4 + 0.008 * i as f32, 0.1, 0.502))
        .collect();
    Owned(ChunkHeader::new(1, station, seq, n as u32), pts)
}

fn pose(station: u32) -> PoseSnapshot {
    PoseSnapshot::new(1, station, PoseMode::DesignScanner)
}

fn event(kind: StationEventKind, station: u32, chunks: u32) -> StationEvent {
    let mut e = StationEvent::new(kind, 1, station);
    e.expected_chunks = chunks;
    e
}

/// Station `station`'s Begin, announcing `chunks` chunks, and its pose.
fn begin_with_pose(
    lc: &mut Lifecycle<Owned>,
    out: &mut Collect,
    t: Instant,
    station: u32,
    chunks: u32,
) {
    lc.on_event(&event(StationEventKind::Begin, station, chunks), t, out);
    lc.on_pose(&pose(station), t, out);
}

#[test]
fn a_clean_station_reports_complete_when_its_last_chunk_is_in() {
    let (mut lc, mut out, t) = setup();
    begin_with_pose(&mut lc, &mut out, t, 7, 0);
    for s in 0..3 {
        lc.on_chunk(chunk(7, s, 50), t, &mut out);
    }
    assert!(out.reports.is_empty());
    lc.on_event(&event(StationEventKind::End, 7, 3), t, &mut out);
    assert_eq!(out.reports.len(), 1);
    let r = out.reports[0];
    assert_eq!(r.status(), Some(StationStatus::Complete));
    assert_eq!(r.points_received, 150);
    assert_eq!(r.stats.count, 150);
    assert!((r.stats.mean - 0.002).abs() < 1e-6, "{}", r.stats.mean);
    assert_eq!(out.deviations.len(), 3);
    assert_eq!(out.deviations[2].0.sequence, 2);
    assert_eq!(lc.stations_open(), 0);
}

/// A lifecycle on the cube, nothing received yet, with what it sends and the time it starts.
fn setup() -> (Lifecycle<Owned>, Collect, Instant) {
    let lc = Lifecycle::new(cube(), FrameChain::default(), cfg(), limits());
    (lc, Collect::default(), Instant::now())
}

fn cfg() -> InspectParams {
    InspectParams::with_tolerance(0.005)
}

#[test]
fn chunks_before_their_pose_wait_and_are_then_processed() {
    let (mut lc, mut out, t) = setup();
    lc.on_chunk(chunk(3, 0, 10), t, &mut out);
    lc.on_event(&event(StationEventKind::Begin, 3, 2), t, &mut out);
    lc.on_chunk(chunk(3, 1, 10), t, &mut out);
    assert_eq!(lc.chunks_waiting(), 2);
    lc.on_pose(&pose(3), t, &mut out);
    assert_eq!(lc.chunks_waiting(), 0);
    lc.on_event(&event(StationEventKind::End, 3, 2), t, &mut out);
    let r = out.reports[0];
    assert_eq!(r.status(), Some(StationStatus::Complete));
    assert_eq!(r.stats.count, 20);
}

#[test]
fn a_station_knows_the_layer_its_begin_gave() {
    let (mut lc, mut out, t) = setup();
    assert_eq!(lc.layer_of(4, 1), 0);
    let mut begin = event(StationEventKind::Begin, 1, 2);
    begin.job = 4;
    begin.layer = 17;
    lc.on_event(&begin, t, &mut out);
    assert_eq!(lc.layer_of(4, 1), 17);
    assert_eq!(lc.layer_of(4, 2), 0);
}

#[test]
fn an_end_that_overtakes_its_last_chunks_waits_for_them() {
    let (mut lc, mut out, t) = setup();
    begin_with_pose(&mut lc, &mut out, t, 2, 3);
    lc.on_chunk(chunk(2, 0, 10), t, &mut out);
    lc.on_event(&event(StationEventKind::End, 2, 3), t, &mut out);
    // The queues run empty before the last chunks, sent by another process, are seen.
    lc.on_idle(t + END_GRACE / 2, &mut out);
    assert!(out.reports.is_empty());
    lc.on_chunk(chunk(2, 1, 10), t + END_GRACE / 2, &mut out);
    lc.on_chunk(chunk(2, 2, 10), t + END_GRACE / 2, &mut out);
    assert_eq!(out.reports[0].status(), Some(StationStatus::Complete));
    assert_eq!(out.reports[0].stats.count, 30);

    // A chunk that never comes: the station is reported incomplete after the grace.
    begin_with_pose(&mut lc, &mut out, t, 3, 2);
    lc.on_chunk(chunk(3, 0, 10), t, &mut out);
    lc.on_event(&event(StationEventKind::End, 3, 2), t, &mut out);
    lc.on_idle(t + END_GRACE / 2, &mut out);
    assert_eq!(out.reports.len(), 1);
    lc.on_idle(t + END_GRACE, &mut out);
    assert_eq!(out.reports[1].status(), Some(StationStatus::Incomplete));
    assert_eq!(out.reports[1].chunks.missing, 1);
}

#[test]
fn a_station_without_pose_is_reported_with_every_point_counted() {
    let (mut lc, mut out, t) = setup();
    lc.on_event(&event(StationEventKind::Begin, 3, 0), t, &mut out);
    for s in 0..6 {
        lc.on_chunk(chunk(3, s, 10), t, &mut out);
    }
    // Two were pushed out of the 4-chunk buffer.
    assert_eq!(lc.counters.input.chunks_pending_overflow, 2);
    lc.on_event(&event(StationEventKind::End, 3, 6), t, &mut out);
    lc.on_idle(t + END_GRACE, &mut out);
    let r = out.reports[0];
    assert_eq!(r.status(), Some(StationStatus::Incomplete));
    assert_eq!(r.points_received, 60);
    assert_eq!(r.rejected.without_pose, 60);
    assert_eq!(r.chunks.missing, 0);
    assert_eq!(r.stats.count, 0);
}

#[test]
fn bad_chunks_are_counted_by_reason_and_good_points_kept() {
    let (mut lc, mut out, t) = setup();
    begin_with_pose(&mut lc, &mut out, t, 1, 0);
    let mut c = chunk(1, 0, 10);
    c.1[0].xyz[0] = f32::NAN;
    c.1[1].flags = ScanPointFlags(ScanPointFlags::INVALID);
    c.1[2].xyz = [1e6, 0.0, 0.0];
    lc.on_chunk(c, t, &mut out);
    lc.on_chunk(chunk(1, 0, 10), t, &mut out); // repeat
    lc.on_chunk(chunk(1, 1, 0), t, &mut out); // empty
    lc.on_chunk(chunk(1, 2, 101), t, &mut out); // oversized
    let mut lying = chunk(1, 3, 10);
    lying.0.point_count = 11;
    lc.on_chunk(lying, t, &mut out);
    let mut future = chunk(1, 4, 10);
    future.0.version = 9;
    lc.on_chunk(future, t, &mut out);
    lc.on_chunk(chunk(1, 5, 10), t, &mut out);
    lc.on_event(&event(StationEventKind::End, 1, 6), t, &mut out);
    lc.on_idle(t + END_GRACE, &mut out);
    let r = out.reports[0];
    let i = lc.counters.input;
    assert_eq!(
        (
            i.chunks_duplicate,
            i.chunks_empty,
            i.chunks_oversized,
            i.chunks_malformed,
            i.version_mismatch
        ),
        (1, 1, 1, 1, 1)
    );
    assert_eq!(r.rejected.non_finite, 1);
    assert_eq!(r.rejected.scanner_invalid, 1);
    assert_eq!(r.rejected.out_of_range, 1);
    assert_eq!(r.rejected.in_rejected_chunks, 10 + 101 + 10);
    assert_eq!(r.stats.count, 7 + 10);
    assert_eq!(r.chunks.missing, 1, "chunk 4 was never usable");
    assert_eq!((r.chunks.empty, r.chunks.oversized), (1, 1));
    assert_eq!(r.status(), Some(StationStatus::Incomplete));
    assert_eq!(lc.counters.rejected_points.total(), r.rejected.total());
}

#[test]
fn silence_closes_a_station_as_timed_out_and_late_chunks_are_counted() {
    let (mut lc, mut out, t) = setup();
    begin_with_pose(&mut lc, &mut out, t, 2, 0);
    lc.on_chunk(chunk(2, 0, 10), t, &mut out);
    lc.on_chunk(chunk(9, 0, 10), t, &mut out); // never begins
    lc.on_tick(t + Duration::from_secs(5), &mut out);
    assert!(out.reports.is_empty());
    lc.on_tick(t + Duration::from_secs(11), &mut out);
    assert_eq!(out.reports[0].status(), Some(StationStatus::TimedOut));
    assert_eq!(out.reports[0].stats.count, 10);
    assert_eq!(lc.counters.input.chunks_unknown_station, 1);
    lc.on_chunk(chunk(2, 1, 10), t, &mut out);
    assert_eq!(lc.counters.input.chunks_after_close, 1);
}

#[test]
fn shutdown_writes_partial_reports() {
    let (mut lc, mut out, t) = setup();
    lc.on_pose(&pose(4), t, &mut out);
    lc.on_chunk(chunk(4, 0, 10), t, &mut out);
    lc.shutdown(&mut out);
    assert_eq!(out.reports[0].status(), Some(StationStatus::Partial));
    assert_eq!(out.reports[0].stats.count, 10);
}

#[test]
fn too_many_open_stations_close_the_least_recent_one() {
    let (mut lc, mut out, t) = setup();
    for (k, s) in [1u32, 2, 3].into_iter().enumerate() {
        lc.on_event(
            &event(StationEventKind::Begin, s, 0),
            t + Duration::from_millis(k as u64),
            &mut out,
        );
    }
    assert_eq!(lc.stations_open(), 2);
    assert_eq!(out.reports.len(), 1);
    assert_eq!(out.reports[0].station, 1);
    assert_eq!(out.reports[0].status(), Some(StationStatus::Incomplete));
}

#[test]
fn a_bad_pose_is_rejected_and_the_station_waits_for_a_good_one() {
    let (mut lc, mut out, t) = setup();
    let mut p = pose(5);
    p.rotation_xyzw = [0.0, 0.0, 0.0, 3.0];
    lc.on_pose(&p, t, &mut out);
    assert_eq!(lc.counters.input.poses_invalid, 1);
    lc.on_chunk(chunk(5, 0, 10), t, &mut out);
    assert_eq!(lc.chunks_waiting(), 1);
    lc.on_pose(&pose(5), t, &mut out);
    assert_eq!(lc.chunks_waiting(), 0);
    assert_eq!(out.deviations.len(), 1);
}

#[test]
fn a_new_printed_height_is_prepared_off_the_loop_while_its_chunks_wait() {
    let (mut lc, mut out, t) = setup();
    let mut begin = event(StationEventKind::Begin, 7, 2);
    // Cut at z = 0.3: the points 2 mm above the full cube's top are 0.202 m above the cap,
    // beyond the maximum distance.
    begin.printed_height = 0.3;
    lc.on_event(&begin, t, &mut out);
    lc.on_pose(&pose(7), t, &mut out);
    lc.on_chunk(chunk(7, 0, 50), t, &mut out);
    // The chunk waits for the design; the loop went on without preparing it.
    assert!(lc.is_preparing());
    assert!(out.deviations.is_empty());
    assert_eq!(lc.chunks_waiting(), 1);
    let waited = Instant::now();
    while lc.is_preparing() {
        assert!(waited.elapsed() < Duration::from_secs(10), "never prepared");
        std::thread::sleep(Duration::from_millis(1));
        lc.poll_designs(Instant::now(), &mut out);
    }
    assert_eq!(out.deviations.len(), 1, "the held chunk went through");
    lc.on_chunk(chunk(7, 1, 50), t, &mut out);
    lc.on_event(&event(StationEventKind::End, 7, 2), t, &mut out);
    assert_eq!(out.reports.len(), 1);
    assert_eq!(
        out.reports[0].no_match, 100,
        "compared with the cut, not the whole cube"
    );
    // A second station at the same height uses the prepared design at once.
    lc.on_event(&begin_at(8, 0.3), t, &mut out);
    lc.on_pose(&pose(8), t, &mut out);
    lc.on_chunk(chunk(8, 0, 10), t, &mut out);
    assert!(!lc.is_preparing());
    assert_eq!(out.deviations.len(), 3);
}

fn begin_at(station: u32, height: f64) -> StationEvent {
    let mut e = event(StationEventKind::Begin, station, 1);
    e.printed_height = height;
    e
}

fn with_attempt(mut c: Owned, attempt: u16) -> Owned {
    c.0.attempt = attempt;
    c
}

/// A Begin (from a service's history, or repeated) of a station attempt already reported
/// opens nothing: the attempt is reported once.
#[test]
fn a_begin_of_a_reported_attempt_opens_nothing() {
    let (mut lc, mut out, t) = setup();
    begin_with_pose(&mut lc, &mut out, t, 5, 1);
    lc.on_chunk(chunk(5, 0, 10), t, &mut out);
    lc.on_event(&event(StationEventKind::End, 5, 1), t, &mut out);
    assert_eq!(out.reports.len(), 1);
    begin_with_pose(&mut lc, &mut out, t, 5, 1);
    lc.on_event(&event(StationEventKind::End, 5, 1), t, &mut out);
    assert_eq!(lc.stations_open(), 0);
    lc.on_tick(t + Duration::from_secs(60), &mut out);
    lc.shutdown(&mut out);
    assert_eq!(out.reports.len(), 1, "{:?}", out.reports);
}

/// The cell sends a station again as attempt 2: the open attempt 1 closes interrupted
/// (adding nothing to findings), attempt 2 is processed on its own, and what attempt 1
/// still sends is dropped and counted.
#[test]
fn a_second_attempt_replaces_the_first_and_late_chunks_of_the_first_are_dropped() {
    let (mut lc, mut out, t) = setup();
    begin_with_pose(&mut lc, &mut out, t, 2, 2);
    lc.on_chunk(chunk(2, 0, 10), t, &mut out);
    let mut begin = event(StationEventKind::Begin, 2, 2);
    begin.attempt = 2;
    lc.on_event(&begin, t, &mut out);
    let mut p = pose(2);
    p.attempt = 2;
    lc.on_pose(&p, t, &mut out);
    assert_eq!(out.reports.len(), 1);
    assert_eq!(out.reports[0].status(), Some(StationStatus::Interrupted));
    assert_eq!(out.reports[0].attempt, 1);
    lc.on_chunk(chunk(2, 1, 10), t, &mut out);
    assert_eq!(lc.counters.input.chunks_after_close, 1);
    lc.on_chunk(with_attempt(chunk(2, 0, 10), 2), t, &mut out);
    lc.on_chunk(with_attempt(chunk(2, 1, 10), 2), t, &mut out);
    let mut end = event(StationEventKind::End, 2, 2);
    end.attempt = 2;
    lc.on_event(&end, t, &mut out);
    assert_eq!(out.reports.len(), 2);
    let r = out.reports[1];
    assert_eq!((r.status(), r.attempt), (Some(StationStatus::Complete), 2));
    assert_eq!(r.stats.count, 20);
}

/// A chunk past the first of a station never begun: the station began before this agent
/// started. It is dropped at once, not held for the station timeout, and the attempt is
/// reported interrupted once, so the cell sends it again.
#[test]
fn a_station_that_began_before_the_agent_is_reported_interrupted_at_once() {
    let (mut lc, mut out, t) = setup();
    lc.on_chunk(chunk(9, 4, 10), t, &mut out);
    lc.on_chunk(chunk(9, 5, 10), t, &mut out);
    assert_eq!(lc.chunks_waiting(), 0);
    assert_eq!(out.reports.len(), 1);
    assert_eq!(out.reports[0].status(), Some(StationStatus::Interrupted));
    assert_eq!(lc.counters.input.chunks_unknown_station, 1);
    assert_eq!(lc.counters.input.chunks_after_close, 1);
    // Its End (and a Begin from history) change nothing.
    lc.on_event(&event(StationEventKind::End, 9, 6), t, &mut out);
    assert_eq!(out.reports.len(), 1);
}

/// An agent resuming its job closes what the agent before left open as interrupted; a
/// reader of the recording does the same where the resumed agent said so.
#[test]
fn stations_left_open_are_interrupted_once() {
    let (mut lc, mut out, t) = setup();
    begin_with_pose(&mut lc, &mut out, t, 1, 3);
    lc.on_chunk(chunk(1, 0, 10), t, &mut out);
    assert_eq!(lc.interrupt_open(&mut out), vec![(1, 1)]);
    lc.interrupt(&event(StationEventKind::Begin, 1, 3), &mut out);
    assert_eq!(out.reports.len(), 1);
    assert_eq!(out.reports[0].status(), Some(StationStatus::Interrupted));
    // An attempt reported interrupted that was never open here is reported all the same.
    let mut begin = event(StationEventKind::Begin, 4, 0);
    begin.attempt = 2;
    begin.name = asbuilt_protocol::FixedText::truncated("L008-S4");
    lc.interrupt(&begin, &mut out);
    assert_eq!(out.reports.len(), 2);
    assert_eq!((out.reports[1].station, out.reports[1].attempt), (4, 2));
    assert_eq!(out.reports[1].name.as_str(), "L008-S4");
}

/// Outputs that keep reports, findings and the scan layer states.
#[derive(Default)]
struct WithStates {
    inner: Collect,
    findings: Vec<StationFindings>,
    states: Vec<asbuilt_core::scan_layer::ScanLayerState>,
}
impl Outputs for WithStates {
    fn deviations(
        &mut self,
        n: usize,
        fill: &mut dyn FnMut(&mut [PointDeviation]) -> DeviationHeader,
    ) {
        self.inner.deviations(n, fill)
    }
    fn report(&mut self, r: &StationReport) {
        self.inner.report(r)
    }
    fn findings(&mut self, f: &StationFindings) {
        self.findings.push(f.clone());
    }
    fn wants_scan_layer_state(&self) -> bool {
        true
    }
    fn scan_layer_state(
        &mut self,
        _: &StationReport,
        state: &asbuilt_core::scan_layer::ScanLayerState,
    ) {
        self.states.push(state.clone());
    }
}

fn with_findings() -> Lifecycle<Owned> {
    let (lc, _, _) = setup();
    let config = crate::config::FindingsConfig {
        enabled: true,
        ..Default::default()
    };
    lc.with_findings(FindingsStage::new(config, 0.005, 0.05, 100))
}

/// A station of 4 chunks of 100 points on the cube's top, 2 mm above it, shifted by `dx`.
fn station_on_top(lc: &mut Lifecycle<Owned>, out: &mut WithStates, station: u32, dx: f32) {
    attempt_on_top(lc, out, (station, 1), dx, 4);
}

/// Attempt `key.1` of station `key.0` as [`station_on_top`] sends it, of which only the
/// first `sent` chunks arrive; a station with chunks missing closes incomplete.
fn attempt_on_top(
    lc: &mut Lifecycle<Owned>,
    out: &mut WithStates,
    (station, attempt): (u32, u8),
    dx: f32,
    sent: u64,
) {
    let t = Instant::now();
    let mut p = pose(station);
    p.translation = [0.0, 0.0, 2.0];
    p.attempt = attempt;
    let mut begin = event(StationEventKind::Begin, station, 4);
    begin.attempt = attempt;
    lc.on_event(&begin, t, out);
    lc.on_pose(&p, t, out);
    for seq in 0..sent {
        let pts = (0..100)
            .map(|i| {
                let x = -0.45 + 0.009 * i as f32 + dx;
                let y = -0.45 + 0.3 * seq as f32;
                ScanPoint::new(x, y, -1.498)
            })
            .collect();
        let c = Owned(ChunkHeader::new(1, station, seq, 100), pts);
        lc.on_chunk(with_attempt(c, attempt.into()), t, out);
    }
    let mut end = event(StationEventKind::End, station, 4);
    end.attempt = attempt;
    lc.on_event(&end, t, out);
    lc.on_idle(t + END_GRACE, out);
}

/// A station whose first attempt got half its chunks through, reported incomplete and sent
/// again, counts once in its scan layer: the findings after it and after the next station
/// are those of a job whose station was complete the first time, bit for bit. An agent that
/// takes the layer up from the state recorded after the incomplete attempt does the same.
#[test]
fn an_incomplete_attempt_sent_again_counts_once_in_the_findings() {
    let bytes = |f: &StationFindings| asbuilt_protocol::codec::encode(f);
    let mut clean = with_findings();
    let mut out_clean = WithStates::default();
    for (station, dx) in [(1, 0.0), (2, 0.004), (3, 0.002)] {
        station_on_top(&mut clean, &mut out_clean, station, dx);
    }
    let mut retried = with_findings();
    let mut out_retried = WithStates::default();
    station_on_top(&mut retried, &mut out_retried, 1, 0.0);
    attempt_on_top(&mut retried, &mut out_retried, (2, 1), 0.004, 2);
    let r = out_retried.inner.reports[1];
    assert_eq!(
        (r.status(), r.attempt),
        (Some(StationStatus::Incomplete), 1)
    );
    // The incomplete attempt's points are in the findings until the station comes again.
    assert_eq!(out_retried.findings[1].stations, 2);
    assert_ne!(
        bytes(&out_retried.findings[1]),
        bytes(&out_clean.findings[1])
    );
    attempt_on_top(&mut retried, &mut out_retried, (2, 2), 0.004, 4);
    station_on_top(&mut retried, &mut out_retried, 3, 0.002);
    assert_eq!(out_retried.findings.len(), 4);
    for (a, b) in [(2, 1), (3, 2)] {
        assert_eq!(
            bytes(&out_retried.findings[a]),
            bytes(&out_clean.findings[b])
        );
        assert_eq!(out_retried.states[a], out_clean.states[b]);
    }

    // Killed after the incomplete attempt: the next agent takes up the state recorded after
    // it, and the one before it, and goes on as the agent that never stopped.
    let mut resumed = with_findings();
    let mut out_resumed = WithStates::default();
    let (after, before) = (&out_retried.states[1], &out_retried.states[0]);
    resumed
        .restore_scan_layer(1, f64::NAN, after, Some((2, Some(before))), false)
        .unwrap();
    resumed.remember_reported((1, 2), 1, 0);
    attempt_on_top(&mut resumed, &mut out_resumed, (2, 2), 0.004, 4);
    station_on_top(&mut resumed, &mut out_resumed, 3, 0.002);
    assert_eq!(out_resumed.findings.len(), 2);
    assert_eq!(
        bytes(&out_resumed.findings[1]),
        bytes(&out_clean.findings[2])
    );

    // A station that was the scan layer's first goes back to the layer's start.
    let mut first = with_findings();
    let mut out_first = WithStates::default();
    attempt_on_top(&mut first, &mut out_first, (1, 1), 0.0, 1);
    attempt_on_top(&mut first, &mut out_first, (1, 2), 0.0, 4);
    assert_eq!(bytes(&out_first.findings[1]), bytes(&out_clean.findings[0]));
}

/// An agent that takes up a scan layer from the state recorded after its second station
/// draws, after the third, the findings of the agent that never stopped, bit for bit.
#[test]
fn a_scan_layer_taken_up_from_its_state_goes_on_as_if_never_stopped() {
    let mut a = with_findings();
    let mut out_a = WithStates::default();
    for (station, dx) in [(1, 0.0), (2, 0.004)] {
        station_on_top(&mut a, &mut out_a, station, dx);
    }
    assert_eq!(out_a.states.len(), 2, "{:?}", out_a.inner.reports);
    let saved = out_a.states[1].clone();
    assert_eq!(saved.stations, 2);
    let encoded = postcard::to_allocvec(&saved).unwrap();
    let decoded: asbuilt_core::scan_layer::ScanLayerState = postcard::from_bytes(&encoded).unwrap();
    assert_eq!(decoded, saved);

    let mut b = with_findings();
    let mut out_b = WithStates::default();
    b.restore_scan_layer(1, f64::NAN, &decoded, None, false)
        .unwrap();
    station_on_top(&mut a, &mut out_a, 3, 0.002);
    station_on_top(&mut b, &mut out_b, 3, 0.002);
    let bytes = |f: &StationFindings| asbuilt_protocol::codec::encode(f);
    assert_eq!(out_a.findings.len(), 3);
    assert_eq!(out_b.findings.len(), 1);
    assert_eq!(bytes(&out_a.findings[2]), bytes(&out_b.findings[0]));
    assert_eq!(out_a.states[2], out_b.states[0]);
    assert_eq!(out_b.findings[0].stations, 3);
    // A state of another design does not fit, and says so.
    let mut other = saved.clone();
    other.samples += 1;
    assert!(
        with_findings()
            .restore_scan_layer(1, f64::NAN, &other, None, false)
            .is_err()
    );
}

/// Station `station` of the print started at `started`, sent whole: Begin, pose, one chunk
/// flagged last.
fn station_of_print(lc: &mut Lifecycle<Owned>, out: &mut Collect, started: u64, station: u32) {
    let t = Instant::now();
    let mut begin = event(StationEventKind::Begin, station, 1);
    begin.job_started_ns = started;
    lc.on_event(&begin, t, out);
    lc.on_pose(&pose(station), t, out);
    let mut c = chunk(station, 0, 10);
    c.0.last = 1;
    lc.on_chunk(c, t, out);
}

#[test]
fn a_new_print_under_a_used_job_number_is_served_afresh_and_an_older_one_is_not() {
    let (mut lc, mut out, t) = setup();
    station_of_print(&mut lc, &mut out, 100, 0);
    assert_eq!(out.reports.len(), 1);
    // The same print's station again (a service's history): already reported.
    station_of_print(&mut lc, &mut out, 100, 0);
    assert_eq!(out.reports.len(), 1);
    // A station of the first print left open when its cell went away.
    let mut begin = event(StationEventKind::Begin, 1, 2);
    begin.job_started_ns = 100;
    lc.on_event(&begin, t, &mut out);
    lc.on_pose(&pose(1), t, &mut out);
    // A new print reuses job 1: the open station of the old one is interrupted, and station 0
    // is served again.
    station_of_print(&mut lc, &mut out, 200, 0);
    let got: Vec<_> = out
        .reports
        .iter()
        .map(|r| (r.station, r.status()))
        .collect();
    assert_eq!(
        got,
        vec![
            (0, Some(StationStatus::Complete)),
            (1, Some(StationStatus::Interrupted)),
            (0, Some(StationStatus::Complete)),
        ]
    );
    // The old print's Begin from a history is ignored: it opens nothing.
    lc.on_event(&begin, t, &mut out);
    assert_eq!(lc.stations_open(), 0);
    assert_eq!(out.reports.len(), 3);
    // A sender that does not say when its job started changes nothing.
    station_of_print(&mut lc, &mut out, 0, 0);
    assert_eq!(out.reports.len(), 3);
}

/// A line profiler over the cube's top: the mount 0.1 m above it, moving along +x at 0.2 m/s,
/// looking straight down, its line across (world y); poses every 4 ms on the robot's clock,
/// profiles of 11 points every 0.5 ms on the sensor's, 1 ms behind.
mod profiler {
    use super::*;
    use crate::config::ProfilerConfig;
    use asbuilt_protocol::{MountPose, ProfileHeader, ProfilePoint};

    const T0: u64 = 1_000_000_000;
    const OFFSET: i64 = 1_000_000;
    const POSE_NS: u64 = 4_000_000;
    const PROFILE_NS: u64 = 500_000;

    fn x_at(robot_ns: u64) -> f64 {
        -0.4 + 0.2 * (robot_ns - T0) as f64 * 1e-9
    }

    fn mount_pose(k: u64) -> MountPose {
        let t = T0 + k * POSE_NS;
        let mut m = MountPose::new(1, 5, k, t);
        m.translation = [x_at(t), 0.0, 0.6];
        // Sensor x (the line) along world y, y (the plane's normal) along x, z (the view) down.
        let r = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
            0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0,
        ));
        let q = nalgebra::UnitQuaternion::from_rotation_matrix(&r).coords;
        m.rotation_xyzw = [q.x, q.y, q.z, q.w];
        m
    }

    /// Chunk `c` of 8 profiles: profile `j` is taken at robot time `T0 + j·0.5 ms`.
    fn profiles(c: u64) -> (ProfileHeader, Vec<ProfilePoint>) {
        let mut h = ProfileHeader::new(1, 5, c);
        let mut pts = Vec::new();
        for j in c * 8..(c + 1) * 8 {
            let sensor_ns = T0 + j * PROFILE_NS - OFFSET as u64;
            h.push(sensor_ns, 11);
            pts.extend((0..11).map(|i| ProfilePoint {
                x: -0.05 + 0.01 * i as f32,
                z: 0.1,
            }));
        }
        (h, pts)
    }

    fn setup() -> (Lifecycle<Owned>, Collect, Instant) {
        let config = ProfilerConfig {
            clock_offset_ns: OFFSET,
            ..ProfilerConfig::default()
        };
        let lc =
            Lifecycle::new(cube(), FrameChain::default(), cfg(), limits()).with_profiler(config);
        (lc, Collect::default(), Instant::now())
    }

    /// Sends `chunks` chunks, each after the poses up to its last profile (but those in
    /// `hole`), then the poses after the last profile, then the End.
    fn pass(chunks: u64, hole: std::ops::Range<u64>) -> (Lifecycle<Owned>, Collect) {
        pass_at(f64::NAN, chunks, hole)
    }

    /// [`pass`] of a print `printed_height` high.
    fn pass_at(
        printed_height: f64,
        chunks: u64,
        hole: std::ops::Range<u64>,
    ) -> (Lifecycle<Owned>, Collect) {
        let (mut lc, mut out, t) = setup();
        let mut begin = event(StationEventKind::Begin, 5, chunks as u32);
        begin.printed_height = printed_height;
        lc.on_event(&begin, t, &mut out);
        let mut k = 0;
        let mut poses_to = |lc: &mut Lifecycle<Owned>, out: &mut Collect, robot_ns: u64| {
            while T0 + k * POSE_NS <= robot_ns {
                if !hole.contains(&k) {
                    lc.on_mount_pose(&mount_pose(k), t, out);
                }
                k += 1;
            }
        };
        for c in 0..chunks {
            poses_to(&mut lc, &mut out, T0 + (c * 8 + 7) * PROFILE_NS);
            let (h, p) = profiles(c);
            lc.on_profiles(&h, &p, t, &mut out);
        }
        poses_to(&mut lc, &mut out, T0 + chunks * 8 * PROFILE_NS + POSE_NS);
        lc.on_event(&event(StationEventKind::End, 5, chunks as u32), t, &mut out);
        (lc, out)
    }

    #[test]
    fn each_profile_is_placed_by_the_pose_at_its_time() {
        let (lc, out) = pass(20, 0..0);
        assert_eq!(out.reports.len(), 1);
        let r = out.reports[0];
        assert_eq!(r.status(), Some(StationStatus::Complete));
        assert_eq!(
            (r.points_received, r.stats.count),
            (20 * 8 * 11, 20 * 8 * 11)
        );
        assert_eq!(r.rejected.total(), 0);
        assert_eq!(r.position_sigma, ProfilerConfig::default().position_sigma);
        // In the order they came: point i of profile j at x(T0 + j·0.5 ms), y along the line.
        let placed: Vec<&PointDeviation> = out.deviations.iter().flat_map(|d| &d.1).collect();
        assert_eq!(placed.len(), 20 * 8 * 11);
        for (n, d) in placed.iter().enumerate() {
            let (j, i) = ((n / 11) as u64, n % 11);
            let want = [x_at(T0 + j * PROFILE_NS), -0.05 + 0.01 * i as f64, 0.5];
            for a in 0..3 {
                assert!(
                    (d.position[a] - want[a]).abs() < 1e-6,
                    "{n}: {:?} {want:?}",
                    d.position
                );
            }
            assert!(d.distance.abs() < 1e-6);
        }
        let c = lc.profiler_counts();
        assert_eq!((c.placed, c.refused()), (160, 0));
        assert!(
            c.waited > 0,
            "the last profile of each chunk waits for the pose after it"
        );
    }

    #[test]
    fn profiles_across_a_hole_in_the_poses_are_refused_counted_and_the_pass_still_closes() {
        // Poses 10..19 lost: 36 ms to 80 ms apart, over the 20 ms allowed.
        let (lc, out) = pass(30, 10..20);
        let r = out.reports[0];
        assert_eq!(r.status(), Some(StationStatus::Complete));
        let refused = lc.profiler_counts().refused_gap;
        // The profiles strictly between 36 ms and 80 ms (73..=159), and those at its ends
        // as the track brackets them.
        assert!((87..=89).contains(&refused), "{refused}");
        assert_eq!(r.rejected.without_pose, refused * 11);
        assert_eq!(r.stats.count + r.rejected.without_pose, 30 * 8 * 11);
    }

    #[test]
    fn a_pass_that_ended_waits_for_the_pose_after_its_last_profile() {
        let (mut lc, mut out, t) = setup();
        lc.on_event(&event(StationEventKind::Begin, 5, 1), t, &mut out);
        lc.on_mount_pose(&mount_pose(0), t, &mut out);
        let (h, p) = profiles(0);
        lc.on_profiles(&h, &p, t, &mut out);
        lc.on_event(&event(StationEventKind::End, 5, 1), t, &mut out);
        assert!(
            out.reports.is_empty(),
            "profiles 1..7 wait for pose 1 (4 ms)"
        );
        assert_eq!(lc.profiles_waiting(), 7);
        lc.on_mount_pose(&mount_pose(1), t, &mut out);
        assert_eq!(lc.profiles_waiting(), 0);
        assert_eq!(
            out.reports.len(),
            1,
            "the pass closes with its last profile placed"
        );
        let r = out.reports[0];
        assert_eq!(r.status(), Some(StationStatus::Complete));
        assert_eq!((r.stats.count, r.rejected.total()), (88, 0));
    }

    /// A pass of a job printed with a profiler judges the design from `max_range` (0.3 m)
    /// below its printed height up, the samples there exactly those of the whole cut; a
    /// station of a job without mount poses judges the whole cut.
    #[test]
    fn a_pass_judges_only_what_its_profiler_can_reach() {
        let height = 0.4;
        let run = |profiled: bool| {
            let (lc, _, t) = setup();
            let config = crate::config::FindingsConfig {
                enabled: true,
                ..Default::default()
            };
            let mut lc = lc.with_findings(FindingsStage::new(config, 0.005, 0.05, 100));
            let mut out = WithStates::default();
            if profiled {
                // The track of the job's passes before this one.
                lc.on_mount_pose(&mount_pose(0), t, &mut out);
            }
            let mut begin = event(StationEventKind::Begin, 5, 1);
            begin.printed_height = height;
            lc.on_event(&begin, t, &mut out);
            lc.wait_designs(t, &mut out);
            for k in usize::from(profiled) as u64..3 {
                lc.on_mount_pose(&mount_pose(k), t, &mut out);
            }
            let (h, p) = profiles(0);
            lc.on_profiles(&h, &p, t, &mut out);
            lc.on_mount_pose(&mount_pose(3), t, &mut out);
            lc.on_event(&event(StationEventKind::End, 5, 1), t, &mut out);
            let r = out.inner.reports[0];
            assert_eq!((r.points_received, r.rejected.total()), (88, 0));
            assert_eq!(out.states.len(), 1);
            out.states[0].samples
        };
        let cut = cube().at(height).unwrap();
        let samples = asbuilt_core::sampling::DesignSamples::generate(
            cut.design(),
            crate::config::FindingsConfig::default().spacing,
            asbuilt_core::scan_layer::defaults::SAMPLE_SEED,
        )
        .unwrap();
        let from = height - ProfilerConfig::default().max_range;
        let reached = samples.points.iter().filter(|p| p.z >= from).count();
        assert!(
            reached < samples.len() / 2,
            "{reached} of {}",
            samples.len()
        );
        assert_eq!(run(true), reached);
        assert_eq!(run(false), samples.len());
    }

    #[test]
    fn a_pass_whose_printed_design_is_not_ready_is_held_not_rejected() {
        // The cube printed to 0.3 m: the pass ends before that design is ready; it waits for
        // it, and none of its points is rejected meanwhile.
        let (mut lc, mut out) = pass_at(0.3, 10, 0..0);
        lc.wait_designs(Instant::now(), &mut out);
        assert_eq!(
            out.reports.len(),
            1,
            "the pass closes once its design is ready"
        );
        let r = out.reports[0];
        assert_eq!(r.status(), Some(StationStatus::Complete));
        assert_eq!((r.points_received, r.rejected.total()), (10 * 8 * 11, 0));
        assert!((r.printed_height - 0.3).abs() < 1e-12);
    }
}
