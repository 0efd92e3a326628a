//! What each target does with an input: the same calls a user's command or the agent makes.

use std::path::Path;
use std::process::Command;

use asbuilt_agent::lifecycle::{Lifecycle, LifecycleLimits, Outputs};
use asbuilt_core::printed::PrintedDesigns;
use asbuilt_core::station::InspectParams;
use asbuilt_core::{C2mParams, Design, Units};
use asbuilt_io::scan::ScanFile;
use asbuilt_protocol::recording::{self, Channel, Recorded};
use asbuilt_protocol::{
    ChunkHeader, DeviationHeader, PointDeviation, ScanPoint, StationFindings, StationReport,
};

use super::Outcome;

/// One kind of input a user or a peer can hand us, and how to feed it to asbuilt.
pub struct Target {
    /// The target's name, as `fuzz --target` takes it.
    pub name: &'static str,
    /// A text format: number tokens are mutated too.
    pub text: bool,
    /// Inputs per run of the fixed budget, relative to the others (a target that starts a
    /// process per input gets fewer).
    pub weight: f64,
    run: fn(&str, &[u8], &Path) -> Outcome,
}

impl Target {
    /// Runs one input named `name` (its seed's file name); `scratch` is an empty folder.
    pub fn run(&self, name: &str, bytes: &[u8], scratch: &Path) -> Outcome {
        (self.run)(name, bytes, scratch)
    }
}

/// Every fuzz target.
pub const TARGETS: &[Target] = &[
    scan("scan-ply", true),
    scan("scan-xyz", true),
    scan("scan-ptx", true),
    scan("scan-las", false),
    scan("scan-laz", false),
    scan("scan-e57", false),
    design("design-stl", true),
    design("design-ply", true),
    design("design-obj", true),
    Target {
        name: "wire",
        text: false,
        weight: 1.0,
        run: wire,
    },
    Target {
        name: "recording",
        text: false,
        weight: 1.0,
        run: recording_reads,
    },
    Target {
        name: "report",
        text: false,
        weight: 0.25,
        run: report_command,
    },
    Target {
        name: "resume",
        text: false,
        weight: 1.0,
        run: resume,
    },
    Target {
        name: "ros2-mcap",
        text: false,
        weight: 1.0,
        run: read_bag,
    },
    Target {
        name: "ros2-db3",
        text: false,
        weight: 1.0,
        run: read_bag,
    },
    Target {
        name: "agent-toml",
        text: true,
        weight: 1.0,
        run: agent_toml,
    },
];

/// The target named `name`.
pub fn target(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

const fn scan(name: &'static str, text: bool) -> Target {
    Target {
        name,
        text,
        weight: 1.0,
        run: read_scan,
    }
}

const fn design(name: &'static str, text: bool) -> Target {
    Target {
        name,
        text,
        weight: 1.0,
        run: load_design,
    }
}

/// The input as a file under its seed's name, so readers pick the format by extension.
fn as_file(name: &str, bytes: &[u8], scratch: &Path) -> std::path::PathBuf {
    let path = scratch.join(name);
    std::fs::write(&path, bytes).expect("the scratch folder is writable");
    path
}

/// An error passes when it names the file it is about.
fn named(name: &str, error: String) -> Outcome {
    if error.contains(name) {
        Outcome::Refused(error)
    } else {
        Outcome::Unclear(error)
    }
}

/// Every scan of the file, as `inspect` reads it: parsed on a thread of its own, chunks read
/// ahead (`publish` and `pack` take the same chunks from the same reader, in turn).
fn read_scan(name: &str, bytes: &[u8], scratch: &Path) -> Outcome {
    let path = as_file(name, bytes, scratch);
    let read = || -> anyhow::Result<String> {
        let file = ScanFile::open(&path)?;
        let mut points = 0usize;
        for i in 0..file.scans.len() {
            file.stream_ahead(i, 4096, 2, &mut |c| {
                points += c.len();
                Ok(())
            })?;
        }
        Ok(format!("{} scans, {points} points", file.scans.len()))
    };
    match read() {
        Ok(s) => Outcome::Read(s),
        Err(e) => named(name, format!("{e:#}")),
    }
}

/// A ROS 2 bag as `inspect --ros2` reads it: its transforms and clouds' headers, then every
/// station's points.
fn read_bag(name: &str, bytes: &[u8], scratch: &Path) -> Outcome {
    use asbuilt_io::scan::ros2::{Ros2Bag, Ros2Options};
    let path = as_file(name, bytes, scratch);
    let read = || -> anyhow::Result<String> {
        let bag = Ros2Bag::open(&path, &Ros2Options::default()).map_err(|cause| {
            asbuilt_io::IoError::Scan {
                path: path.clone(),
                cause,
            }
        })?;
        let file = ScanFile::of_ros2(&path, std::sync::Arc::new(bag));
        let mut points = 0usize;
        let mut failed = 0usize;
        for i in 0..file.scans.len() {
            match file.stream(i, 4096, &mut |c| {
                points += c.len();
                Ok(())
            }) {
                Ok(_) => {}
                // A station that cannot be read names the bag; the others go on.
                Err(e) if e.to_string().contains(name) => failed += 1,
                Err(e) => return Err(e.into()),
            }
        }
        Ok(format!(
            "{} stations ({failed} unreadable), {points} points",
            file.scans.len()
        ))
    };
    match read() {
        Ok(s) => Outcome::Read(s),
        Err(e) => named(name, format!("{e:#}")),
    }
}

/// The design loaded and indexed, as the agent does at start-up.
fn load_design(name: &str, bytes: &[u8], scratch: &Path) -> Outcome {
    let path = as_file(name, bytes, scratch);
    let design = match asbuilt_io::read_design(&path, Units::Metres) {
        Ok(d) => d,
        Err(e) => return named(name, e.to_string()),
    };
    let triangles = design.triangles.len();
    match PrintedDesigns::new(design, C2mParams::default()) {
        Ok(d) => {
            let ix = d.full().index.stats();
            Outcome::Read(format!("{triangles} triangles, index {} bytes", ix.bytes))
        }
        // The index's errors are about the design's geometry, not a file.
        Err(e) => Outcome::Refused(e.to_string()),
    }
}

/// Outputs of the agent's lifecycle, dropped.
struct Discard(Vec<PointDeviation>);

impl Outputs for Discard {
    fn deviations(
        &mut self,
        n: usize,
        fill: &mut dyn FnMut(&mut [PointDeviation]) -> DeviationHeader,
    ) {
        self.0.resize(n, PointDeviation::default());
        fill(&mut self.0);
    }
    fn report(&mut self, _: &StationReport) {}
    fn findings(&mut self, _: &StationFindings) {}
}

/// The bytes decoded as every kind of message, and whatever decodes as an input fed to the
/// agent's lifecycle, as a peer's message would be.
fn wire(_: &str, bytes: &[u8], _: &Path) -> Outcome {
    let mut lifecycle = small_lifecycle();
    let mut out = Discard(Vec::new());
    let now = std::time::Instant::now();
    let mut decoded = Vec::new();
    for channel in Channel::ALL {
        match Recorded::decode(channel, bytes) {
            Ok(m) => {
                decoded.push(channel);
                match m {
                    Recorded::Event(e) => lifecycle.on_event(&e, now, &mut out),
                    Recorded::Pose(p) => lifecycle.on_pose(&p, now, &mut out),
                    Recorded::Chunk(h, p) => lifecycle.on_chunk((h, p), now, &mut out),
                    Recorded::MountPose(m) => lifecycle.on_mount_pose(&m, now, &mut out),
                    Recorded::Profiles(h, p) => lifecycle.on_profiles(&h, &p, now, &mut out),
                    _ => {}
                }
            }
            // The error's message is what a user reads: it must format without a panic.
            Err(e) => drop(e.to_string()),
        }
    }
    lifecycle.on_idle(now + std::time::Duration::from_secs(1), &mut out);
    lifecycle.on_tick(now + std::time::Duration::from_secs(60), &mut out);
    lifecycle.shutdown(&mut out);
    if decoded.is_empty() {
        Outcome::Refused("no message decodes from these bytes".into())
    } else {
        Outcome::Read(format!("decoded as {decoded:?}"))
    }
}

/// An agent starting on a recording folder whose newest file its writer never closed (the
/// input, with its footer cut off when it has one): the file is recovered in place or set
/// aside, the job is replayed into the lifecycle and what was open is interrupted, as
/// `asbuilt-agent` does at start. It must start whatever the file holds.
fn resume(_: &str, bytes: &[u8], scratch: &Path) -> Outcome {
    use asbuilt_agent::resume;
    // What it could not use is said in warnings; the outcome below says it for the harness.
    asbuilt_agent::log::set_min_level(asbuilt_agent::log::Level::Error);
    let dir = scratch.join("recording");
    std::fs::create_dir_all(&dir).expect("scratch is writable");
    let unfinished = match bytes.strip_suffix(b"\x89MCAP0\r\n") {
        Some(b) => b,
        None => bytes,
    };
    std::fs::write(dir.join("job-1-1700000000.mcap"), unfinished).expect("scratch is writable");
    let folder = resume::scan_folder(&dir);
    let files = folder.files;
    let mut lifecycle = small_lifecycle();
    let mut out = Discard(Vec::new());
    let Some(r) = resume::replay_job(&files, &mut lifecycle) else {
        return Outcome::Refused("set aside: nothing to resume".into());
    };
    let mut open = lifecycle.interrupt_open(&mut out);
    for begin in &r.open {
        lifecycle.interrupt(begin, &mut out);
        open.push((begin.job, begin.station));
    }
    // Recovered (or set aside) while the agent would serve: the next start finds nothing
    // unfinished.
    resume::recover_files(&folder.unfinished);
    let again = resume::scan_folder(&dir);
    assert!(
        again.unfinished.is_empty(),
        "a recovered file is unfinished again"
    );
    Outcome::Read(format!(
        "{} report(s), {} replayed, {} interrupted, {} unreadable",
        r.recorded.len(),
        r.stations_replayed,
        open.len(),
        r.unreadable.len()
    ))
}

/// The agent's lifecycle on a small design, with small limits.
fn small_lifecycle() -> Lifecycle<(ChunkHeader, Vec<ScanPoint>)> {
    Lifecycle::new(
        box_design(),
        Default::default(),
        InspectParams::with_tolerance(0.005),
        LifecycleLimits {
            max_points_per_chunk: 4096,
            pending_chunks: 4,
            open_stations: 2,
            station_timeout: std::time::Duration::from_secs(10),
        },
    )
}

fn box_design() -> PrintedDesigns {
    let v = |x, y, z| nalgebra::Point3::new(x, y, z);
    let vertices = vec![
        v(0.0, 0.0, 0.0),
        v(1.0, 0.0, 0.0),
        v(0.0, 1.0, 0.0),
        v(0.0, 0.0, 1.0),
    ];
    let triangles = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let design = Design::from_indexed(vertices, triangles, 1.0).expect("a tetrahedron");
    PrintedDesigns::new(design, C2mParams::default()).expect("a tetrahedron indexes")
}

/// Everything the commands read of a recording: its messages (in file and in agent order), its
/// job metadata and design, its recorded settings, and `recover`'s rewrite.
fn recording_reads(_: &str, bytes: &[u8], _: &Path) -> Outcome {
    let mut notes = Vec::new();
    let mut refused = false;
    for ordered in [false, true] {
        let all: Result<Vec<_>, _> = if ordered {
            recording::messages_in_agent_order(bytes).map(|m| m.collect())
        } else {
            recording::messages(bytes).map(|m| m.collect())
        };
        match all {
            Ok(all) => {
                let ok = all.iter().filter(|m| m.is_ok()).count();
                refused |= ok < all.len();
                notes.push(format!("{ok} of {} messages", all.len()));
            }
            Err(e) => {
                refused = true;
                notes.push(e.to_string());
            }
        }
    }
    match recording::job(bytes) {
        Ok((meta, designs)) => {
            notes.push(format!("{} design(s)", designs.len()));
            if let Some(m) = meta {
                if let Err(p) = asbuilt_agent::config::recorded_settings(&m.config) {
                    refused = true;
                    notes.push(p.join("; "));
                }
                if let Err(p) = asbuilt_agent::config::recorded_limits(&m.config) {
                    refused = true;
                    notes.push(p.join("; "));
                }
            }
        }
        Err(e) => {
            refused = true;
            notes.push(e.to_string());
        }
    }
    match recording::recover(bytes, std::io::Cursor::new(Vec::new())) {
        Ok((_, c)) => notes.push(format!("recovered {} messages", c.messages)),
        Err(e) => {
            refused = true;
            notes.push(e.to_string());
        }
    }
    if refused {
        Outcome::Refused(notes.join("; "))
    } else {
        Outcome::Read(notes.join("; "))
    }
}

/// `asbuilt report` on the recording, as its own process (set `ASBUILT` to the binary). Its
/// address space is capped, so that an allocation no file justifies aborts it.
fn report_command(name: &str, bytes: &[u8], scratch: &Path) -> Outcome {
    let path = as_file(name, bytes, scratch);
    let bin = std::env::var("ASBUILT").expect("ASBUILT names the asbuilt binary");
    let mut cmd = Command::new(bin);
    cmd.arg("report")
        .arg(&path)
        .arg("--out")
        .arg(scratch.join("report"));
    limit_memory(&mut cmd, 4 << 30);
    let o = cmd.output().expect("asbuilt runs");
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    match o.status.code() {
        Some(0) => Outcome::Read("reported".into()),
        // A refusal: it must say which file and what is wrong.
        Some(1) | Some(2) => named(name, stderr),
        _ => panic!("asbuilt report ended with {}: {stderr}", o.status),
    }
}

fn limit_memory(cmd: &mut Command, bytes: u64) {
    use std::os::unix::process::CommandExt;
    // SAFETY: setrlimit is async-signal-safe and touches nothing of the parent.
    unsafe {
        cmd.pre_exec(move || {
            let lim = libc::rlimit {
                rlim_cur: bytes,
                rlim_max: bytes,
            };
            libc::setrlimit(libc::RLIMIT_AS, &lim);
            Ok(())
        });
    }
}

/// agent.toml read and checked as the agent does at start-up.
fn agent_toml(name: &str, bytes: &[u8], scratch: &Path) -> Outcome {
    let path = as_file(name, bytes, scratch);
    // The design the seed configuration names, so a valid file is read to the end.
    crate::write_box_stl(&scratch.join("box.stl"), [0.0; 3], [1.0; 3]);
    match asbuilt_agent::AgentConfig::load(&path) {
        Ok(_) => Outcome::Read("valid".into()),
        Err(e) => named(name, e.to_string()),
    }
}
