//! The `asbuilt` command line as a library: [`Cli`] parses the arguments, [`run`] runs the
//! command they name. The `asbuilt` executable is `main` over these two; the Python package runs
//! the same commands in its own process (`asbuilt.inspect`, `asbuilt.read_recording`).

#![warn(missing_docs)]

mod calibrate;
mod convert;
mod demo;
pub mod inspect;
mod job_args;
mod maps_png;
mod pack;
pub mod publish;
mod recover;
mod replay;
mod report_cmd;
pub mod ros2_args;
pub mod sim_cmd;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "asbuilt",
    version,
    about = "Geometric inspection for construction 3D printing"
)]
/// The command line's arguments, checked by clap.
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The whole system on a simulated print cell: an agent, a printing robot with a scanner,
    /// the recording, the rerun view and the report, in out/demo/.
    Demo(Box<demo::DemoArgs>),
    /// Publish a simulated print job (a part printed with defects, scanned by a robot-mounted
    /// scanner) to a running agent.
    Sim(Box<sim_cmd::SimArgs>),
    /// Run the agent in this process, as `asbuilt-agent --config FILE` does.
    Agent {
        /// The agent configuration (TOML); see agent/agent.example.toml.
        #[arg(long, short)]
        config: PathBuf,
    },
    /// Compare scans with the design: signed distances per point, statistics per station.
    Inspect(Box<inspect::InspectArgs>),
    /// Estimate t_design_base or t_flange_scanner from sphere targets with known centres.
    Calibrate(calibrate::CalibrateArgs),
    /// Convert scan files (E57, LAS/LAZ, PTX, PLY, XYZ) into one file of another format.
    Convert(convert::ConvertArgs),
    /// Stream scans with known poses into a running asbuilt-agent, station by station.
    Publish(publish::PublishArgs),
    /// Turn scan files with poses into a recording that replay and report accept.
    Pack(pack::PackArgs),
    /// Play a recording's inputs to a running agent, with the recorded timing or at full speed.
    Replay(replay::ReplayArgs),
    /// Save every complete message of a recording whose writer died.
    Recover(recover::RecoverArgs),
    /// Inspect a recording again: report.json as inspect writes it, and an HTML report.
    Report(report_cmd::ReportArgs),
    /// Convert a Stanford/Scanalyze `.conf` (bmesh lines) into a stations.toml.
    ImportConf {
        /// The .conf file.
        conf: PathBuf,
        /// Where to write stations.toml; scan paths are made relative to its folder.
        #[arg(short, long)]
        out: PathBuf,
    },
}

/// Runs the command `cli` names. Errors say what went wrong and what to do; the exit code is
/// the command's own (an inspection out of tolerance, say).
pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Demo(args) => demo::run(*args),
        Command::Sim(args) => sim_cmd::run(*args),
        Command::Agent { config } => run_agent(&config),
        Command::Inspect(args) => inspect::run(*args),
        Command::Publish(args) => publish::run(args),
        Command::Calibrate(args) => calibrate::run(args),
        Command::Convert(args) => convert::run(args),
        Command::Pack(args) => pack::run(args),
        Command::Replay(args) => replay::run(args),
        Command::Recover(args) => recover::run(args),
        Command::Report(args) => report_cmd::run(args),
        Command::ImportConf { conf, out } => import_conf(&conf, &out).map(|_| ExitCode::SUCCESS),
    }
}

pub use asbuilt_io::error_message;

fn import_conf(conf: &std::path::Path, out: &std::path::Path) -> anyhow::Result<()> {
    let dir = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    std::fs::create_dir_all(dir)?;
    let file = asbuilt_io::stations::from_conf(conf, dir)?;
    let text = format!(
        "# Stations converted from {} by `asbuilt import-conf`.\n\
         # p_design = R(rotation_xyzw) * p_scan + translation (metres); scan paths are relative \
         to this file.\n\n{}",
        conf.display(),
        toml::to_string(&file)?
    );
    std::fs::write(out, text)?;
    eprintln!("wrote {} stations to {}", file.station.len(), out.display());
    Ok(())
}

fn run_agent(config: &std::path::Path) -> anyhow::Result<ExitCode> {
    let config = asbuilt_agent::AgentConfig::load(config)?;
    let summary = asbuilt_agent::daemon::run(&config)?;
    asbuilt_agent::info!(
        "exit: {} stations, {} points",
        summary.stations_reported,
        summary.points_processed
    );
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::error_message;
    use anyhow::Context;

    #[test]
    fn an_error_message_says_each_cause_once() {
        let full = std::io::Error::from_raw_os_error(28);
        let os = full.to_string();
        let write = asbuilt_io::IoError::Write {
            path: "out/deviations.ply".into(),
            source: full,
        };
        let e = Err::<(), _>(write).context("station s1").unwrap_err();
        let m = error_message(e.as_ref());
        assert_eq!(
            m,
            format!("station s1: cannot write out/deviations.ply: {os}")
        );
        assert_eq!(m.matches(&os).count(), 1, "{m}");
        // Causes that add something are all kept, in order.
        let e = anyhow::anyhow!("inner").context("middle").context("outer");
        assert_eq!(error_message(e.as_ref()), "outer: middle: inner");
    }
}
