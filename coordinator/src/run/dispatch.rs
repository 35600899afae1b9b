//! Handing jobs to idle workers, and settling each job: a final report is appended to the ledger (durably, before
//! anything else learns of it); a lost job is re-queued until it has failed `max_attempts` times.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use dynforge_ipc::IpcError;

use dynforge_proto::job::Job;
use dynforge_proto::job::{JobReport, JobRequest};
use dynforge_proto::run_dir::SHARDS;

use super::{GenerateError, Observer, Queue, Run};
use crate::plan;
use dynforge_proto::ledger::{Entry, Status};

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
            None => match requeue_or_fail(&mut self.attempts, &mut self.pending, job, id, self.cfg.max_attempts, why) {
                Ok(attempt) => {
                    observer.message(&format!(
                        "robot {} trajectory {}: {why}; retrying (attempt {attempt})",
                        job.robot, job.trajectory
                    ));
                    return Ok(());
                }
                Err(failed) => failed,
            },
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

/// Counts one loss of the job `job` (id `id`, lost because `why`) in `attempts`, and puts it back at the front of
/// `pending` unless it has now been lost `max_attempts` times: `Ok` with the attempt it goes on to, else `Err` with the
/// failure to record.
fn requeue_or_fail(
    attempts: &mut HashMap<u64, u32>,
    pending: &mut Queue,
    job: Job,
    id: u64,
    max_attempts: u32,
    why: &str,
) -> Result<u32, Status> {
    let n = attempts.entry(id).or_default();
    *n += 1;
    if *n < max_attempts {
        pending.push_front(job);
        return Ok(*n + 1);
    }
    Err(Status::Failed { message: format!("{why} ({} attempts)", *n) })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::{BTreeMap, VecDeque};

    const TRAJECTORIES: u32 = 4;

    fn queue(planned: Vec<Job>) -> Queue {
        let planned: Box<dyn Iterator<Item = Job>> = Box::new(planned.into_iter());
        Queue { retries: VecDeque::new(), planned: planned.peekable() }
    }

    fn jobs(robots: u64) -> Vec<Job> {
        plan::jobs(3, robots, TRAJECTORIES, dynforge_proto::manifest::Partition::WHOLE).collect()
    }

    fn id(job: &Job) -> u64 {
        plan::job_id(job, TRAJECTORIES)
    }

    #[test]
    fn a_dead_worker_s_job_is_queued_again_once_and_handed_out_next() {
        let planned = jobs(1);
        let mut pending = queue(planned.clone());
        let mut attempts = HashMap::new();
        let taken = pending.pop_front().unwrap();
        let retry = requeue_or_fail(&mut attempts, &mut pending, taken, id(&taken), 3, "its worker died");
        assert_eq!(retry, Ok(2), "it goes on to its second attempt");
        let mut handed = Vec::new();
        while let Some(j) = pending.pop_front() {
            handed.push(j);
        }
        assert_eq!(handed[0], taken, "the lost job is handed out before new ones");
        assert_eq!(handed, planned, "it is queued once, and no other job is lost or repeated");
    }

    #[test]
    fn a_job_lost_max_attempts_times_is_recorded_failed_and_not_queued_again() {
        let planned = jobs(1);
        let (first, second) = (planned[0], planned[1]);
        let mut pending = queue(planned.clone());
        let mut attempts = HashMap::new();
        let max = 3;
        for attempt in 1..=max {
            let taken = pending.pop_front().unwrap();
            assert_eq!(taken, first, "attempt {attempt} runs the lost job again");
            let outcome = requeue_or_fail(&mut attempts, &mut pending, taken, id(&taken), max, "its worker hung");
            if attempt < max {
                assert_eq!(outcome, Ok(attempt + 1));
            } else {
                let Err(Status::Failed { message }) = outcome else { panic!("{outcome:?}: not recorded failed") };
                assert!(message.contains("its worker hung"), "{message}");
                assert!(message.contains(&max.to_string()), "{message} names the attempts");
            }
        }
        assert_eq!(pending.pop_front(), Some(second), "the failed job is not queued again");
        // Attempts are counted per job: another job's first loss is retried.
        assert_eq!(requeue_or_fail(&mut attempts, &mut pending, second, id(&second), max, "x"), Ok(2));
        // With a single attempt allowed, the first loss is final.
        let mut none = HashMap::new();
        assert!(matches!(
            requeue_or_fail(&mut none, &mut pending, first, id(&first), 1, "x"),
            Err(Status::Failed { .. })
        ));
    }

    /// The ledger's exactly-once record rests on this: whatever workers die, every planned job is settled once
    /// (done or failed), and a job runs again only after it was lost.
    #[test]
    fn every_job_is_settled_exactly_once_however_often_workers_die() {
        let max = 3;
        // How often each job's worker dies under it before it is done: 0, 1, 2, or every time (it fails).
        let deaths = |j: &Job| match id(j) % 4 {
            3 => u32::MAX,
            n => n as u32,
        };
        let planned = jobs(5);
        let mut pending = queue(planned.clone());
        let mut attempts = HashMap::new();
        let mut slots: Vec<Option<Job>> = vec![None; 3];
        let mut runs: BTreeMap<Job, u32> = BTreeMap::new();
        let mut settled: Vec<(Job, Status)> = Vec::new();
        loop {
            for slot in slots.iter_mut().filter(|s| s.is_none()) {
                *slot = pending.pop_front();
                if let Some(j) = slot {
                    *runs.entry(*j).or_default() += 1;
                }
            }
            if slots.iter().all(Option::is_none) {
                break;
            }
            for slot in &mut slots {
                let Some(j) = slot.take() else { continue };
                if runs[&j] <= deaths(&j) {
                    if let Err(failed) = requeue_or_fail(&mut attempts, &mut pending, j, id(&j), max, "its worker died")
                    {
                        settled.push((j, failed));
                    }
                } else {
                    settled.push((j, Status::Done { samples: 1, shard_hash: 0 }));
                }
            }
        }
        let mut settled_jobs: Vec<Job> = settled.iter().map(|(j, _)| *j).collect();
        settled_jobs.sort();
        let mut want = planned.clone();
        want.sort();
        assert_eq!(settled_jobs, want, "every job settled, none twice");
        for (j, status) in &settled {
            let (d, ran) = (deaths(j), runs[j]);
            match status {
                Status::Failed { .. } => assert!(d >= max && ran == max, "{j:?} failed after {ran} runs"),
                _ => assert!(d < max && ran == d + 1, "{j:?} done after {ran} runs, {d} deaths"),
            }
        }
        assert!(settled.iter().any(|(_, s)| matches!(s, Status::Failed { .. })), "the script has failures");
    }
}
