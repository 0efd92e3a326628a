//! A line profiler's passes: the robot's mount poses form one track; each profile is placed by
//! the pose interpolated at its time (`asbuilt_core::profiler::Placer`), or waits for its later
//! pose, or is refused with its reason. A pass is a station: its profile chunks are its chunks
//! (counted, in order, against its End), its placed points go through the station's inspector
//! in the design frame, and its coverage is what the laser's plane swept.
//!
//! Memory is fixed: the poses kept and the profiles waiting are bounded (`[profiler]`), a pass
//! holds at most `hold_points` placed points while its printed design is prepared, and the
//! point buffers of profiles that left the wait are reused.

use asbuilt_core::profiler::{MountPose as TrackPose, Placed, Placer, PlacerCounts, Refused};
use asbuilt_protocol::{MountPose, ProfileHeader, ProfilePoint};
use nalgebra::{Isometry3, Point3};

use super::*;
use crate::config::ProfilerConfig;

/// A profile waiting for its pose: its pass and its points, sensor frame.
pub(super) struct Profile {
    key: StationKey,
    attempt: u16,
    points: Vec<ProfilePoint>,
}

/// What the placer let go during one call, in order.
#[derive(Default)]
struct Left(Vec<(Profile, Result<Isometry3<f64>, Refused>)>);

impl Placed<Profile> for Left {
    fn placed(&mut self, profile: Profile, sensor: &Isometry3<f64>) {
        self.0.push((profile, Ok(*sensor)));
    }
    fn refused(&mut self, profile: Profile, why: Refused) {
        self.0.push((profile, Err(why)));
    }
}

/// A pass's placed profiles not yet compared: design-frame points and each profile's sensor.
#[derive(Default)]
pub(super) struct PassBuffer {
    points: Vec<ScanPoint>,
    sensors: Vec<Isometry3<f64>>,
    /// Batches compared so far: the sequence of the pass's deviation chunks.
    batches: u64,
    /// The last refusal's reason was logged (once per pass and reason).
    logged: Option<std::mem::Discriminant<Refused>>,
}

/// The profiler's side of the lifecycle.
pub(super) struct Profiler {
    config: ProfilerConfig,
    placer: Placer<Profile>,
    left: Left,
    /// Point buffers of profiles that left the wait, for the next ones.
    spare: Vec<Vec<ProfilePoint>>,
    /// The job of the newest mount pose taken: its stations are passes.
    track_job: Option<u64>,
}

impl Profiler {
    pub(super) fn new(config: ProfilerConfig) -> Self {
        Self {
            placer: Placer::new(config.track(), config.wait_profiles),
            config,
            left: Left::default(),
            spare: Vec::new(),
            track_job: None,
        }
    }

    /// What the placer did since start.
    pub(super) fn counts(&self) -> &PlacerCounts {
        self.placer.counts()
    }

    /// Profiles waiting for their later pose.
    pub(super) fn waiting(&self) -> usize {
        self.placer.waiting()
    }

    fn buffer(&mut self, n: usize) -> Vec<ProfilePoint> {
        let mut b = self.spare.pop().unwrap_or_default();
        b.clear();
        b.reserve(n);
        b
    }
}

impl<C: ChunkSource> Lifecycle<C> {
    /// Uses `[profiler]` for the passes of a line profiler.
    pub fn with_profiler(mut self, config: ProfilerConfig) -> Self {
        self.profiler = Profiler::new(config);
        self
    }

    /// What the profiler's placer did since start: profiles placed, waited, refused by reason.
    pub fn profiler_counts(&self) -> PlacerCounts {
        *self.profiler.counts()
    }

    /// Takes an open station as a line profiler's pass (an agent resuming a pass whose
    /// profiles did not reach the disk before it stopped): it goes on with what comes, and is
    /// not reported interrupted. False when it is not open.
    pub fn take_up_pass(&mut self, job: u64, pass: u32) -> bool {
        match self.find(&(job, pass)) {
            Some(i) => {
                self.open[i].profiled = true;
                true
            }
            None => false,
        }
    }

    /// The lowest height a pass of `job` at printed height `height` judges, when `job` is
    /// printed with a profiler (`profiled`, or its newest mount pose says so): the profiler
    /// rides beside the nozzle, at the printed height or above it, and nothing farther than its
    /// `max_range` below returns light to it. Findings keep the design samples from there up,
    /// so their state does not grow with the print.
    pub(super) fn pass_floor(&self, job: u64, height: f64, profiled: bool) -> Option<f64> {
        let profiled = profiled || self.profiler.track_job == Some(job);
        (profiled && height.is_finite()).then_some(height - self.profiler.config.max_range)
    }

    /// A pass's position σ: the robot's pose accuracy, from `[profiler]`.
    pub(super) fn profiler_sigma(&self) -> f64 {
        self.profiler.config.position_sigma
    }

    /// Profiles waiting for their later pose now.
    pub fn profiles_waiting(&self) -> usize {
        self.profiler.waiting()
    }

    /// Takes a robot pose of the profiler's mount: the waiting profiles it brackets are
    /// placed.
    pub fn on_mount_pose(&mut self, m: &MountPose, now: Instant, out: &mut impl Outputs) {
        if !self.readable::<MountPose>(m.version, format_args!("mount pose {}", m.sequence)) {
            return;
        }
        let parts = asbuilt_core::frames::isometry(m.translation, m.rotation_xyzw).and_then(|b| {
            asbuilt_core::frames::isometry(m.mount_sensor_translation, m.mount_sensor_rotation_xyzw)
                .map(|s| (b, s))
        });
        let (base_mount, mount_sensor) = match parts {
            Ok(p) => p,
            Err(e) => {
                self.counters.input.poses_invalid += 1;
                warn!("job {} mount pose {}: rejected: {e}", m.job, m.sequence);
                return;
            }
        };
        let p = &mut self.profiler;
        if p.placer.track().params().mount_sensor != mount_sensor {
            // A new calibration: the profiles waiting were taken under the old one.
            if !p.placer.track().is_empty() {
                info!(
                    "job {}: the profiler's mount-to-sensor calibration changed with mount pose \
                     {}; profiles waiting are refused",
                    m.job, m.sequence
                );
            }
            p.placer.set_mount_sensor(mount_sensor, &mut p.left);
        }
        let pose = TrackPose {
            time_ns: m.time_ns.min(i64::MAX as u64) as i64,
            pose: self.frames.t_design_base * base_mount,
        };
        match p.placer.pose(pose, &mut p.left) {
            Ok(()) => p.track_job = Some(m.job),
            Err(e) => {
                self.counters.input.poses_invalid += 1;
                warn!("job {} mount pose {}: rejected: {e}", m.job, m.sequence);
            }
        }
        self.take_left(now, out);
        // A pass that ended waiting for this pose closes now.
        let mut i = 0;
        while i < self.open.len() {
            let open = self.open.len();
            if self.open[i].profiled {
                self.close_if_complete(i, out);
            }
            if self.open.len() == open {
                i += 1;
            }
        }
    }

    /// Takes a chunk of a pass's profiles: counted as the pass's chunk, each profile placed or
    /// waiting for its pose.
    pub fn on_profiles(
        &mut self,
        h: &ProfileHeader,
        points: &[ProfilePoint],
        now: Instant,
        out: &mut impl Outputs,
    ) {
        let n = points.len();
        let what = format_args!("profile chunk ({n} points)");
        if !self.readable::<ProfileHeader>(h.version, what) {
            return;
        }
        let key = (h.job, h.pass);
        let attempt = attempt_of(h.attempt);
        if self.is_over(key, attempt, out) {
            self.counters.input.chunks_after_close += 1;
            warn!(
                "job {} pass {} attempt {attempt}: profile chunk {} arrived after the pass's \
                 report, dropped ({n} points)",
                key.0, key.1, h.sequence
            );
            return;
        }
        let i = self.open_slot(key, attempt, now, out);
        let s = &mut self.open[i];
        s.profiled = true;
        s.last_activity = now;
        if h.last != 0 {
            s.last_sequence = Some(h.sequence);
            s.finished_at.get_or_insert(now);
        }
        if !self.accept_profiles(i, h, n) {
            return;
        }
        let profiles = h.profiles(n).expect("accept_profiles checked the shape");
        for (sensor_ns, range) in profiles {
            let mut b = self.profiler.buffer(range.len());
            b.extend_from_slice(&points[range]);
            let profile = Profile {
                key,
                attempt,
                points: b,
            };
            let p = &mut self.profiler;
            p.placer.profile(sensor_ns, profile, &mut p.left);
        }
        self.counters.chunks_processed += 1;
        self.take_left(now, out);
        if let Some(i) = self.find(&key) {
            self.close_if_complete(i, out);
        }
    }

    /// Whether a profile chunk is the pass's next and well formed; counted and its points
    /// rejected when not.
    fn accept_profiles(&mut self, i: usize, h: &ProfileHeader, n: usize) -> bool {
        let s = &mut self.open[i];
        let input = &mut self.counters.input;
        let verdict = s.tracker.offer(h.sequence);
        let problem = match verdict {
            ChunkVerdict::Duplicate => {
                input.chunks_duplicate += 1;
                Some("repeated".to_string())
            }
            ChunkVerdict::TooOld => {
                input.chunks_out_of_order += 1;
                Some("too far out of order to tell whether it is new".to_string())
            }
            _ if n > self.limits.max_points_per_chunk => {
                input.chunks_oversized += 1;
                s.oversized += 1;
                Some(format!(
                    "has {n} points, more than limits.max_points_per_chunk = {}",
                    self.limits.max_points_per_chunk
                ))
            }
            _ => h.profiles(n).err().map(|e| {
                input.chunks_malformed += 1;
                e.to_string()
            }),
        };
        if n == 0 && problem.is_none() {
            input.chunks_empty += 1;
            s.empty += 1;
        }
        match problem {
            None => true,
            Some(why) => {
                s.inspector.reject(n as u64, |r| &mut r.in_rejected_chunks);
                warn!(
                    "job {} pass {}: profile chunk {} {why}, rejected",
                    h.job, h.pass, h.sequence
                );
                false
            }
        }
    }

    /// The profiles the placer let go: placed ones into their pass's buffer (compared when a
    /// batch is full), refused ones counted against their pass.
    fn take_left(&mut self, now: Instant, out: &mut impl Outputs) {
        let mut left = std::mem::take(&mut self.profiler.left.0);
        for (profile, placed) in left.drain(..) {
            let n = profile.points.len() as u64;
            match self.find(&profile.key) {
                Some(i) if self.open[i].attempt == profile.attempt => {
                    match placed {
                        Ok(sensor) => self.hold_placed(i, &sensor, &profile.points),
                        Err(why) => self.refuse_profile(i, n, why),
                    }
                    self.compare_full(i, now, out);
                }
                // Its pass closed (it gave the profile up) or moved to a later attempt.
                _ => self.counters.input.chunks_after_close += 1,
            }
            self.profiler.spare.push(profile.points);
        }
        self.profiler.left.0 = left;
    }

    /// A placed profile's points into the design frame, into its pass's buffer; refused when
    /// the buffer holds `hold_points` already (the printed design is not ready).
    fn hold_placed(&mut self, i: usize, sensor: &Isometry3<f64>, points: &[ProfilePoint]) {
        let hold = self.profiler.config.hold_points.max(self.batch());
        let s = &mut self.open[i];
        let b = s.profiles.get_or_insert_with(Default::default);
        if b.points.len() + points.len() > hold {
            s.inspector
                .reject(points.len() as u64, |r| &mut r.without_pose);
            return;
        }
        b.sensors.push(*sensor);
        // The laser's plane is the sensor's y = 0. A ray without a return (NaN) stays NaN and
        // is counted by the inspector as not finite.
        b.points.extend(points.iter().map(|p| {
            let d = sensor * Point3::new(p.x as f64, 0.0, p.z as f64);
            ScanPoint::new(d.x as f32, d.y as f32, d.z as f32)
        }));
    }

    fn refuse_profile(&mut self, i: usize, n: u64, why: Refused) {
        let s = &mut self.open[i];
        s.inspector.reject(n, |r| &mut r.without_pose);
        let b = s.profiles.get_or_insert_with(Default::default);
        let kind = std::mem::discriminant(&why);
        if b.logged != Some(kind) {
            b.logged = Some(kind);
            warn!(
                "job {} pass {}: a profile is refused: {why} (further refusals for this reason \
                 are counted, not logged)",
                s.key.0, s.key.1
            );
        }
    }

    fn batch(&self) -> usize {
        self.profiler
            .config
            .batch_points
            .min(self.limits.max_points_per_chunk)
            .max(1)
    }

    /// Compares the pass's held points once a batch is full and its design is ready.
    fn compare_full(&mut self, i: usize, now: Instant, out: &mut impl Outputs) {
        let full = self.open[i]
            .profiles
            .as_ref()
            .is_some_and(|b| b.points.len() >= self.batch());
        if full && self.ready(i) {
            self.compare_held(i, now, out);
        }
    }

    /// Compares everything the pass holds: its points through the inspector (in batches), its
    /// profiles' sensors into the sweep.
    pub(super) fn compare_held(&mut self, i: usize, now: Instant, out: &mut impl Outputs) {
        let Some(mut b) = self.open[i].profiles.take() else {
            return;
        };
        let key = self.open[i].key;
        let sweep = self.profiler.config.sweep();
        if self.begin_findings(i)
            && let Some(stage) = self.findings.as_mut()
        {
            for sensor in &b.sensors {
                stage.sweep(key, sensor, sweep);
            }
        }
        let batch = self.batch();
        for (j, points) in b.points.chunks(batch).enumerate() {
            let seq = b.batches + j as u64;
            self.inspect(i, (key.0, key.1, seq, 0), points, now, out);
        }
        b.batches += b.points.len().div_ceil(batch) as u64;
        if let (Some(sensor), Some(begin)) = (b.sensors.last(), self.open[i].begin) {
            out.pass_sensor(key, begin.layer, sensor);
        }
        b.points.clear();
        b.sensors.clear();
        self.open[i].profiles = Some(b);
    }

    /// Before a pass closes: its profiles still waiting are refused (no later pose came), and
    /// what it holds is compared, or refused when its design never became ready.
    pub(super) fn end_pass(&mut self, i: usize, now: Instant, out: &mut impl Outputs) {
        let key = self.open[i].key;
        if self.profiler.placer.any_waiting(|p| p.key == key) {
            let p = &mut self.profiler;
            p.placer.end_pass(&mut p.left);
            self.take_left(now, out);
        }
        if self.ready(i) {
            self.compare_held(i, now, out);
        } else if let Some(b) = self.open[i].profiles.take() {
            let n = b.points.len() as u64;
            self.open[i].inspector.reject(n, |r| &mut r.without_pose);
        }
        let c = self.profiler.counts();
        info!(
            "job {} pass {}: profiles since start: {} placed ({} after waiting), {} refused \
             (gap {}, before the poses kept {}, wait full {}, no later pose {}, bad time {}); \
             {} poses refused",
            key.0,
            key.1,
            c.placed,
            c.waited,
            c.refused(),
            c.refused_gap,
            c.refused_before_poses,
            c.refused_wait_full,
            c.refused_no_later_pose,
            c.refused_bad_time,
            c.poses_refused
        );
    }

    /// Whether a pass still waits for poses for some of its profiles.
    pub(super) fn profiles_wait_for(&self, key: StationKey) -> bool {
        self.profiler.placer.any_waiting(|p| p.key == key)
    }
}
