//! `asbuilt-agent`: the daemon next to the robot controller.

use std::path::PathBuf;
use std::process::ExitCode;

use asbuilt_agent::{AgentConfig, daemon, error, info};
use clap::Parser;

#[derive(Parser)]
#[command(
    name = "asbuilt-agent",
    version,
    about = "Streams deviations of scan chunks from the design, per station, over iceoryx2",
    after_help = "A commented configuration: agent/agent.example.toml. Stop with SIGINT or \
                  SIGTERM: open stations get partial reports before the agent exits."
)]
struct Cli {
    /// The agent configuration (TOML).
    #[arg(long, short)]
    config: PathBuf,
    /// Validate the configuration, print what would run, and exit.
    #[arg(long)]
    check_config: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let config = match AgentConfig::load(&cli.config) {
        Ok(c) => c,
        Err(e) => {
            error!("{}", asbuilt_io::error_message(&e));
            return ExitCode::from(2);
        }
    };
    if cli.check_config {
        println!(
            "{}: valid\n  design {} ({})\n  methods {}; tolerance {} m, max distance {} m\n  \
             services under {}/\n  chunks up to {} points, station timeout {} s",
            cli.config.display(),
            config.design.path.display(),
            config.design.units,
            config.inspect.methods.join(", "),
            config.inspect.tolerance,
            config.inspect.max_distance(),
            config.services.prefix,
            config.limits.max_points_per_chunk,
            config.limits.station_timeout_s
        );
        return ExitCode::SUCCESS;
    }
    match daemon::run(&config) {
        Ok(summary) => {
            info!(
                "exit: {} stations, {} points",
                summary.stations_reported, summary.points_processed
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            error!("{}", asbuilt_io::error_message(&e));
            ExitCode::from(1)
        }
    }
}
