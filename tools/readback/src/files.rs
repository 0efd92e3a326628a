//! Opening a recording for the commands that read one (`replay`, `report`, `recover`).

use std::fs::File;
use std::path::{Path, PathBuf};

use crate::ReadBackError;

type Result<T> = std::result::Result<T, ReadBackError>;

fn io(what: &'static str, path: &Path) -> impl FnOnce(std::io::Error) -> ReadBackError {
    let path = path.to_path_buf();
    move |source| ReadBackError::File { what, path, source }
}

/// The file mapped into memory: pages are read as the MCAP reader reaches them, so a large
/// recording is never held whole.
pub fn map(path: &Path) -> Result<memmap2::Mmap> {
    let file = File::open(path).map_err(io("open", path))?;
    // SAFETY: the file is only read; a writer changing it underneath would give wrong bytes,
    // which the MCAP reader rejects as a damaged record rather than misreading.
    unsafe { memmap2::Mmap::map(&file) }.map_err(io("map", path))
}

/// The files of one job from what a user names: one or more recordings of the same job (in
/// any order), or the agent's recording folder (its newest job, or `job`). Oldest first, as
/// the agent wrote them: a job the agent resumed after a stop, or rotated into parts, spans
/// several files.
pub fn job_files(named: &[PathBuf], job: Option<u64>) -> Result<Vec<PathBuf>> {
    use asbuilt_agent::resume::JobFile;
    if named.is_empty() {
        return Err(ReadBackError::NothingNamed);
    }
    if let [dir] = named
        && dir.is_dir()
    {
        let mut files: Vec<JobFile> = std::fs::read_dir(dir)
            .map_err(io("list", dir))?
            .filter_map(|e| e.ok().and_then(|e| JobFile::parse(&e.path())))
            .collect();
        files.sort();
        let Some(newest) = files.last().map(|f| f.job) else {
            return Err(ReadBackError::NoJob(dir.clone()));
        };
        let job = job.unwrap_or(newest);
        let jobs: std::collections::BTreeSet<u64> = files.iter().map(|f| f.job).collect();
        let prints = files.iter().filter(|f| f.job == job && f.part == 1).count();
        let print = asbuilt_agent::resume::newest_print(&files, job);
        if print.is_empty() {
            return Err(ReadBackError::NoSuchJob {
                dir: dir.clone(),
                job,
                jobs,
            });
        }
        if jobs.len() > 1 {
            eprintln!(
                "{} holds jobs {jobs:?}: reading job {job} ({} file(s); --job picks another)",
                dir.display(),
                print.len()
            );
        }
        if prints > 1 {
            eprintln!(
                "{} holds {prints} prints of job {job}: reading the newest, from {} (name an \
                 earlier one's files to read it)",
                dir.display(),
                print[0].path.display()
            );
        }
        return Ok(print.into_iter().map(|f| f.path.clone()).collect());
    }
    if let Some(dir) = named.iter().find(|p| p.is_dir()) {
        return Err(ReadBackError::FolderAmongFiles(dir.clone()));
    }
    // Files the agent named sort in writing order; others keep the order given.
    let mut files: Vec<(Option<JobFile>, PathBuf)> = named
        .iter()
        .map(|p| (JobFile::parse(p), p.clone()))
        .collect();
    if files.iter().all(|(f, _)| f.is_some()) {
        files.sort();
        let jobs: std::collections::BTreeSet<u64> = files
            .iter()
            .filter_map(|(f, _)| f.as_ref().map(|f| f.job))
            .collect();
        if jobs.len() != 1 {
            return Err(ReadBackError::ManyJobs(jobs));
        }
    }
    Ok(files.into_iter().map(|(_, p)| p).collect())
}
