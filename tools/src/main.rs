//! `asbuilt`: the command line. Thin: the commands are `asbuilt-tools`' library, every
//! computation lives in asbuilt-core.

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    match asbuilt_tools::run(asbuilt_tools::Cli::parse()) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", asbuilt_tools::error_message(e.as_ref()));
            ExitCode::from(2)
        }
    }
}
