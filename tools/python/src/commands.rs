//! `asbuilt.run` and the commands over it: the command line's own code, in this process.

use std::process::ExitCode;

use clap::Parser;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::anyhow_err;

/// Runs an `asbuilt` command, `args` as on the command line without the program name
/// (`["inspect", "--design", "part.stl", ...]`). Returns the command's exit code (0 when every
/// station is within its limits, 1 when not); raises ValueError for arguments the command
/// refuses (with its usage) and RuntimeError when the command fails.
#[pyfunction]
pub fn run(py: Python<'_>, args: Vec<String>) -> PyResult<u8> {
    let argv = std::iter::once("asbuilt".to_string()).chain(args);
    let cli = match asbuilt_tools::Cli::try_parse_from(argv) {
        Ok(cli) => cli,
        // --help and --version are answers, not errors.
        Err(e) if !e.use_stderr() => {
            print!("{}", e.render());
            return Ok(0);
        }
        Err(e) => return Err(PyValueError::new_err(e.render().to_string())),
    };
    let code = py.detach(|| asbuilt_tools::run(cli)).map_err(anyhow_err)?;
    Ok(exit_code(code))
}

/// ExitCode keeps its value private; the commands return these.
fn exit_code(code: ExitCode) -> u8 {
    [0u8, 1, 2]
        .into_iter()
        .find(|&c| ExitCode::from(c) == code)
        .unwrap_or(2)
}
