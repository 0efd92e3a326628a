//! The simulated cell scanning while printing: a line profiler behind the nozzle sends every
//! layer's pass as it is laid. Each layer is a pass (a station numbered as the layer): its
//! Begin with the printed height, then the robot's mount poses and the profiler's chunks
//! interleaved as they happen (a chunk goes once its last profile is taken, with the poses up
//! to then before it), then its End. The printer does not wait for the agent; closed loop, it
//! prints each next layer with the latest advice, waiting for the advice after each pass.

use std::time::{Duration, Instant};

use asbuilt_protocol::ipc::CellPorts;
use asbuilt_protocol::{
    FixedText, MAX_PROFILES_PER_CHUNK, MountPose, ProfileHeader, ProfilePoint, StationEvent,
    StationEventKind, unix_time_ns,
};
use nalgebra::Isometry3;
use rayon::prelude::*;

use crate::cell::{Result, collect, finish, tell_applied, wait_for_advice};
use crate::profiler::{Profile, ProfilePass, ProfilerModel};
use crate::{LayerSettings, PlannedStation, SimEvent, SimJob, SimOutcome};

/// The robot moves from one layer's end to the next layer's start in this long.
const NEXT_LAYER_NS: i64 = 500_000_000;

/// What the profiler sends of one pass.
#[derive(Debug, Clone, Copy, Default)]
struct Sent {
    chunks: u32,
    points: u64,
}

/// Sends `job` to the agent behind `ports` as a print scanned by `model` while it is laid:
/// every layer a pass. Profiles go `profiles_per_chunk` to a chunk (at most
/// [`MAX_PROFILES_PER_CHUNK`]). Real time when `job.rate` is set, else as fast as the agent
/// takes them. Waits up to `wait` for the last reports (and findings, when `expect_findings`).
pub fn run_printing(
    job: &SimJob,
    model: &ProfilerModel,
    profiles_per_chunk: usize,
    ports: &CellPorts,
    expect_findings: bool,
    wait: Duration,
    on: &mut dyn FnMut(SimEvent<'_>),
) -> Result<SimOutcome> {
    let per_chunk = profiles_per_chunk.clamp(1, MAX_PROFILES_PER_CHUNK);
    let mut out = SimOutcome::default();
    let started = Instant::now();
    collect(job.job, ports, &mut out, on)?;
    let mut settings: Vec<LayerSettings> = Vec::new();
    let plan = job.plan();
    let layers = plan.len() as u32;
    let mut robot_ns = job.job_started_ns.min(i64::MAX as u64 / 2) as i64;
    for layer in 0..layers {
        if job.closed_loop && layer > 0 {
            let advice = wait_for_advice(job, layer - 1, ports, &mut out, on)?;
            settings.push(advice.map_or(LayerSettings::NOMINAL, |c| {
                LayerSettings::advised(&c, layer).scaled(job.apply)
            }));
            let followed = advice.map_or(u32::MAX, |c| c.layer);
            tell_applied(job, ports, &settings, layer..layer + 1, followed)?;
            on(SimEvent::Printing {
                layers: (layer, layer),
                advice: advice.as_ref(),
            });
        } else if job.closed_loop {
            settings.push(LayerSettings::NOMINAL);
            tell_applied(job, ports, &settings, 0..1, u32::MAX)?;
        }
        let built = job.as_built_with(layer + 1, &settings)?;
        let pass = ProfilePass::new(&job.part, &built, layer, *model, job.seed, robot_ns)?;
        let station = &plan[layer as usize];
        let t = Instant::now();
        let sent = send_pass(job, model, &pass, station, per_chunk, ports)?;
        on(SimEvent::Sent {
            station,
            points: sent.points,
            seconds: t.elapsed().as_secs_f64(),
        });
        out.points_sent += sent.points;
        robot_ns = pass.end_ns() + NEXT_LAYER_NS;
        collect(job.job, ports, &mut out, on)?;
    }
    out.settings = settings;
    finish(job, ports, (expect_findings, wait), started, out, on)
}

/// One pass on the wire: Begin, poses and profile chunks in time order, End.
fn send_pass(
    job: &SimJob,
    model: &ProfilerModel,
    pass: &ProfilePass<'_>,
    station: &PlannedStation,
    per_chunk: usize,
    ports: &CellPorts,
) -> Result<Sent> {
    let n = pass.profiles();
    let chunks = n.div_ceil(per_chunk) as u32;
    let mut ev = StationEvent::new(StationEventKind::Begin, job.job, station.index);
    ev.job_started_ns = job.job_started_ns;
    ev.name = FixedText::truncated(&station.name);
    ev.layer = station.index;
    ev.printed_height = station.printed_height;
    ev.expected_chunks = chunks;
    ev.timestamp_ns = unix_time_ns();
    ports.send_event(&ev)?;
    let poses = pass.poses();
    let mount_sensor = model.mount_sensor();
    let mut next_pose = 0;
    let send_poses_to = |t_ns: i64, next: &mut usize| -> Result<()> {
        while let Some(p) = poses.get(*next).filter(|p| p.time_ns <= t_ns) {
            let m = mount_pose(job.job, station.index, *next as u64, p, &mount_sensor);
            ports.send_mount_pose(&m)?;
            *next += 1;
        }
        Ok(())
    };
    let wall = Instant::now();
    let first_ns = pass.profile_time_ns(0).unwrap_or(0);
    let mut sent = Sent::default();
    let mut buf: Vec<ProfilePoint> = Vec::new();
    for c in 0..chunks as usize {
        let ks = c * per_chunk..((c + 1) * per_chunk).min(n);
        let profiles: Vec<Profile> = ks.into_par_iter().filter_map(|k| pass.profile(k)).collect();
        let last_ns = profiles
            .last()
            .map_or(first_ns, |p| p.sensor_ns as i64 + model.clock_offset_ns);
        if job.rate.is_some() {
            // Real time: the chunk leaves when its last profile was taken.
            let due = Duration::from_nanos((last_ns - first_ns).max(0) as u64);
            if let Some(ahead) = due.checked_sub(wall.elapsed()) {
                std::thread::sleep(ahead);
            }
        }
        send_poses_to(last_ns, &mut next_pose)?;
        let mut h = ProfileHeader::new(job.job, station.index, c as u64);
        h.timestamp_ns = unix_time_ns();
        h.last = u8::from(c + 1 == chunks as usize);
        buf.clear();
        for p in &profiles {
            h.push(p.sensor_ns, p.points.len() as u32);
            buf.extend(p.points.iter().map(|q| ProfilePoint { x: q[0], z: q[2] }));
        }
        ports.send_profiles(&h, &buf)?;
        sent.chunks += 1;
        sent.points += buf.len() as u64;
    }
    send_poses_to(i64::MAX, &mut next_pose)?;
    let mut end = StationEvent::new(StationEventKind::End, job.job, station.index);
    end.job_started_ns = job.job_started_ns;
    end.name = ev.name;
    end.layer = station.index;
    end.printed_height = station.printed_height;
    end.expected_chunks = sent.chunks;
    end.expected_points = sent.points;
    end.timestamp_ns = unix_time_ns();
    ports.send_event(&end)?;
    Ok(sent)
}

/// A robot pose of the mount as the controller sends it, with the calibration.
fn mount_pose(
    job: u64,
    pass: u32,
    sequence: u64,
    p: &asbuilt_core::profiler::MountPose,
    mount_sensor: &Isometry3<f64>,
) -> MountPose {
    let mut m = MountPose::new(job, pass, sequence, p.time_ns.max(0) as u64);
    m.translation = p.pose.translation.vector.into();
    let q = p.pose.rotation.coords;
    m.rotation_xyzw = [q.x, q.y, q.z, q.w];
    m.mount_sensor_translation = mount_sensor.translation.vector.into();
    let q = mount_sensor.rotation.coords;
    m.mount_sensor_rotation_xyzw = [q.x, q.y, q.z, q.w];
    m
}
