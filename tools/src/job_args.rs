//! The job a command's stations go out as (`publish`, `pack`): its number, and when it started.

use asbuilt_protocol::unix_time_ns;
use clap::Args;

/// A job as the cell names it in every Begin.
#[derive(Args, Debug, Clone)]
pub struct JobIdentity {
    /// Job number carried by every message.
    #[arg(long = "job", default_value_t = 1)]
    pub number: u64,
    /// When the job started (ns since the Unix epoch), which tells this print from another of
    /// the same number. Default: now; give the first run's to send more of the same job.
    #[arg(long, value_name = "NS")]
    pub job_started_ns: Option<u64>,
}

impl JobIdentity {
    /// When the job started: as given, else now.
    pub fn started_ns(&self) -> u64 {
        self.job_started_ns.unwrap_or_else(unix_time_ns)
    }
}
