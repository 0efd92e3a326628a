//! `asbuilt pack`: scan files with poses into a recording that `replay` plays to an agent and
//! `report` inspects, as if a scanner on a robot had sent them at a given rate.

use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use asbuilt_core::Units;
use asbuilt_protocol::recording::{ChunkCompression, JobMetadata, Recorded, RecordingWriter};
use asbuilt_protocol::{
    ChunkHeader, FixedText, PoseMode, PoseSnapshot, ScanPoint, StationEvent, StationEventKind,
    StationSender, StationSink, unix_time_ns,
};
use clap::Args;
use sha2::{Digest, Sha256};

use asbuilt_io::stations;

#[derive(Args)]
pub struct PackArgs {
    /// Stations file: [[station]] with id, scan and a pose unless the scan file holds one. With
    /// --ros2, the clouds of each station: [[station]] with id, from and to (seconds).
    #[arg(long, required_unless_present = "ros2")]
    stations: Option<PathBuf>,
    /// A ROS 2 bag as the scans.
    #[command(flatten)]
    ros2: crate::ros2_args::Ros2Args,
    /// The design the job is inspected against; attached to the recording.
    #[arg(long)]
    design: PathBuf,
    /// Units the design file is written in (m or mm).
    #[arg(long)]
    units: Units,
    /// The recording to write.
    #[arg(long, short)]
    out: PathBuf,
    /// The job's number and start.
    #[command(flatten)]
    job: crate::job_args::JobIdentity,
    /// Points per scan chunk.
    #[arg(long, default_value_t = 16_384)]
    chunk_points: usize,
    /// The scanner's rate, points per second: sets the recorded timing a replay at --speed 1
    /// follows.
    #[arg(long, default_value_t = 1_000_000.0)]
    rate: f64,
    /// Also write channels Foxglove shows: the design, each station's frame and its scan
    /// points in that frame (see the README's Recordings section).
    #[arg(long)]
    foxglove: bool,
    /// How the file's chunks are compressed: zstd, lz4 or none.
    #[arg(long, default_value = "zstd", value_parser = compression)]
    compression: ChunkCompression,
}

fn compression(s: &str) -> Result<ChunkCompression, String> {
    match s {
        "zstd" => Ok(ChunkCompression::Zstd),
        "lz4" => Ok(ChunkCompression::Lz4),
        "none" => Ok(ChunkCompression::None),
        _ => Err(format!("{s:?}: use zstd, lz4 or none")),
    }
}

pub fn run(args: PackArgs) -> Result<ExitCode> {
    if args.chunk_points == 0 || args.chunk_points > u32::MAX as usize {
        bail!("--chunk-points must be between 1 and {}", u32::MAX);
    }
    if !(args.rate > 0.0 && args.rate.is_finite()) {
        bail!("--rate must be a positive number of points per second");
    }
    let (stations, source) = match args.ros2.stations(args.stations.as_deref())? {
        Some(s) => (s, args.ros2.ros2.clone().expect("a bag")),
        None => {
            let path = args
                .stations
                .clone()
                .expect("clap requires --stations or --ros2");
            (stations::load(&path)?, path)
        }
    };
    let job_started_ns = args.job.started_ns();
    let design = std::fs::read(&args.design)
        .with_context(|| format!("cannot read design {}", args.design.display()))?;
    // Refuse a design the agent could not load, before writing anything.
    let mesh = asbuilt_io::read_design(&args.design, args.units)?;
    let file =
        File::create(&args.out).with_context(|| format!("cannot write {}", args.out.display()))?;
    let mut w = RecordingWriter::with_compression(
        BufWriter::with_capacity(1 << 20, file),
        args.compression,
    )?;
    if args.foxglove {
        // A packed file has scans, not deviations: the colour scale is never used.
        w = w
            .with_foxglove(Box::new(|_| [255, 255, 255]))?
            .with_foxglove_scans()?;
    }
    let t0 = unix_time_ns();
    w.metadata(&metadata(&args, &design, &source))?;
    let name = args
        .design
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    w.attach_design(&name, &design, t0)?;
    let vertices = mesh.vertices.iter().map(|v| [v.x, v.y, v.z]);
    w.foxglove_design(t0, vertices, &mesh.triangles)?;
    drop(mesh);

    let mut sent = 0u64;
    for (n, st) in stations.iter().enumerate() {
        let station = n as u32;
        let scan = st.open_scan()?;
        eprintln!("station {}: pose from {}", st.id, st.pose_source);
        let declared = scan.scans[st.scan_index].points;
        let mut begin = StationEvent::new(StationEventKind::Begin, args.job.number, station);
        begin.job_started_ns = job_started_ns;
        begin.name = FixedText::truncated(&st.id);
        begin.expected_points = declared.unwrap_or(0);
        begin.expected_chunks = declared.map_or(0, |p| p.div_ceil(args.chunk_points as u64)) as u32;
        let mut pose = PoseSnapshot::new(args.job.number, station, PoseMode::DesignScanner);
        pose.translation = st.translation;
        pose.rotation_xyzw = st.rotation_xyzw;
        pose.position_sigma = st.position_sigma;
        let mut sink = Packed {
            w: &mut w,
            t0,
            rate: args.rate,
            sent_before: sent,
        };
        let mut sender = StationSender::start(begin, pose, &mut sink)?;
        scan.stream(st.scan_index, args.chunk_points, &mut |chunk| {
            Ok(sender.chunk(chunk, &mut sink)?)
        })?;
        sent += sender.points_sent();
        sender.finish(&mut sink)?;
        // A station per chunk of the file: a cut file keeps every finished station.
        w.flush()?;
    }
    w.finish()?;
    eprintln!(
        "wrote {} ({} stations, {sent} points, {:.1} s of scanning at {} points/s)",
        args.out.display(),
        stations.len(),
        sent as f64 / args.rate,
        args.rate
    );
    Ok(ExitCode::SUCCESS)
}

/// The recording's metadata: the design, and where the stations came from.
fn metadata(args: &PackArgs, design: &[u8], source: &std::path::Path) -> JobMetadata {
    JobMetadata {
        writer: "asbuilt pack".into(),
        asbuilt_version: env!("CARGO_PKG_VERSION").into(),
        design_path: args.design.display().to_string(),
        design_units: args.units.to_string(),
        design_sha256: format!("{:x}", Sha256::digest(design)),
        config: format!(
            "packed from {}\n\n{}",
            source.display(),
            args.stations
                .as_ref()
                .and_then(|p| std::fs::read_to_string(p).ok())
                .unwrap_or_default()
        ),
        calibrations: "none: poses are the scanner in the design frame".into(),
    }
}

/// A recording written as a scanner at `rate` points per second would have sent the stations.
struct Packed<'w, W: std::io::Write + std::io::Seek> {
    w: &'w mut RecordingWriter<W>,
    t0: u64,
    rate: f64,
    /// Points of the stations before this one.
    sent_before: u64,
}

impl<W: std::io::Write + std::io::Seek> StationSink for Packed<'_, W> {
    type Error = anyhow::Error;
    fn now_ns(&mut self, points_sent: u64) -> u64 {
        self.t0 + ((self.sent_before + points_sent) as f64 / self.rate * 1e9) as u64
    }
    fn event(&mut self, event: &StationEvent) -> Result<()> {
        Ok(self.w.write(event.timestamp_ns, &Recorded::Event(*event))?)
    }
    fn pose(&mut self, pose: &PoseSnapshot) -> Result<()> {
        Ok(self.w.write(pose.timestamp_ns, &Recorded::Pose(*pose))?)
    }
    fn chunk(&mut self, header: &ChunkHeader, points: &[ScanPoint]) -> Result<()> {
        let chunk = Recorded::Chunk(*header, points.to_vec());
        Ok(self.w.write(header.timestamp_ns, &chunk)?)
    }
}
