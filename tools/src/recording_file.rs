//! Opening a recording for the commands that read one (`replay`, `report`, `recover`).

use std::fs::File;
use std::path::Path;

use anyhow::{Context, Result};
use asbuilt_protocol::recording::ReadError;

/// The file mapped into memory: pages are read as the MCAP reader reaches them, so a large
/// recording is never held whole.
pub fn map(path: &Path) -> Result<memmap2::Mmap> {
    let file = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    // SAFETY: the file is only read; a writer changing it underneath would give wrong bytes,
    // which the MCAP reader rejects as a damaged record rather than misreading.
    unsafe { memmap2::Mmap::map(&file) }.with_context(|| format!("cannot map {}", path.display()))
}

/// A read error, with what to do about a file whose writer died.
pub fn unreadable(path: &Path, e: ReadError) -> anyhow::Error {
    anyhow::anyhow!(
        "{}: {e}. If its writer died, `asbuilt recover` saves what it can",
        path.display()
    )
}
