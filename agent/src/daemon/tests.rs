//! The event loop's parts against a cell on iceoryx2: the input drain.
use asbuilt_core::C2mParams;
use asbuilt_core::frames::FrameChain;
use asbuilt_protocol::ipc::CellPorts;
use asbuilt_protocol::{ChunkHeader, PoseMode, ScanPoint, StationReport, StationStatus};

use super::*;

/// The agent's side of the ports and the cell's, on services of their own, and a lifecycle
/// with one station slot and one held chunk over a 1 m cube.
pub(super) struct Bench {
    pub(super) _node: Node<Ipc>,
    pub(super) ports: AgentPorts,
    pub(super) cell: CellPorts,
    pub(super) frames: FrameChain,
    pub(super) lifecycle: AgentLifecycle,
}

pub(super) fn bench(name: &str, station_timeout: Duration) -> Bench {
    let names = ServiceNames::new(&format!("asbuilt-drain-test/{name}/{}", std::process::id()));
    let node = NodeBuilder::new().create::<Ipc>().unwrap();
    let queues = QueueSizes {
        max_points_per_chunk: 16,
        chunk_queue: 8,
        pending_chunks: 1,
        lent_chunks: 0,
    };
    let ports = AgentPorts::create(&node, &names, queues).unwrap();
    let cell = CellPorts::try_open(&node, &names, 16).unwrap();
    let lifecycle = lifecycle(station_timeout);
    Bench {
        _node: node,
        ports,
        cell,
        frames: FrameChain::default(),
        lifecycle,
    }
}

/// A lifecycle with one station slot and one held chunk over a 1 m cube.
pub(super) fn lifecycle(station_timeout: Duration) -> AgentLifecycle {
    let cube = asbuilt_core::design::shapes::cuboid(
        nalgebra::Point3::origin(),
        nalgebra::Point3::new(1.0, 1.0, 1.0),
    );
    let designs = PrintedDesigns::new(cube, C2mParams::within(0.05)).unwrap();
    let limits = LifecycleLimits {
        max_points_per_chunk: 16,
        pending_chunks: 1,
        open_stations: 1,
        station_timeout,
    };
    Lifecycle::new(
        designs,
        FrameChain::default(),
        InspectParams::with_tolerance(0.005),
        limits,
    )
}

/// Station `station`'s Begin announcing `chunks` chunks of 10 points, and its pose.
pub(super) fn begin(cell: &CellPorts, station: u32, chunks: u32) {
    let mut ev = StationEvent::new(StationEventKind::Begin, 1, station);
    ev.expected_chunks = chunks;
    ev.expected_points = u64::from(chunks) * 10;
    cell.send_event(&ev).unwrap();
    cell.send_pose(&PoseSnapshot::new(1, station, PoseMode::DesignScanner))
        .unwrap();
}

/// Chunk `seq` of `station`: 10 points 1 mm above the cube's top.
pub(super) fn chunk(cell: &CellPorts, station: u32, seq: u64, last: bool) {
    let points: Vec<ScanPoint> = (0..10)
        .map(|i| ScanPoint::new(0.1 + 0.05 * i as f32, 0.5, 1.001))
        .collect();
    let mut h = ChunkHeader::new(1, station, seq, 10);
    h.last = u8::from(last);
    cell.send_chunk(&h, &points).unwrap();
}

pub(super) fn end(cell: &CellPorts, station: u32, chunks: u32) {
    let mut ev = StationEvent::new(StationEventKind::End, 1, station);
    ev.expected_chunks = chunks;
    ev.expected_points = u64::from(chunks) * 10;
    cell.send_event(&ev).unwrap();
}

pub(super) fn reports(cell: &CellPorts) -> Vec<StationReport> {
    let mut out = Vec::new();
    while let Some(r) = cell.reports.receive().unwrap() {
        out.push(*r.payload());
    }
    out
}

/// Nothing waits any more and no input was refused.
fn assert_all_taken(held: &HeldControl, b: &Bench) {
    assert!(!held.waits_for_a_slot() && held.chunk.is_none());
    assert_eq!(
        b.lifecycle.counters.input,
        Default::default(),
        "nothing refused"
    );
}

/// A cell running ahead of the agent, three stations queued before the agent reads with
/// one station slot and room for one held chunk: each station waits in the cell's queues
/// for the slot, and every point of every station is measured.
#[test]
fn stations_queued_ahead_of_the_slots_wait_in_the_queues_and_lose_nothing() {
    let mut b = bench("ahead", Duration::from_secs(600));
    let mut out = Fanout::new(&b.ports, (None, None), &b.frames, 16, false);
    let mut held = HeldControl::default();
    for station in 0..3 {
        begin(&b.cell, station, 2);
        chunk(&b.cell, station, 0, false);
        chunk(&b.cell, station, 1, true);
        end(&b.cell, station, 2);
    }
    assert_eq!(held.drain(&mut b.lifecycle, &mut out), Drained::Empty);
    let seen: Vec<_> = reports(&b.cell)
        .iter()
        .map(|r| (r.station, r.status(), r.stats.count))
        .collect();
    let complete = Some(StationStatus::Complete);
    assert_eq!(
        seen,
        vec![(0, complete, 20), (1, complete, 20), (2, complete, 20)]
    );
    assert_all_taken(&held, &b);
}

/// A station whose Begin comes while the only slot is held by a station that went quiet
/// waits with its chunks, which stay in the cell's queue rather than push the one held
/// chunk out. When the quiet station times out, the waiting one is taken whole.
#[test]
fn a_station_without_a_slot_waits_with_its_chunks_until_the_slot_frees() {
    let timeout = Duration::from_millis(200);
    let mut b = bench("slot", timeout);
    let mut out = Fanout::new(&b.ports, (None, None), &b.frames, 16, false);
    let mut held = HeldControl::default();
    begin(&b.cell, 0, 2);
    chunk(&b.cell, 0, 0, false);
    begin(&b.cell, 1, 3);
    for seq in 0..3 {
        chunk(&b.cell, 1, seq, seq == 2);
    }
    end(&b.cell, 1, 3);

    assert_eq!(held.drain(&mut b.lifecycle, &mut out), Drained::Empty);
    assert_eq!(b.lifecycle.stations_open(), 1, "station 0 holds the slot");
    assert!(held.waits_for_a_slot(), "station 1's Begin waits");
    assert_eq!(
        held.chunk.as_ref().map(|c| c.user_header().station),
        Some(1),
        "station 1's first chunk waits with it"
    );
    assert_eq!(b.lifecycle.chunks_waiting(), 0, "nothing was pushed out");
    assert!(reports(&b.cell).is_empty());

    // Station 0 says nothing more: the tick closes it, and station 1 goes through whole.
    std::thread::sleep(timeout + Duration::from_millis(50));
    b.lifecycle.on_tick(Instant::now(), &mut out);
    assert_eq!(held.drain(&mut b.lifecycle, &mut out), Drained::Empty);
    let seen: Vec<_> = reports(&b.cell)
        .iter()
        .map(|r| (r.station, r.status(), r.stats.count))
        .collect();
    assert_eq!(
        seen,
        vec![
            (0, Some(StationStatus::TimedOut), 10),
            (1, Some(StationStatus::Complete), 30)
        ]
    );
    assert_all_taken(&held, &b);
}

/// Chunks that come before their station's Begin and pose (the cell sends them on other
/// services) are matched with them in the same pass.
#[test]
fn chunks_read_before_their_begin_find_it_in_the_same_pass() {
    let mut b = bench("order", Duration::from_secs(600));
    let mut out = Fanout::new(&b.ports, (None, None), &b.frames, 16, false);
    let mut held = HeldControl::default();
    // The chunks are in their queue before the Begin is in its own.
    chunk(&b.cell, 4, 0, false);
    chunk(&b.cell, 4, 1, true);
    begin(&b.cell, 4, 2);
    end(&b.cell, 4, 2);
    assert_eq!(held.drain(&mut b.lifecycle, &mut out), Drained::Empty);
    let got = reports(&b.cell);
    assert_eq!(got.len(), 1);
    assert_eq!(got[0].status(), Some(StationStatus::Complete));
    assert_eq!(got[0].points_received, 20);
    assert_eq!(got[0].stats.count, 20, "every point measured");
}
