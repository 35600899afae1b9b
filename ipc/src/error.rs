use thiserror::Error;

/// Errors of the transport. iceoryx2's own errors are kept as the source, with what was being done.
#[derive(Debug, Error)]
pub enum IpcError {
    #[error("invalid run id {0:?}: use 1-24 characters of [A-Za-z0-9_-]")]
    InvalidRunId(String),
    #[error("worker slot {slot} is out of range (the coordinator has {max_workers} slots)")]
    SlotOutOfRange { slot: usize, max_workers: usize },
    #[error("worker slot {0} is not attached (call attach_worker first)")]
    NotAttached(usize),
    #[error("worker slot {0} has no worker ready to receive (its server is not open yet, or it died)")]
    WorkerNotReady(usize),
    #[error("worker slot {slot} already runs job {job_id} (one job in flight per worker)")]
    Busy { slot: usize, job_id: u64 },
    /// `pid` is unknown when two coordinators started at the same moment (both give up).
    #[error(
        "another coordinator {} is running for this run directory",
        .pid.map_or("(started at the same moment)".to_string(), |p| format!("(pid {p})"))
    )]
    CoordinatorAlreadyRunning { pid: Option<i32> },
    #[error("no coordinator is running for this run id")]
    CoordinatorNotRunning,
    #[error("worker slot {slot} is still held by another worker process after {waited_ms} ms")]
    SlotTaken { slot: usize, waited_ms: u64 },
    #[error("no job is active (report() needs a job from next_job())")]
    NoActiveJob,
    #[error("report for job {got} while job {active} is active")]
    WrongJob { active: u64, got: u64 },
    #[error("the coordinator no longer waits for job {0} (it gave the job up or restarted)")]
    JobAbandoned(u64),
    #[error("interrupted by SIGINT or SIGTERM")]
    Interrupted,
    #[error("{what}: {source}")]
    Iceoryx {
        what: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync + 'static>,
    },
    #[error("{what}: {source}")]
    Io {
        what: String,
        #[source]
        source: std::io::Error,
    },
}

/// Attaches a description to an iceoryx2 error.
pub(crate) trait Context<T> {
    fn ctx(self, what: impl FnOnce() -> String) -> Result<T, IpcError>;
}

impl<T, E: std::error::Error + Send + Sync + 'static> Context<T> for Result<T, E> {
    fn ctx(self, what: impl FnOnce() -> String) -> Result<T, IpcError> {
        self.map_err(|e| IpcError::Iceoryx { what: what(), source: Box::new(e) })
    }
}
