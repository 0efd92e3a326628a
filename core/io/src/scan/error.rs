//! What a scan reader or writer says went wrong, typed: the file's content, a library or the
//! system beneath it, or the caller's sink. Readers build these with [`bail!`] and
//! [`Context`]; [`crate::IoError::Scan`] puts the file's path on them.

use std::fmt::Display;

/// An error of the code a reader hands its points to ([`super::Sink`]) or takes them from
/// ([`super::write::Feed`]): it ends the read or write and comes back as its cause.
pub type SinkError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// A scan reader's or writer's result.
pub type Result<T, E = ScanError> = std::result::Result<T, E>;

/// Why a scan file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    /// The content is not what the format says (a bad header, a truncated scan, no valid
    /// point); the message says where.
    #[error("{0}")]
    Content(String),
    /// A library beneath the reader (e57, las, ply) or the system failed at `what`.
    #[error("{what}")]
    Beneath {
        /// What was being done, naming the file.
        what: String,
        /// The library's or the system's error.
        #[source]
        source: SinkError,
    },
    /// The caller's sink or feed failed, which ended the read or write.
    #[error(transparent)]
    Sink(SinkError),
    /// The system failed reading or writing the file.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// A library beneath said what is wrong in its own words (las, e57, a file the writer
    /// opens).
    #[error(transparent)]
    Library(SinkError),
}

/// Errors of the libraries beneath, in their own words.
macro_rules! library_errors {
    ($($t:ty),*) => {$(
        impl From<$t> for ScanError {
            fn from(e: $t) -> Self {
                ScanError::Library(Box::new(e))
            }
        }
    )*};
}
library_errors!(
    las::Error,
    e57::Error,
    std::array::TryFromSliceError,
    crate::IoError
);

impl From<SinkError> for ScanError {
    fn from(e: SinkError) -> Self {
        ScanError::Sink(e)
    }
}

/// Returns a [`ScanError::Content`] made like `format!`.
macro_rules! bail {
    ($($arg:tt)*) => {
        return Err($crate::scan::error::ScanError::Content(format!($($arg)*)))
    };
}
pub(crate) use bail;

/// Says what was being done when an `Option` came back empty or a library failed.
pub(crate) trait Context<T> {
    /// The error, if any, with `what`.
    fn context(self, what: impl Display) -> Result<T>;
    /// The error, if any, with what `what` makes (only made on an error).
    fn with_context<D: Display>(self, what: impl FnOnce() -> D) -> Result<T>;
}

impl<T> Context<T> for Option<T> {
    fn context(self, what: impl Display) -> Result<T> {
        self.ok_or_else(|| ScanError::Content(what.to_string()))
    }
    fn with_context<D: Display>(self, what: impl FnOnce() -> D) -> Result<T> {
        self.ok_or_else(|| ScanError::Content(what().to_string()))
    }
}

impl<T, E: Into<SinkError>> Context<T> for std::result::Result<T, E> {
    fn context(self, what: impl Display) -> Result<T> {
        self.map_err(|e| ScanError::Beneath {
            what: what.to_string(),
            source: e.into(),
        })
    }
    fn with_context<D: Display>(self, what: impl FnOnce() -> D) -> Result<T> {
        self.map_err(|e| ScanError::Beneath {
            what: what().to_string(),
            source: e.into(),
        })
    }
}
