//! One error for every file: which file, what kind of failure, and the cause beneath it.

use std::path::PathBuf;

/// What went wrong reading or writing a file. The message names the file; the source (an I/O
/// error, a parser's error) stays attached for callers that walk the chain.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The file is not there.
    #[error("cannot open {kind} file {path}: it does not exist; check the path")]
    NotFound {
        /// The file as given.
        path: PathBuf,
        /// "scan" or "design".
        kind: &'static str,
    },
    /// The file is there but cannot be opened (permissions, a directory...).
    #[error("cannot open {path}: {source}")]
    Open {
        /// The file as given.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// The extension names no format asbuilt reads.
    #[error("{path}: unknown {kind} format .{extension}: use {expected}")]
    UnknownFormat {
        /// The file as given.
        path: PathBuf,
        /// "scan" or "design".
        kind: &'static str,
        /// The extension, without the dot.
        extension: String,
        /// The formats that would be read, as a user types them.
        expected: &'static str,
    },
    /// The file is there but its content is not what its format says: `what` names the line,
    /// record or element where that is known.
    #[error("cannot read {path} as {format}: {what}")]
    Malformed {
        /// The file as given.
        path: PathBuf,
        /// The format the file was read as.
        format: &'static str,
        /// What is wrong, and where.
        what: String,
    },
    /// The file cannot be written.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The file as given.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// The design holds no triangle with an area.
    #[error(
        "design file {path} has no usable triangles (empty, or every triangle degenerate): \
         export the surface as a triangle mesh"
    )]
    EmptyDesign {
        /// The file as given.
        path: PathBuf,
    },
    /// A scan reader or writer failed; its message says where in the file. The reader's
    /// chain of causes is kept whole in `cause` and written out in the message, so it is not
    /// also offered as `source()` (a caller printing the chain would print it twice).
    #[error("{}", scan_message(path, cause))]
    Scan {
        /// The file as given.
        path: PathBuf,
        /// The reader's error with its causes.
        cause: crate::scan::ScanError,
    },
}

impl IoError {
    /// Nothing when `path` is a file; otherwise that the `kind` of file ("scan", "design",
    /// "stations"...) is not there, which every reader says before it opens anything.
    pub(crate) fn require_file(path: &std::path::Path, kind: &'static str) -> Result<(), IoError> {
        if path.is_file() {
            return Ok(());
        }
        Err(IoError::NotFound {
            path: path.to_path_buf(),
            kind,
        })
    }

    /// The file the error is about.
    pub fn path(&self) -> &std::path::Path {
        match self {
            IoError::NotFound { path, .. }
            | IoError::Open { path, .. }
            | IoError::Write { path, .. }
            | IoError::UnknownFormat { path, .. }
            | IoError::Malformed { path, .. }
            | IoError::EmptyDesign { path }
            | IoError::Scan { path, .. } => path,
        }
    }
}

/// A scan reader's message mostly names the file already; those of the libraries beneath it
/// (a UTF-8 or I/O error) get the path in front.
fn scan_message(path: &std::path::Path, e: &crate::scan::ScanError) -> String {
    let message = crate::error_message(e);
    if message.contains(&path.display().to_string()) {
        message
    } else {
        format!("cannot read {}: {message}", path.display())
    }
}

/// What to tell the user of `e`: the error and its causes joined by `: `, each said once. Many
/// errors already end their own message with their cause (`cannot write F: No space left on
/// device`), and the chain then repeats it; a cause the message so far ends with is left out.
pub fn error_message(e: &(dyn std::error::Error + 'static)) -> String {
    let mut message = String::new();
    let mut cause = Some(e);
    while let Some(c) = cause {
        cause = c.source();
        let text = c.to_string();
        if message.ends_with(&text) {
            continue;
        }
        if !message.is_empty() {
            message.push_str(": ");
        }
        message.push_str(&text);
    }
    message
}
