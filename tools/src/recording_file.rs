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

/// The files of one job from what a user names: one or more recordings of the same job (in
/// any order), or the agent's recording folder (its newest job, or `job`). Oldest first, as
/// the agent wrote them: a job the agent resumed after a stop, or rotated into parts, spans
/// several files.
pub fn job_files(
    named: &[std::path::PathBuf],
    job: Option<u64>,
) -> Result<Vec<std::path::PathBuf>> {
    use asbuilt_agent::resume::JobFile;
    anyhow::ensure!(
        !named.is_empty(),
        "name a recording, or the agent's recording folder"
    );
    if let [dir] = named
        && dir.is_dir()
    {
        let mut files: Vec<JobFile> = std::fs::read_dir(dir)
            .with_context(|| format!("cannot list {}", dir.display()))?
            .filter_map(|e| e.ok().and_then(|e| JobFile::parse(&e.path())))
            .collect();
        files.sort();
        let Some(newest) = files.last().map(|f| f.job) else {
            anyhow::bail!(
                "{} holds no recording the agent wrote (job-<job>-<seconds>.mcap)",
                dir.display()
            );
        };
        let job = job.unwrap_or(newest);
        let jobs: std::collections::BTreeSet<u64> = files.iter().map(|f| f.job).collect();
        files.retain(|f| f.job == job);
        if files.is_empty() {
            anyhow::bail!(
                "{} holds no recording of job {job}; its jobs: {jobs:?}",
                dir.display()
            );
        }
        if jobs.len() > 1 {
            eprintln!(
                "{} holds jobs {jobs:?}: reading job {job} ({} file(s); --job picks another)",
                dir.display(),
                files.len()
            );
        }
        return Ok(files.into_iter().map(|f| f.path).collect());
    }
    for p in named {
        anyhow::ensure!(
            !p.is_dir(),
            "{} is a folder: name it alone, or name files",
            p.display()
        );
    }
    // Files the agent named sort in writing order; others keep the order given.
    let mut files: Vec<(Option<JobFile>, std::path::PathBuf)> = named
        .iter()
        .map(|p| (JobFile::parse(p), p.clone()))
        .collect();
    if files.iter().all(|(f, _)| f.is_some()) {
        files.sort();
        let jobs: std::collections::BTreeSet<u64> = files
            .iter()
            .filter_map(|(f, _)| f.as_ref().map(|f| f.job))
            .collect();
        anyhow::ensure!(
            jobs.len() == 1,
            "the files hold jobs {jobs:?}: name the files of one job"
        );
    }
    Ok(files.into_iter().map(|(_, p)| p).collect())
}
