//! Handing jobs to idle workers, and settling each job: a final report is appended to the ledger (durably, before
//! anything else learns of it); a lost job is re-queued until it has failed `max_attempts` times.

use std::time::{Duration, Instant};

use dynforge_ipc::{IpcError, JobReport, JobRequest};
use dynforge_proto::job::Job;
use dynforge_proto::run_dir::SHARDS;

use super::{GenerateError, Observer, Run};
use crate::ledger::{Entry, Status};
use crate::plan;

impl Run<'_> {
    /// Sends a job to every idle, ready worker (none once interrupted).
    pub(super) fn dispatch(&mut self) -> Result<(), GenerateError> {
        if self.interrupted {
            return Ok(());
        }
        for k in 0..self.running.len() {
            if self.running[k].is_none() && self.ipc.worker_ready(k) {
                let Some(job) = self.pending.pop_front() else { break };
                let request = JobRequest { job_id: plan::job_id(&job, self.cfg.trajectories), job };
                self.ipc.send(k, &request)?;
                self.running[k] = Some((job, Instant::now()));
                self.starts[k] = super::Start::ready();
            }
        }
        Ok(())
    }

    /// Waits up to 100 ms for reports and settles the final ones. A signal stops dispatching and abandons the jobs
    /// in flight (their shards are written atomically or not at all).
    pub(super) fn receive(&mut self, observer: &mut dyn Observer) -> Result<(), GenerateError> {
        let reports = match self.ipc.wait(Duration::from_millis(100)) {
            Ok(r) => r,
            Err(IpcError::Interrupted) => {
                observer.message(
                    "interrupted: stopping; jobs in flight are abandoned (their shards are written atomically or not at all)",
                );
                self.interrupted = true;
                for k in 0..self.running.len() {
                    self.procs.kill(k);
                    self.running[k] = None;
                }
                return Ok(());
            }
            Err(e) => return Err(e.into()),
        };
        for (k, report) in reports {
            let Some((job, _)) = self.running[k] else { continue };
            let (status, why) = match report {
                JobReport::Progress { .. } => continue,
                JobReport::Done { samples, content_hash, .. } => {
                    (Some(Status::Done { samples, shard_hash: content_hash }), String::new())
                }
                JobReport::Discarded { reason, .. } => (Some(Status::Discarded { reason }), String::new()),
                JobReport::Failed { message, .. } => (None, format!("worker error: {message}")),
            };
            self.running[k] = None;
            self.settle(job, status, &why, observer)?;
        }
        Ok(())
    }

    /// Records a final outcome durably, or (`status` None: the job was lost, `why`) re-queues the job if it may be
    /// retried, else records it failed.
    pub(super) fn settle(
        &mut self,
        job: Job,
        status: Option<Status>,
        why: &str,
        observer: &mut dyn Observer,
    ) -> Result<(), GenerateError> {
        let id = plan::job_id(&job, self.cfg.trajectories);
        let status = match status {
            Some(s) => s,
            None => {
                let n = self.attempts.entry(id).or_default();
                *n += 1;
                if *n < self.cfg.max_attempts {
                    observer.message(&format!(
                        "robot {} trajectory {}: {why}; retrying (attempt {})",
                        job.robot,
                        job.trajectory,
                        *n + 1
                    ));
                    self.pending.push_front(job);
                    return Ok(());
                }
                Status::Failed { message: format!("{why} ({} attempts)", *n) }
            }
        };
        self.progress.record(&status);
        if let Status::Failed { message } = &status {
            observer.message(&format!("robot {} trajectory {} failed: {message}", job.robot, job.trajectory));
            // A worker killed as hung may still have finished its shard: a failed job keeps no shard.
            let shard = self.cfg.dir.join(SHARDS).join(job.shard_name(self.cfg.sim.engine.name()));
            match std::fs::remove_file(&shard) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(source) => return Err(GenerateError::Dir { dir: shard.display().to_string(), source }),
            }
        }
        self.ledger.append(&Entry { job_id: id, robot: job.robot, trajectory: job.trajectory, status })?;
        Ok(())
    }
}
