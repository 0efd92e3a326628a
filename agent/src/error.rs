//! Why the agent cannot start or keep serving.

/// Why the agent cannot start or keep serving.
#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    /// The design file named in `[design]` could not be loaded.
    #[error(transparent)]
    Design(#[from] asbuilt_io::IoError),
    /// The design loaded but cannot be indexed (its extent, the maximum distance).
    #[error("indexing the design: {0}")]
    Index(#[from] asbuilt_core::c2m::C2mError),
    /// The recorder's folder cannot be made or written.
    #[error("cannot start the recorder in {dir}: {source}")]
    Recorder {
        /// The folder.
        dir: std::path::PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// The rerun view cannot start.
    #[error(transparent)]
    Viewer(#[from] asbuilt_viewer::ViewerError),
    /// The cell's services: a node, a port or the wait set could not be made.
    #[error(transparent)]
    Ipc(#[from] asbuilt_protocol::ipc::IpcError),
}
