//! Why a recording cannot be read back; each case names the file and says what to do.

use std::collections::BTreeSet;
use std::path::PathBuf;

use asbuilt_protocol::recording::ReadError;

/// A recording that cannot be read back.
#[derive(Debug, thiserror::Error)]
pub enum ReadBackError {
    /// Nothing was named.
    #[error("name a recording, or the agent's recording folder")]
    NothingNamed,
    /// A file cannot be opened or mapped.
    #[error("cannot {what} {}", path.display())]
    File {
        /// `open`, `map` or `list`.
        what: &'static str,
        /// The file or folder.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// A file is not a readable recording.
    #[error("{}: {source}. If its writer died, `asbuilt recover` saves what it can", path.display())]
    Unreadable {
        /// The file.
        path: PathBuf,
        /// What the reader said.
        #[source]
        source: ReadError,
    },
    /// A folder holds no file the agent wrote.
    #[error("{} holds no recording the agent wrote (job-<job>-<seconds>.mcap)", .0.display())]
    NoJob(PathBuf),
    /// A folder holds no file of the job asked for.
    #[error("{} holds no recording of job {job}; its jobs: {jobs:?}", dir.display())]
    NoSuchJob {
        /// The folder.
        dir: PathBuf,
        /// The job asked for.
        job: u64,
        /// The jobs it holds.
        jobs: BTreeSet<u64>,
    },
    /// A folder named among files.
    #[error("{} is a folder: name it alone, or name files", .0.display())]
    FolderAmongFiles(PathBuf),
    /// Files of several jobs named together.
    #[error("the files hold jobs {0:?}: name the files of one job")]
    ManyJobs(BTreeSet<u64>),
    /// A file asbuilt did not write.
    #[error("{} has no asbuilt.job metadata: it was not written by asbuilt", .0.display())]
    NotAsbuilt(PathBuf),
    /// A recording without its design.
    #[error("{} carries no design attachment", .0.display())]
    NoDesign(PathBuf),
    /// The recorded design's units are not `m` or `mm`.
    #[error("the recording's design units: {0}")]
    Units(String),
    /// The recorded design cannot be read.
    #[error("the design recorded in {}", path.display())]
    Design {
        /// The recording.
        path: PathBuf,
        /// The design reader's error.
        #[source]
        source: asbuilt_io::IoError,
    },
    /// The recorded design cannot be indexed.
    #[error("the recorded design cannot be indexed")]
    Index(#[from] asbuilt_core::c2m::C2mError),
    /// The recorded configuration has problems.
    #[error("the recording's configuration: {}", .0.join("; "))]
    Config(Vec<String>),
    /// The verdicts' limits cannot be made from `[tolerances]` and `--limit`.
    #[error("the verdicts' limits ([tolerances], --limit): {0}")]
    Limits(String),
    /// The recorded `[tolerances]` name something this build does not know.
    #[error("the recording's [tolerances]: {0}")]
    Tolerances(String),
    /// The tolerance or maximum distance is not a positive length.
    #[error("--tolerance and --max-distance must be positive metres")]
    NotPositive,
    /// A later file of the job was recorded against another design.
    #[error(
        "{} was recorded against another design (sha256 {found}) than {} ({expected}): the \
         files are not one job",
        file.display(),
        first.display()
    )]
    OtherDesign {
        /// The later file.
        file: PathBuf,
        /// Its design's hash.
        found: String,
        /// The first file.
        first: PathBuf,
        /// The first file's design's hash.
        expected: String,
    },
    /// A recording without a station.
    #[error("{} holds no station", .0.display())]
    NoStation(PathBuf),
}

impl ReadBackError {
    /// `path` is not a readable recording: `e` says why.
    pub fn unreadable(path: &std::path::Path, e: ReadError) -> Self {
        Self::Unreadable {
            path: path.to_path_buf(),
            source: e,
        }
    }
}
