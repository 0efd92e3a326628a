//! The simulated profiler against what it looks at: its points on the as-built surface, the
//! top and the outer side both seen, its poses good enough to place it, its noise repeatable.

use asbuilt_core::profiler::{PoseAt, PoseTrack, PoseTrackParams};
use asbuilt_core::{C2mIndex, C2mParams, Cursor, Design};
use nalgebra::Point3;

use super::*;
use crate::as_built;

const START_NS: i64 = 1_795_000_000_000_000_000;

fn column_pass(built: &AsBuilt, model: ProfilerModel) -> ProfilePass<'_> {
    ProfilePass::new(&Part::column(), built, 10, model, 7, START_NS).unwrap()
}

/// Design-frame points of profile `k`, placed with the true pose of its time.
fn placed(pass: &ProfilePass, k: usize, model: &ProfilerModel) -> Vec<Point3<f64>> {
    let p = pass.profile(k).unwrap();
    let t = pass.profile_time_ns(k).unwrap();
    let sensor = pass.mount_at(t).unwrap() * model.mount_sensor();
    p.points
        .iter()
        .map(|q| sensor * Point3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2])))
        .collect()
}

#[test]
fn a_profile_lies_on_the_as_built_surface_and_sees_the_top_and_the_outer_side() {
    let part = Part::column();
    let built = as_built(&part, &[], 11).unwrap();
    let model = ProfilerModel::default();
    let pass = column_pass(&built, model);
    // An ellipse of 0.15 × 0.10 m: 0.79 m of path at 0.2 m/s, 2,000 profiles a second.
    let n = pass.profiles();
    assert!((7_800..8_000).contains(&n), "{n}");
    let mesh = Design::from_indexed(built.vertices.clone(), built.triangles.clone(), 1.0).unwrap();
    let index = C2mIndex::from_design(mesh, C2mParams::within(0.05)).unwrap();
    let mut cursor = Cursor::default();
    let top = built.top;
    for k in (0..n).step_by(397) {
        let pts = placed(&pass, k, &model);
        // The rays out past the edge and below the side's reach return nothing.
        assert!(pts.len() > 1_000, "profile {k}: {} points", pts.len());
        let mut worst: f64 = 0.0;
        for p in &pts {
            let d = index
                .query(p, &mut cursor)
                .map_or(f64::INFINITY, |c| c.distance);
            worst = worst.max(d);
        }
        // Range noise of 0.05 mm: five σ.
        assert!(worst < 0.25e-3, "profile {k}: {:.3} mm off", worst * 1e3);
        let on_top = pts.iter().filter(|p| (p.z - top).abs() < 1e-3).count();
        let on_side = pts.iter().filter(|p| p.z < top - 0.01).count();
        assert!(
            on_top > 300 && on_side > 300,
            "{k}: {on_top} top, {on_side} side"
        );
    }
}

#[test]
fn its_poses_place_every_profile_within_five_hundredths_of_a_millimetre() {
    let part = Part::column();
    let built = as_built(&part, &[], 11).unwrap();
    let model = ProfilerModel {
        clock_offset_ns: 5_000_000,
        ..Default::default()
    };
    let pass = column_pass(&built, model);
    let mut track = PoseTrack::new(PoseTrackParams {
        capacity: 4096,
        max_gap_ns: 20_000_000,
        clock_offset_ns: model.clock_offset_ns,
        mount_sensor: model.mount_sensor(),
    });
    let poses = pass.poses();
    // 250 a second over 3.96 s, and one at the end.
    assert!((985..=1_000).contains(&poses.len()), "{}", poses.len());
    for p in &poses {
        track.push(*p).unwrap();
    }
    // Where the laser meets the top of the layer: 0.1 m down the view, tilted.
    let probe = Point3::new(0.0, 0.0, 0.11);
    let mut worst: f64 = 0.0;
    for k in 0..pass.profiles() {
        let t = pass.profile_time_ns(k).unwrap();
        let sensor_ns = (t - model.clock_offset_ns) as u64;
        let PoseAt::Ready(placed) = track.at(sensor_ns) else {
            panic!("profile {k}: {:?}", track.at(sensor_ns));
        };
        let truth = pass.mount_at(t).unwrap() * model.mount_sensor();
        let e = (placed * probe - truth * probe).norm();
        worst = worst.max(e);
    }
    assert!(worst < 0.05e-3, "{:.4} mm", worst * 1e3);
}

#[test]
fn a_pass_is_the_same_for_the_same_seed() {
    let part = Part::column();
    let built = as_built(&part, &[], 11).unwrap();
    let model = ProfilerModel::default();
    let a = column_pass(&built, model);
    let b = column_pass(&built, model);
    for k in [0, 1, 4000, a.profiles() - 1] {
        assert_eq!(a.profile(k), b.profile(k), "{k}");
    }
    assert_eq!(a.poses(), b.poses());
    assert_eq!(a.profile(a.profiles()), None);
    // Its sensor clock runs behind the robot's by the offset.
    let late = ProfilePass::new(
        &part,
        &built,
        10,
        ProfilerModel {
            clock_offset_ns: 5_000_000,
            ..model
        },
        7,
        START_NS,
    )
    .unwrap();
    let (x, y) = (a.profile(10).unwrap(), late.profile(10).unwrap());
    assert_eq!(x.sensor_ns - y.sensor_ns, 5_000_000);
    assert_eq!(x.points, y.points);
}
