use asbuilt_protocol::codec::{self, DecodeError};
use asbuilt_protocol::*;
use iceoryx2::prelude::ZeroCopySend;
use std::mem::{align_of, size_of};

fn sample_report() -> StationReport {
    let mut r = StationReport::new(7, 3);
    r.name = FixedText::new("bun045").unwrap();
    r.layer = 12;
    r.printed_height = 0.42;
    r.tolerance = 0.005;
    r.stats.count = 40_000;
    r.stats.mean = -1.25e-4;
    r.stats.median_abs = 6.1e-5;
    r.histogram.low = -0.02;
    r.histogram.high = 0.02;
    for (i, b) in r.histogram.bins.iter_mut().enumerate() {
        *b = (i * i) as u64;
    }
    r.rejected.non_finite = 3;
    r.chunks.duplicate = 1;
    r
}

#[test]
fn every_message_round_trips_through_postcard() {
    let mut pose = PoseSnapshot::new(1, 2, PoseMode::FixedOrientation);
    pose.translation = [1.5, -2.25, 0.125];
    let h = std::f64::consts::FRAC_1_SQRT_2;
    pose.rotation_xyzw = [0.0, 0.0, h, h];
    assert_eq!(
        codec::decode::<PoseSnapshot>(&codec::encode(&pose)).unwrap(),
        pose
    );

    let mut ev = StationEvent::new(StationEventKind::End, 1, 2);
    ev.name = FixedText::new("north-east").unwrap();
    ev.expected_points = 1_000_000;
    let back = codec::decode::<StationEvent>(&codec::encode(&ev)).unwrap();
    assert_eq!(back.kind(), Some(StationEventKind::End));
    assert_eq!(back.name.as_str(), "north-east");
    assert!(back.printed_height.is_nan());

    let report = sample_report();
    let back = codec::decode::<StationReport>(&codec::encode(&report)).unwrap();
    assert_eq!(back.histogram.bins, report.histogram.bins);
    assert_eq!(back.name.as_str(), "bun045");
    assert_eq!(back.stats, report.stats);
    assert_eq!(back.status(), Some(StationStatus::Complete));

    let mut status = AgentStatus::new(4242);
    status.state = AgentState::ShuttingDown as u8;
    status.points_per_second = 2.1e6;
    status.input.chunks_unknown_station = 3;
    status.output.reports = 1;
    status.rejected_points.in_rejected_chunks = 5000;
    let back = codec::decode::<AgentStatus>(&codec::encode(&status)).unwrap();
    assert_eq!(back, status);
    assert_eq!(back.state(), Some(AgentState::ShuttingDown));

    let points: Vec<ScanPoint> = (0..1000)
        .map(|i| ScanPoint::new(i as f32 * 0.001, -(i as f32), 3.0))
        .collect();
    let header = ChunkHeader::new(1, 2, 5, points.len() as u32);
    let (h, p) = codec::decode_scan_chunk(&codec::encode_scan_chunk(&header, &points)).unwrap();
    assert_eq!(h, header);
    assert_eq!(p, points);

    let devs = vec![
        PointDeviation {
            position: [1.0, 2.0, 3.0],
            distance: -0.0015,
            triangle: 17,
            feature: Feature::Edge as u8,
            feature_index: 2,
            flags: DeviationFlags(DeviationFlags::OUT_OF_TOLERANCE),
            _reserved: 0,
        };
        3
    ];
    let mut dh = DeviationHeader::new(1, 2, 5);
    dh.point_count = 3;
    let (h, p) = codec::decode_deviation_chunk(&codec::encode_deviation_chunk(&dh, &devs)).unwrap();
    assert_eq!(h, dh);
    assert_eq!(p, devs);
    assert_eq!(p[0].feature(), Some(Feature::Edge));
}

#[test]
fn a_record_of_another_version_is_refused_with_a_clear_error() {
    let pose = PoseSnapshot::new(1, 2, PoseMode::SixDof);
    let mut bytes = codec::encode(&pose);
    bytes[0] = 3; // the leading version varint
    let err = codec::decode::<PoseSnapshot>(&bytes).unwrap_err();
    assert_eq!(
        err,
        DecodeError::VersionMismatch {
            message: "asbuilt.PoseSnapshot.v2",
            found: 3,
            expected: 2,
            oldest: 1,
        }
    );
    assert!(err.to_string().contains("version 3"), "{err}");
    assert!(err.to_string().contains("versions 1 to 2"), "{err}");

    // A payload that arrived through shared memory carries its version in a field.
    let mut pose = pose;
    pose.version = 9;
    assert!(check_version::<PoseSnapshot>(pose.version).is_err());
    assert!(matches!(
        codec::decode::<PoseSnapshot>(&codec::encode(&pose)),
        Err(DecodeError::VersionMismatch { found: 9, .. })
    ));
}

#[test]
fn corrupt_and_mistyped_records_are_errors_not_panics() {
    let report = codec::encode(&sample_report());
    for cut in [0, 1, 5, report.len() / 2, report.len() - 1] {
        assert!(
            codec::decode::<StationReport>(&report[..cut]).is_err(),
            "cut {cut}"
        );
    }
    // A pose record is not a station event.
    let pose = codec::encode(&PoseSnapshot::new(1, 2, PoseMode::SixDof));
    assert!(codec::decode::<StationEvent>(&pose).is_err());

    // A chunk whose header lies about its length.
    let points = vec![ScanPoint::new(1.0, 2.0, 3.0); 4];
    let header = ChunkHeader::new(1, 2, 0, 5);
    let err = codec::decode_scan_chunk(&codec::encode_scan_chunk(&header, &points)).unwrap_err();
    assert!(err.to_string().contains("declares 5 points but 4"), "{err}");

    // Text longer than its field.
    assert!(FixedText::<4>::new("too long").is_err());
    assert_eq!(FixedText::<4>::truncated("héllo").as_str(), "hél");
}

#[test]
fn layouts_are_fixed_and_aligned_for_shared_memory() {
    assert_eq!(size_of::<ScanPoint>(), 20);
    assert_eq!(align_of::<ScanPoint>(), 4);
    assert_eq!(size_of::<PointDeviation>(), 40);
    assert_eq!(align_of::<PointDeviation>(), 8);
    assert_eq!(size_of::<PoseSnapshot>(), 96);
    assert_eq!(size_of::<ChunkHeader>(), 40);
    assert_eq!(size_of::<DeviationHeader>(), 48);
    // A change to any of these sizes is a layout change: bump the message version with it.
    assert_eq!(size_of::<StationEvent>(), 112);
    for (size, align) in [
        (size_of::<PoseSnapshot>(), align_of::<PoseSnapshot>()),
        (size_of::<StationReport>(), align_of::<StationReport>()),
        (size_of::<ChunkHeader>(), align_of::<ChunkHeader>()),
        (size_of::<AgentStatus>(), align_of::<AgentStatus>()),
    ] {
        assert_eq!(align, 8);
        assert_eq!(size % align, 0);
    }
}

#[test]
fn iceoryx2_type_names_carry_the_version() {
    // SAFETY: type_name only returns a static string.
    unsafe {
        assert_eq!(PoseSnapshot::type_name(), PoseSnapshot::TYPE_NAME);
        assert_eq!(ChunkHeader::type_name(), ChunkHeader::TYPE_NAME);
        assert_eq!(StationEvent::type_name(), StationEvent::TYPE_NAME);
        assert_eq!(DeviationHeader::type_name(), DeviationHeader::TYPE_NAME);
        assert_eq!(StationReport::type_name(), StationReport::TYPE_NAME);
        assert_eq!(AgentStatus::type_name(), AgentStatus::TYPE_NAME);
        assert_eq!(ScanPoint::type_name(), "asbuilt.ScanPoint.v1");
        assert_eq!(PointDeviation::type_name(), "asbuilt.PointDeviation.v1");
    }
}

#[test]
fn foreign_text_bytes_never_panic() {
    let mut t = FixedText::<8>::new("abc").unwrap();
    // Simulate a peer that wrote a bogus length into shared memory.
    // SAFETY: FixedText is repr(C) and starts with its u32 length, which any value may hold;
    // `t` is a live, exclusively borrowed value.
    unsafe {
        let p = &mut t as *mut FixedText<8> as *mut u32;
        *p = 1000;
    }
    assert_eq!(t.as_str(), "abc\0\0\0\0\0");
}

/// Every reason an input is rejected is named once, so the health line and the total miss none.
#[test]
fn every_input_reject_is_named_once_and_counted_in_the_total() {
    let i = InputRejects {
        chunks_unknown_station: 1,
        chunks_after_close: 1 << 1,
        chunks_pending_overflow: 1 << 2,
        chunks_empty: 1 << 3,
        chunks_oversized: 1 << 4,
        chunks_duplicate: 1 << 5,
        chunks_out_of_order: 1 << 6,
        chunks_malformed: 1 << 7,
        version_mismatch: 1 << 8,
        poses_invalid: 1 << 9,
        events_invalid: 1 << 10,
    };
    let reasons = i.by_reason();
    let mut bits: Vec<u64> = reasons.iter().map(|(_, n)| *n).collect();
    bits.sort_unstable();
    assert_eq!(bits, (0..11).map(|k| 1u64 << k).collect::<Vec<_>>());
    let mut names: Vec<&str> = reasons.iter().map(|(r, _)| *r).collect();
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), 11);
    assert_eq!(i.total(), (1 << 11) - 1);
}

/// Records of versions 1 and 2 of a station event (without `job_started_ns`; version 1 with a
/// zero where version 2 keeps the attempt) still read, the print's start as not said; a
/// version 1 chunk header reads with its attempt 0, which the agent takes as the first.
#[test]
fn version_1_and_2_records_read_with_what_they_lack_as_unknown() {
    use asbuilt_protocol::Record;
    for (version, attempt) in [(1u16, 0u8), (2, 3)] {
        // The fields in the order versions 1 and 2 wrote them.
        let mut bytes = postcard::to_allocvec(&version).unwrap();
        let name = FixedText::<48>::new("L008-S1").unwrap();
        let old = (
            version, 0u8, attempt, 4u32, 3u64, 77u64, 7u32, 2u32, 10u64, 0.5f64, name,
        );
        bytes.extend(postcard::to_allocvec(&old).unwrap());
        let back = <StationEvent as Record>::decode(&bytes).unwrap();
        assert_eq!(back.version, StationEvent::VERSION);
        assert_eq!(
            (back.attempt, back.station, back.job, back.job_started_ns),
            (attempt, 4, 3, 0)
        );
        assert_eq!(
            (back.timestamp_ns, back.layer, back.expected_chunks),
            (77, 7, 2)
        );
        assert_eq!((back.expected_points, back.printed_height), (10, 0.5));
        assert_eq!(back.name.as_str(), "L008-S1");
        // Cut short, or with bytes left over, it is an error.
        assert!(<StationEvent as Record>::decode(&bytes[..bytes.len() - 3]).is_err());
        let mut long = bytes.clone();
        long.push(0);
        assert!(<StationEvent as Record>::decode(&long).is_err());
    }
    let mut ev = StationEvent::new(StationEventKind::Begin, 3, 4);
    ev.job_started_ns = 123;
    let back = <StationEvent as Record>::decode(&<StationEvent as Record>::encode(&ev)).unwrap();
    assert_eq!(back.job_started_ns, 123);
    let mut h = ChunkHeader::new(3, 4, 0, 1);
    h.version = 1;
    h.attempt = 0;
    let point = ScanPoint::new(1.0, 2.0, 3.0);
    let (back, points) = codec::decode_scan_chunk(&postcard_scan_chunk(&h, &[point])).unwrap();
    assert_eq!((back.attempt, points), (0, vec![point]));
}

/// A scan chunk record as releases before the byte planes wrote it: the header's version, the
/// header, then the points as a postcard sequence.
fn postcard_scan_chunk(h: &ChunkHeader, points: &[ScanPoint]) -> Vec<u8> {
    let mut bytes = postcard::to_allocvec(&h.version).unwrap();
    bytes.extend(postcard::to_allocvec(h).unwrap());
    bytes.extend(postcard::to_allocvec(points).unwrap());
    bytes
}

/// Recordings written before the byte planes still read, point for point; the planes record
/// is the one written now, and is refused when cut short or followed by more.
#[test]
fn both_scan_chunk_layouts_read_back() {
    let points: Vec<ScanPoint> = (0..300)
        .map(|i| ScanPoint {
            intensity: i as f32 / 300.0,
            returns: 0x21,
            ..ScanPoint::new(i as f32 * 0.01, 1.5, -(i as f32))
        })
        .collect();
    let h = ChunkHeader::new(7, 1, 3, points.len() as u32);
    let old = postcard_scan_chunk(&h, &points);
    assert_eq!(codec::decode_scan_chunk(&old).unwrap(), (h, points.clone()));
    let new = codec::encode_scan_chunk(&h, &points);
    assert_eq!(new[0] as u16, codec::SCAN_CHUNK_PLANES);
    assert_eq!(codec::decode_scan_chunk(&new).unwrap(), (h, points.clone()));
    let cut = codec::decode_scan_chunk(&new[..new.len() - 1]).unwrap_err();
    assert!(
        cut.to_string().contains("declares 300 points but 299"),
        "{cut}"
    );
    let mut long = new.clone();
    long.push(0);
    assert!(matches!(
        codec::decode_scan_chunk(&long),
        Err(DecodeError::TrailingBytes { extra: 1, .. })
    ));
    // A header from a newer release is refused by its version, whatever the layout.
    let mut newer = h;
    newer.version = 9;
    let err = codec::decode_scan_chunk(&codec::encode_scan_chunk(&newer, &points)).unwrap_err();
    assert!(
        matches!(err, DecodeError::VersionMismatch { found: 9, .. }),
        "{err}"
    );
}
