//! `asbuilt convert`: scan files from one format to another, every scan of every input into
//! one output. PTX and E57 keep each scan in its frame with its pose; LAS, PLY and ASCII get the
//! points placed by their poses, with intensity and scan index as scalar fields.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Result, bail};
use asbuilt_io::scan::write::{self, OutScan};
use asbuilt_io::scan::{DEFAULT_CHUNK, Format, ScanFile};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Isometry3;

#[derive(Args)]
pub struct ConvertArgs {
    /// Scan files: E57, LAS/LAZ, PTX, PLY, XYZ/PTS/TXT.
    #[arg(required_unless_present = "ros2")]
    inputs: Vec<PathBuf>,
    /// A ROS 2 bag's clouds instead, each a scan placed by the bag's transform tree.
    #[command(flatten)]
    ros2: crate::ros2_args::Ros2Args,
    /// The output; its extension picks the format (.e57, .ptx, .las, .laz, .ply, .txt/.xyz).
    #[arg(long, short)]
    out: PathBuf,
}

pub fn run(args: ConvertArgs) -> Result<ExitCode> {
    Format::from_path(&args.out)?;
    let mut files: Vec<ScanFile> = args
        .inputs
        .iter()
        .map(|p| ScanFile::open(p))
        .collect::<Result<_, _>>()?;
    files.extend(args.ros2.scan_file(None)?);
    if args.inputs.iter().any(|p| p == &args.out) {
        bail!("--out {} is also an input", args.out.display());
    }
    // PTX and PLY need counts up front; count the scans that do not declare theirs.
    let mut counts = Vec::new();
    for f in &files {
        for s in &f.scans {
            let n = match s.points {
                Some(n) => n,
                None => {
                    let mut n = 0u64;
                    f.stream(s.index, DEFAULT_CHUNK, &mut |c| {
                        n += c.len() as u64;
                        Ok(())
                    })?;
                    n
                }
            };
            counts.push(n);
        }
    }
    let total: u64 = counts.iter().sum();
    let bar = ProgressBar::new(total).with_style(
        ProgressStyle::with_template("[{bar:30}] {pos}/{len} points ({per_sec})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let mut writer = write::create(&args.out, total)?;
    let mut k = 0;
    let mut written = 0u64;
    for f in &files {
        for s in &f.scans {
            let scan = OutScan {
                name: s.name.clone(),
                pose: s.pose.map(|p| p.0).unwrap_or_else(Isometry3::identity),
                points: counts[k],
            };
            k += 1;
            let mut notes = None;
            written += writer.write_scan(&scan, &mut |emit| {
                notes = Some(f.stream(s.index, DEFAULT_CHUNK, &mut |c| {
                    bar.inc(c.len() as u64);
                    emit(c)
                })?);
                Ok(())
            })?;
            if let Some(n) = notes.filter(|n| n.malformed_lines > 0) {
                eprintln!(
                    "warning: {} {}: {} unreadable lines skipped (first at line {})",
                    f.path.display(),
                    s.name,
                    n.malformed_lines,
                    n.first_malformed_line.unwrap_or(0)
                );
            }
        }
    }
    writer.finish()?;
    bar.finish_and_clear();
    eprintln!(
        "wrote {} ({} scans, {written} of {total} points; formats without an invalid flag leave \
         the scanner's invalid points out)",
        args.out.display(),
        counts.len()
    );
    Ok(ExitCode::SUCCESS)
}
