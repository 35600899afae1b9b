//! What a job is, and the messages between the coordinator and its workers: a request for a job, and how a worker
//! answers it. The transport (`dynforge-ipc`) carries them in fixed-size wire forms of its own.

/// One unit of work: trajectory `trajectory` of robot `robot` of the dataset of seed `seed`. Everything else a job
/// needs (generator and simulation settings) is in the run directory's manifest.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Job {
    pub seed: u64,
    pub robot: u64,
    pub trajectory: u32,
}

impl Job {
    /// The shard file name of this job when simulated by `engine`: derived from the job alone, so re-running a job
    /// rewrites the same file.
    pub fn shard_name(&self, engine: &str) -> String {
        crate::shard::file_name(self.robot, self.trajectory, engine)
    }
}

/// Run `job`. `job_id` is the coordinator's identifier, echoed in every [`JobReport`]; the worker reads the run's
/// manifest once.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct JobRequest {
    pub job_id: u64,
    pub job: Job,
}

/// What a worker answers to one [`JobRequest`]: any number of `Progress`, then exactly one final report (`Done`,
/// `Discarded` or `Failed`). The coordinator never delivers anything for a job after its final report.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum JobReport {
    /// Still working; `permille` of the job done.
    Progress { job_id: u64, permille: u32 },
    /// Shard written.
    Done { job_id: u64, samples: u64, content_hash: u64 },
    /// The simulation was discarded (a reason code such as "timeout", "collision"); no shard.
    Discarded { job_id: u64, reason: String },
    /// Worker-side error (I/O and the like). The coordinator also makes one up when a live worker drops a job
    /// without a final report.
    Failed { job_id: u64, message: String },
}

/// Bytes of a reason or message that cross the process boundary: room for a path and an OS error. Longer text
/// loses its middle (the ipc crate's `FixedStr`), keeping what failed on which file and the cause at the end.
pub const MESSAGE_CAPACITY: usize = 512;

impl JobReport {
    /// The job this report belongs to.
    pub fn job_id(&self) -> u64 {
        match *self {
            JobReport::Progress { job_id, .. }
            | JobReport::Done { job_id, .. }
            | JobReport::Discarded { job_id, .. }
            | JobReport::Failed { job_id, .. } => job_id,
        }
    }

    /// Whether this is the job's last report (everything but `Progress`).
    pub fn is_final(&self) -> bool {
        !matches!(self, JobReport::Progress { .. })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_helpers() {
        let p = JobReport::Progress { job_id: 3, permille: 10 };
        let d = JobReport::Discarded { job_id: 4, reason: "collision".into() };
        assert_eq!((p.job_id(), p.is_final()), (3, false));
        assert_eq!((d.job_id(), d.is_final()), (4, true));
    }
}
