//! `asbuilt recover`: every complete message of a recording whose writer died, into a valid
//! file.

use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::Args;

#[derive(Args)]
pub struct RecoverArgs {
    /// The damaged recording (no summary, a truncated chunk).
    broken: PathBuf,
    /// Where to write what could be saved.
    fixed: PathBuf,
}

pub fn run(args: RecoverArgs) -> Result<ExitCode> {
    if args.broken == args.fixed {
        bail!(
            "write the recovered file elsewhere: {} is the input",
            args.fixed.display()
        );
    }
    let bytes = asbuilt_readback::files::map(&args.broken)?;
    let out = File::create(&args.fixed)
        .with_context(|| format!("cannot write {}", args.fixed.display()))?;
    let (_, counts) = asbuilt_protocol::recording::recover(&bytes, BufWriter::new(out))
        .map_err(|e| anyhow::anyhow!("cannot recover {}: {e}", args.broken.display()))?;
    println!(
        "saved {} messages, {} metadata records and {} attachments into {}{}",
        counts.messages,
        counts.metadata,
        counts.attachments,
        args.fixed.display(),
        if counts.truncated {
            "; the file ended inside a record (its writer died): everything after was lost"
        } else {
            ""
        }
    );
    if counts.skipped > 0 {
        println!(
            "{} messages whose channel was not in the file (its record was lost) were left out",
            counts.skipped
        );
    }
    Ok(ExitCode::SUCCESS)
}
