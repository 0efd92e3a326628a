//! `asbuilt report`: a recording inspected again offline, into the same `report.json` that
//! `inspect` writes and an HTML page that opens without a network.
//!
//! The design comes from the recording's attachment and the settings from its configuration,
//! so the review needs nothing but the file. Every station is recomputed from its recorded pose
//! and scan chunks with the same inspector the agent runs ([`asbuilt_readback`]).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use asbuilt_report::{Report, summary_table};
use clap::Args;

use asbuilt_readback::{Overrides, read};

/// `asbuilt report`'s arguments.
#[derive(Args)]
pub struct ReportArgs {
    /// The recording (from the agent's recorder or `asbuilt pack`); several files of one job
    /// (a job the agent resumed after a stop, or rotated into parts); or the agent's recording
    /// folder, for its newest job.
    #[arg(required = true, value_name = "RECORDING")]
    recordings: Vec<PathBuf>,
    /// With a folder: the job to report instead of the newest.
    #[arg(long)]
    job: Option<u64>,
    /// Output folder for report.json and report.html.
    #[arg(long, default_value = "out/report")]
    out: PathBuf,
    /// Tolerance, metres; default the recording's configuration, else 0.005.
    #[arg(long)]
    tolerance: Option<f64>,
    /// Maximum distance, metres; default the recording's configuration, else 10 × tolerance.
    #[arg(long)]
    max_distance: Option<f64>,
    #[command(flatten)]
    judging: asbuilt_readback::Judging,
}

/// Writes report.json and report.html for a recording and prints its summary table.
pub fn run(args: ReportArgs) -> Result<ExitCode> {
    write(
        &args.recordings,
        &args.out,
        Overrides {
            tolerance: args.tolerance,
            max_distance: args.max_distance,
            job: args.job,
            judging: args.judging,
        },
    )
    .map_err(|e| {
        // Every refusal names the recording it is about.
        let path = args.recordings[0].display().to_string();
        if format!("{e:#}").contains(&path) {
            e
        } else {
            e.context(format!("cannot report on {path}"))
        }
    })?;
    Ok(ExitCode::SUCCESS)
}

/// Writes `out/report.json` and `out/report.html` for the job `recordings` name (see
/// [`asbuilt_readback::files::job_files`]), and returns the report.
pub fn write(
    recordings: &[PathBuf],
    out: &std::path::Path,
    overrides: Overrides,
) -> Result<Report> {
    let png = overrides.judging.png;
    let files = asbuilt_readback::files::job_files(recordings, overrides.job)?;
    let (report, _) = read(&files, overrides, false)?;
    let source = match files.as_slice() {
        [one] => one.display().to_string(),
        many => format!(
            "{} files from {} to {}",
            many.len(),
            many[0].display(),
            many[many.len() - 1].display()
        ),
    };
    write_outputs(&source, out, &report)?;
    if png {
        crate::maps_png::write(&report, out)?;
    }
    Ok(report)
}

fn write_outputs(source: &str, out: &std::path::Path, report: &Report) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let json = out.join("report.json");
    std::fs::write(&json, serde_json::to_string_pretty(report)?)
        .with_context(|| format!("cannot write {}", json.display()))?;
    let html = out.join("report.html");
    std::fs::write(&html, asbuilt_report::html::page(report, source))
        .with_context(|| format!("cannot write {}", html.display()))?;
    print!("{}", summary_table(report));
    print!("{}", asbuilt_report::verdict_text(report));
    eprintln!("wrote {} and {}", json.display(), html.display());
    Ok(())
}
