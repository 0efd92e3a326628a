//! The pose of a profile against an analytic path: a helix (a curve in plan, climbing as a
//! print does) at 0.2 m/s, the mount turning with the path and tilted, poses at 250 Hz with
//! jittered sampling times, profiles at 2 kHz.

use std::f64::consts::FRAC_PI_2;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};

use super::*;

/// An epoch-like origin for the robot's clock: times are large, as they are.
const BASE_NS: i64 = 1_795_000_000_000_000_000;
const RADIUS: f64 = 0.5;
const SPEED: f64 = 0.2;
const CLIMB: f64 = 0.002;

/// The mount's true pose `t_ns` on the robot's clock.
fn truth(t_ns: i64) -> Isometry3<f64> {
    let t = (t_ns - BASE_NS) as f64 * 1e-9;
    let a = SPEED / RADIUS * t;
    let position = Vector3::new(RADIUS * a.cos(), RADIUS * a.sin(), 0.3 + CLIMB * t);
    let heading = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a + FRAC_PI_2);
    let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.3);
    Isometry3::from_parts(Translation3::from(position), heading * tilt)
}

/// The robot's poses at 250 Hz for `seconds`, each sampled up to ±0.5 ms off its tick (and
/// stamped with when it was).
fn robot_poses(seconds: f64, seed: u64) -> Vec<MountPose> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let n = (seconds * 250.0) as i64;
    (0..=n)
        .map(|k| {
            let t = BASE_NS + k * 4_000_000 + rng.random_range(-500_000..=500_000);
            MountPose {
                time_ns: t,
                pose: truth(t),
            }
        })
        .collect()
}

fn track_of(poses: &[MountPose], params: PoseTrackParams) -> PoseTrack {
    let mut track = PoseTrack::new(params);
    for p in poses {
        track.push(*p).unwrap();
    }
    track
}

/// The profiler 60 mm behind the nozzle and 50 mm above, looking down.
fn profiler_on_mount() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(-0.06, 0.0, 0.05),
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI),
    )
}

/// A point 0.1 m in front of the sensor: where its points are.
const IN_VIEW: Point3<f64> = Point3::new(0.0, 0.0, 0.1);

/// The largest distance, over profiles at 2 kHz within the poses, between where the track
/// puts `probe` (sensor frame) and where it truly was; the sensor's clock runs
/// `true_offset_ns` behind the robot's.
fn worst_error(track: &PoseTrack, seconds: f64, true_offset_ns: i64, probe: Point3<f64>) -> f64 {
    let mount_sensor = track.params().mount_sensor;
    let mut worst: f64 = 0.0;
    let profiles = (seconds * 2000.0) as i64;
    // Away from the ends, where a profile misplaced by the offset would have no pose.
    for j in 20..profiles - 20 {
        let robot_t = BASE_NS + j * 500_000 + 137;
        let sensor_ns = (robot_t - true_offset_ns) as u64;
        let PoseAt::Ready(pose) = track.at(sensor_ns) else {
            panic!("profile {j}: {:?}", track.at(sensor_ns));
        };
        let truly = truth(robot_t) * mount_sensor;
        worst = worst.max((pose * probe - truly * probe).norm());
    }
    worst
}

#[test]
fn a_profiles_pose_on_a_curved_path_is_within_five_hundredths_of_a_millimetre() {
    let poses = robot_poses(3.0, 1);
    let params = PoseTrackParams {
        mount_sensor: profiler_on_mount(),
        ..Default::default()
    };
    let worst = worst_error(&track_of(&poses, params), 3.0, 0, IN_VIEW);
    assert!(worst < 0.05e-3, "{:.4} mm", worst * 1e3);
    // Slerp and the chord: far inside, the rounding of large clock values.
    assert!(worst < 1e-6, "{:.6} mm", worst * 1e3);
}

#[test]
fn a_clock_offset_left_uncorrected_is_a_millimetre_along_the_path_and_corrected_is_gone() {
    let poses = robot_poses(3.0, 2);
    let offset = 5_000_000; // 5 ms: the sensor's clock behind the robot's.
    // The mount itself: it moves at 0.2 m/s (and climbs 2 mm/s), so 5 ms are 1.0 mm.
    let origin = Point3::origin();
    let track = track_of(&poses, PoseTrackParams::default());
    let uncorrected = worst_error(&track, 3.0, offset, origin);
    assert!(
        (uncorrected - 1.0e-3).abs() < 0.005e-3,
        "{:.4} mm",
        uncorrected * 1e3
    );
    let params = PoseTrackParams {
        clock_offset_ns: offset,
        ..Default::default()
    };
    let track = track_of(&poses, params);
    for probe in [origin, IN_VIEW] {
        let corrected = worst_error(&track, 3.0, offset, probe);
        assert!(corrected < 1e-6, "{:.6} mm", corrected * 1e3);
    }
}

#[test]
fn a_profile_waits_for_the_pose_after_it_and_is_refused_across_a_gap_or_before_the_poses() {
    let poses = robot_poses(1.0, 3);
    let params = PoseTrackParams {
        capacity: 100,
        max_gap_ns: 20_000_000,
        ..Default::default()
    };
    let mut track = PoseTrack::new(params);
    // Poses 0..=100, then a 40 ms hole (10 poses lost), then 111..=200.
    for p in poses[..=100].iter().chain(&poses[111..=200]) {
        track.push(*p).unwrap();
    }
    assert_eq!(track.len(), 100, "the oldest go when it is full");
    let at = |t: i64| track.at(t as u64);
    // In the hole: the bracketing poses are 40 ms apart.
    let hole = at(poses[105].time_ns);
    let PoseAt::Refused(Refused::Gap { gap_ns }) = hole else {
        panic!("{hole:?}");
    };
    assert_eq!(gap_ns, poses[111].time_ns.abs_diff(poses[100].time_ns));
    // Before the oldest kept pose (101 of them went).
    let old = at(poses[2].time_ns);
    let PoseAt::Refused(why) = old else {
        panic!("{old:?}");
    };
    assert!(matches!(why, Refused::BeforePoses { .. }), "{why:?}");
    // The refusal says what to look at.
    assert!(why.to_string().contains("clock offset"), "{why}");
    // After the newest: it waits, and is placed once the next pose comes.
    let later = poses[200].time_ns + 1_000_000;
    assert_eq!(at(later), PoseAt::Wait);
    // Exactly at a pose: that pose.
    assert_eq!(at(poses[150].time_ns), PoseAt::Ready(poses[150].pose));
    track.push(poses[201]).unwrap();
    let PoseAt::Ready(p) = track.at(later as u64) else {
        panic!("{:?}", track.at(later as u64));
    };
    assert!((p.translation.vector - truth(later).translation.vector).norm() < 1e-6);
}

#[test]
fn poses_out_of_order_or_not_rigid_are_refused_and_the_track_keeps_going() {
    let poses = robot_poses(0.1, 4);
    let mut track = track_of(&poses[..10], PoseTrackParams::default());
    assert!(matches!(
        track.push(poses[5]),
        Err(PoseRefused::NotAfter { .. })
    ));
    // The newest pose again (a service's history) is a repeat: nothing changes. Another pose
    // at its time is out of order.
    track.push(poses[9]).unwrap();
    assert_eq!(track.len(), 10);
    let mut moved = poses[9];
    moved.pose.translation.vector.x += 1e-3;
    assert!(matches!(
        track.push(moved),
        Err(PoseRefused::NotAfter { .. })
    ));
    let mut nan = poses[10];
    nan.pose.translation.vector.x = f64::NAN;
    assert!(matches!(track.push(nan), Err(PoseRefused::NotRigid { .. })));
    track.push(poses[10]).unwrap();
    assert_eq!(track.len(), 11);
}

#[test]
fn a_rotation_and_its_negative_quaternion_interpolate_alike() {
    let a = truth(BASE_NS);
    let b = truth(BASE_NS + 4_000_000);
    let mut flipped = b;
    flipped.rotation = UnitQuaternion::new_unchecked(-b.rotation.into_inner());
    for s in [0.0, 0.25, 0.5, 0.9, 1.0] {
        let x = interpolate(&a, &b, s);
        let y = interpolate(&a, &flipped, s);
        assert!(x.rotation.angle_to(&y.rotation) < 1e-12, "{s}");
    }
    // Equal rotations (slerp's 0/0) give that rotation.
    let same = interpolate(&a, &a, 0.3);
    assert!(same.rotation.angle_to(&a.rotation) < 1e-12);
}

#[test]
fn memory_stays_fixed_however_many_poses_come() {
    let mut track = PoseTrack::new(PoseTrackParams {
        capacity: 256,
        ..Default::default()
    });
    let cap = track.poses_capacity();
    for k in 0..100_000 {
        track
            .push(MountPose {
                time_ns: BASE_NS + k * 1_000_000,
                pose: Isometry3::identity(),
            })
            .unwrap();
    }
    assert_eq!(track.len(), 256);
    assert_eq!(track.poses_capacity(), cap);
}

/// Collects what a placer does: each profile's index and its pose, or why not.
#[derive(Default)]
struct Out {
    placed: Vec<(usize, Isometry3<f64>)>,
    refused: Vec<(usize, Refused)>,
}

impl Placed<usize> for Out {
    fn placed(&mut self, k: usize, sensor: &Isometry3<f64>) {
        self.placed.push((k, *sensor));
    }
    fn refused(&mut self, k: usize, why: Refused) {
        self.refused.push((k, why));
    }
}

/// What arrives, in the order it arrives: the robot's poses `lag_ns` after they were taken
/// (up to `poses_until_ns` from the start), profiles at 2 kHz when they are taken.
fn arrivals(seconds: f64, lag_ns: i64, poses_until_ns: i64) -> Vec<(i64, Option<MountPose>)> {
    let mut events: Vec<(i64, Option<MountPose>)> = robot_poses(seconds, 5)
        .into_iter()
        .filter(|p| p.time_ns - BASE_NS <= poses_until_ns)
        .map(|p| (p.time_ns + lag_ns, Some(p)))
        .collect();
    let profiles = (seconds * 2000.0) as i64;
    events.extend((10..profiles).map(|j| (BASE_NS + j * 500_000, None)));
    events.sort_by_key(|e| e.0);
    events
}

fn run(placer: &mut Placer<usize>, events: &[(i64, Option<MountPose>)], out: &mut Out) -> usize {
    let (mut k, mut most_waiting) = (0, 0);
    for (t, e) in events {
        match e {
            Some(pose) => placer.pose(*pose, out).unwrap(),
            None => {
                placer.profile(*t as u64, k, out);
                k += 1;
            }
        }
        most_waiting = most_waiting.max(placer.waiting());
    }
    most_waiting
}

#[test]
fn profiles_wait_for_late_poses_and_all_are_placed_in_order() {
    // The robot's poses arrive 10 ms late: each profile waits for the pose after it.
    let events = arrivals(1.0, 10_000_000, i64::MAX);
    let mut placer = Placer::new(PoseTrackParams::default(), 64);
    let mut out = Out::default();
    let most_waiting = run(&mut placer, &events, &mut out);
    placer.end_pass(&mut out);
    let profiles = events.iter().filter(|e| e.1.is_none()).count();
    // The last few come after the last pose was taken: nothing brackets them.
    let late = out
        .refused
        .iter()
        .filter(|r| r.1 == Refused::NoLaterPose)
        .count();
    assert!(late <= 8, "{late}");
    assert_eq!(
        out.refused.len(),
        late,
        "{:?}",
        &out.refused[..3.min(out.refused.len())]
    );
    assert_eq!(out.placed.len() + late, profiles);
    assert!(
        out.placed.windows(2).all(|w| w[0].0 < w[1].0),
        "out of order"
    );
    // 10 ms of profiles and a pose's 4 ms wait at most: 28 profiles, within the 64 held.
    assert!((20..=30).contains(&most_waiting), "{most_waiting}");
    let c = placer.counts();
    assert!(c.waited > c.placed / 2, "{c:?}");
    for (k, pose) in &out.placed {
        let t = BASE_NS + (*k as i64 + 10) * 500_000;
        let err = (pose.translation.vector - truth(t).translation.vector).norm();
        assert!(err < 0.05e-3, "profile {k}: {:.4} mm", err * 1e3);
    }
}

#[test]
fn when_the_poses_stop_the_wait_stays_full_and_every_profile_is_accounted_for() {
    // The pose publisher dies half-way.
    let events = arrivals(1.0, 0, 500_000_000);
    let mut placer = Placer::new(PoseTrackParams::default(), 64);
    let mut out = Out::default();
    let most_waiting = run(&mut placer, &events, &mut out);
    assert_eq!(most_waiting, 64, "the wait never grows past its size");
    placer.end_pass(&mut out);
    let profiles = events.iter().filter(|e| e.1.is_none()).count();
    let c = *placer.counts();
    assert_eq!(c.placed + c.refused(), profiles as u64);
    assert_eq!(c.refused_no_later_pose, 64);
    assert!(c.refused_wait_full > 900, "{c:?}");
    assert_eq!(out.placed.len() as u64, c.placed);
    assert_eq!(out.refused.len() as u64, c.refused());
    assert_eq!(placer.waiting(), 0);
}

#[test]
fn profiles_in_a_hole_in_the_poses_are_refused_and_the_rest_placed() {
    let mut events = arrivals(1.0, 0, i64::MAX);
    // 40 ms of poses lost from 0.5 s on.
    let hole = BASE_NS + 500_000_000..BASE_NS + 540_000_000;
    events.retain(|(_, e)| e.is_none_or(|p| !hole.contains(&p.time_ns)));
    let mut placer = Placer::new(PoseTrackParams::default(), 64);
    let mut out = Out::default();
    run(&mut placer, &events, &mut out);
    placer.end_pass(&mut out);
    let c = *placer.counts();
    // The profiles between the poses either side of the hole, about 48 ms of them: refused
    // for the gap once the pose after it comes, or for a full wait before it does.
    let lost = c.refused_gap + c.refused_wait_full;
    assert!((80..=110).contains(&lost), "{c:?}");
    assert!(c.refused_gap > 0 && c.refused_wait_full > 0, "{c:?}");
    let profiles = events.iter().filter(|e| e.1.is_none()).count() as u64;
    assert_eq!(c.placed + lost, profiles, "{c:?}");
    // One run of profiles, in the hole.
    let first_lost = out.refused.iter().map(|r| r.0).min().unwrap();
    let last_lost = out.refused.iter().map(|r| r.0).max().unwrap();
    assert_eq!((last_lost - first_lost + 1) as u64, lost);
}

/// A box 0.6 × 0.2 × 0.4 m, its −y face's top edge followed from x = −0.2 to 0.2 m by a
/// profiler 50 mm outside and 100 mm above it, tilted to look at the edge, a profile every
/// 0.1 mm. Returns the samples and which were swept.
fn swept_box(max_step: f64) -> (crate::sampling::DesignSamples, Vec<bool>) {
    let design =
        crate::design::shapes::cuboid(Point3::new(-0.3, -0.1, 0.0), Point3::new(0.3, 0.1, 0.4));
    let samples = crate::sampling::DesignSamples::generate(&design, 0.005, 1).unwrap();
    let index = crate::C2mIndex::from_design(design, crate::C2mParams::within(0.05)).unwrap();
    let mut sweep = Sweep::new(
        &samples.points,
        &samples.normals,
        SweepParams {
            max_step,
            ..Default::default()
        },
    );
    // Sensor axes: y along the path (+x), z looking down and in (towards +y), x across.
    let tilt = 0.05_f64.atan2(0.1);
    let (s, c) = tilt.sin_cos();
    let axes = nalgebra::Matrix3::from_columns(&[
        Vector3::new(0.0, c, s),
        Vector3::x(),
        Vector3::new(0.0, s, -c),
    ]);
    let rotation =
        UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(axes));
    for k in 0..=4000 {
        let x = -0.2 + 1e-4 * f64::from(k);
        let sensor = Isometry3::from_parts(Translation3::new(x, -0.15, 0.5), rotation);
        sweep.profile(&sensor, &index);
    }
    sweep.end_pass();
    let swept = sweep.swept().to_vec();
    (samples, swept)
}

#[test]
fn a_profiler_sweeps_the_top_and_the_outer_side_it_faces_and_nothing_else() {
    let (samples, swept) = swept_box(0.005);
    let mut top_reach: f64 = f64::NEG_INFINITY;
    let mut side_depth: f64 = f64::INFINITY;
    let mut top_inside_reach = 0;
    for (i, p) in samples.points.iter().enumerate() {
        let on_top = (p.z - 0.4).abs() < 1e-9;
        let on_side = (p.y + 0.1).abs() < 1e-9;
        let within = (-0.2 + 0.001..0.2 - 0.001).contains(&p.x);
        if !swept[i] {
            // Inside the footprint, analytically: the top from the edge to 0.1016 m in, the
            // side down to 0.1836 m below the top (where its incidence reaches 80°).
            if within && on_top && p.y < -0.1 + 0.1016 - 0.002 {
                top_inside_reach += 1;
            }
            if within && on_side && p.z > 0.4 - 0.1836 + 0.002 {
                panic!("side sample at {p} not swept");
            }
            continue;
        }
        assert!(on_top || on_side, "swept off the faces it sees: {p}");
        assert!(
            (-0.2 - 1e-9..=0.2 + 1e-9).contains(&p.x),
            "beyond the path: {p}"
        );
        if on_top {
            top_reach = top_reach.max(p.y + 0.1);
        } else {
            side_depth = side_depth.min(p.z);
        }
    }
    assert_eq!(top_inside_reach, 0, "top samples within reach not swept");
    // The footprint's far ends, within a sample's spacing.
    assert!(
        (top_reach - 0.1016).abs() < 0.006,
        "top reach {top_reach:.4} m"
    );
    assert!(
        (0.4 - side_depth - 0.1836).abs() < 0.006,
        "side depth {:.4} m",
        0.4 - side_depth
    );
}

#[test]
fn profiles_too_far_apart_sweep_nothing_between_them() {
    // A profile every 0.1 mm, but a step allowed of 0.05 mm: nothing is swept.
    let (_, swept) = swept_box(0.00005);
    assert!(swept.iter().all(|s| !s));
}
