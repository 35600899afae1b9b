//! `generate`: the coordinator's main loop. Plans the jobs not yet in the ledger, spawns the worker processes,
//! dispatches jobs over iceoryx2, records every final report durably, and replaces dead or hung workers.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use dynforge_ipc::{Coordinator, IpcError, JobReport, JobRequest, RunId, StatusMsg};
use dynforge_robot::generator::GeneratorConfig;
use dynforge_worker::job::{Job, shard_name};
use dynforge_worker::simulate::SimConfig;

use crate::ledger::{Entry, Ledger, LedgerError, Status};
use crate::manifest::{Manifest, ManifestError};
use crate::plan::{self, Partition};
use dynforge_proto::run_dir::{LEDGER, LOGS, SHARDS, is_temporary};

/// Everything `generate` needs.
#[derive(Debug, Clone)]
pub struct GenerateConfig {
    pub dir: PathBuf,
    pub seed: u64,
    pub robots: u64,
    pub trajectories: u32,
    pub workers: usize,
    pub partition: Partition,
    pub generator: GeneratorConfig,
    pub sim: SimConfig,
    /// A job running longer than this marks its worker as hung: it is killed and replaced.
    pub job_timeout: Duration,
    /// A job whose worker died (or failed) this many times is recorded as failed.
    pub max_attempts: u32,
    /// Program and leading arguments that start a worker; `--dir DIR --slot K` are appended.
    pub worker_command: Vec<OsString>,
}

/// How the run is going, for progress displays.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Progress {
    /// Jobs of this run (after the partition), including those finished in earlier runs.
    pub total: u64,
    /// Finished before this invocation (resumed).
    pub resumed: u64,
    pub done: u64,
    pub discarded: u64,
    pub failed: u64,
    pub reasons: BTreeMap<String, u64>,
    pub in_flight: u32,
    pub workers_alive: u32,
    pub respawns: u32,
    /// Finished jobs per second in this invocation.
    pub rate: f64,
    /// Per worker slot: the job it runs, if any.
    pub slots: Vec<Option<Job>>,
}

impl Progress {
    pub fn finished(&self) -> u64 {
        self.done + self.discarded + self.failed
    }

    /// Counts one finished job.
    pub fn record(&mut self, status: &Status) {
        match status {
            Status::Done { .. } => self.done += 1,
            Status::Discarded { reason } => {
                self.discarded += 1;
                *self.reasons.entry(reason.clone()).or_default() += 1;
            }
            Status::Failed { .. } => self.failed += 1,
        }
    }

    /// Counts of a ledger's records (the last record of a job wins) for a run of `total` jobs.
    pub fn from_ledger(total: u64, entries: &[Entry]) -> Progress {
        let latest: HashMap<u64, &Entry> = entries.iter().map(|e| (e.job_id, e)).collect();
        let mut p = Progress { total, ..Progress::default() };
        for e in latest.values() {
            p.record(&e.status);
        }
        p
    }
}

/// Receives progress (a terminal display, logs, tests).
pub trait Observer {
    fn update(&mut self, p: &Progress);
    fn message(&mut self, text: &str);
}

#[derive(Debug, thiserror::Error)]
pub enum GenerateError {
    #[error("{dir}: cannot use as the output directory: {source}")]
    Dir { dir: String, source: std::io::Error },
    #[error("nothing to do: {0}")]
    Empty(String),
    #[error(transparent)]
    Manifest(#[from] ManifestError),
    #[error(transparent)]
    Ledger(#[from] LedgerError),
    #[error(transparent)]
    Ipc(#[from] IpcError),
    #[error("starting worker {slot} ({program}): {source}")]
    Spawn { slot: usize, program: String, source: std::io::Error },
    #[error("interrupted: {finished} of {total} jobs are recorded; run the same command again to resume")]
    Interrupted { finished: u64, total: u64 },
}

/// Removes temporary files that crashed writers left in the shard directory.
fn remove_leftovers(shards: &Path) -> std::io::Result<usize> {
    let mut n = 0;
    for entry in std::fs::read_dir(shards)? {
        let entry = entry?;
        let name = entry.file_name().to_string_lossy().to_string();
        if is_temporary(&name) {
            std::fs::remove_file(entry.path())?;
            n += 1;
        }
    }
    Ok(n)
}

struct Workers {
    command: Vec<OsString>,
    dir: PathBuf,
    children: Vec<Option<Child>>,
}

impl Workers {
    fn spawn(&mut self, slot: usize) -> Result<(), GenerateError> {
        self.kill(slot);
        let logs = self.dir.join(LOGS);
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(logs.join(format!("worker-{slot}.log")))
            .map_err(|source| GenerateError::Dir { dir: logs.display().to_string(), source })?;
        let (program, args) = self.command.split_first().expect("a worker command");
        let child = Command::new(program)
            .args(args)
            .arg("--dir")
            .arg(&self.dir)
            .arg("--slot")
            .arg(slot.to_string())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map_err(|source| GenerateError::Spawn { slot, program: program.to_string_lossy().into(), source })?;
        self.children[slot] = Some(child);
        Ok(())
    }

    fn kill(&mut self, slot: usize) {
        if let Some(mut child) = self.children[slot].take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }

    /// Slots whose process has exited (before or without the coordinator noticing through iceoryx2).
    fn exited(&mut self) -> Vec<usize> {
        let mut out = Vec::new();
        for (k, c) in self.children.iter_mut().enumerate() {
            if let Some(child) = c
                && matches!(child.try_wait(), Ok(Some(_)))
            {
                out.push(k);
            }
        }
        out
    }
}

impl Drop for Workers {
    fn drop(&mut self) {
        for k in 0..self.children.len() {
            self.kill(k);
        }
    }
}

/// Runs (or resumes) a generation. Returns the final progress.
pub fn generate(cfg: &GenerateConfig, observer: &mut dyn Observer) -> Result<Progress, GenerateError> {
    if cfg.robots == 0 || cfg.trajectories == 0 || cfg.workers == 0 {
        return Err(GenerateError::Empty(format!(
            "--robots {}, --trajectories {} and --workers {} must all be at least 1",
            cfg.robots, cfg.trajectories, cfg.workers
        )));
    }
    let dir_err = |source| GenerateError::Dir { dir: cfg.dir.display().to_string(), source };
    std::fs::create_dir_all(cfg.dir.join(SHARDS)).map_err(dir_err)?;
    std::fs::create_dir_all(cfg.dir.join(LOGS)).map_err(dir_err)?;
    let manifest =
        Manifest::new(cfg.seed, cfg.robots, cfg.trajectories, cfg.partition, cfg.generator.clone(), cfg.sim.clone());
    if let Some(before) = manifest.create_or_check(&cfg.dir)? {
        observer.message(&format!("growing the dataset from {before} to {} robots", cfg.robots));
    }
    let (mut ledger, entries) = Ledger::open(&cfg.dir.join(LEDGER))?;
    let removed = remove_leftovers(&cfg.dir.join(SHARDS)).map_err(dir_err)?;
    if removed > 0 {
        observer.message(&format!("removed {removed} partial shard file(s) left by an interrupted run"));
    }

    let finished: HashMap<u64, &Entry> = entries.iter().map(|e| (e.job_id, e)).collect();
    let all: Vec<Job> = plan::jobs(cfg.seed, cfg.robots, cfg.trajectories, cfg.partition).collect();
    let mut progress = Progress { slots: vec![None; cfg.workers], ..Progress::from_ledger(all.len() as u64, &entries) };
    progress.resumed = progress.finished();
    let mut pending: VecDeque<Job> =
        all.into_iter().filter(|j| !finished.contains_key(&plan::job_id(j, cfg.trajectories))).collect();
    if pending.is_empty() {
        observer.update(&progress);
        return Ok(progress);
    }
    let workers = cfg.workers.min(pending.len());
    progress.slots.truncate(workers);

    let run = RunId::for_dir(&cfg.dir)?;
    dynforge_ipc::cleanup_stale(&run)?;
    let mut ipc = Coordinator::new(&run, workers)?;
    let mut procs = Workers {
        command: cfg.worker_command.clone(),
        dir: cfg.dir.clone(),
        children: (0..workers).map(|_| None).collect(),
    };
    for k in 0..workers {
        procs.spawn(k)?;
        ipc.attach_worker(k)?;
    }

    let engine = cfg.sim.engine as u32;
    let mut attempts: HashMap<u64, u32> = HashMap::new();
    let mut running: Vec<Option<(Job, Instant)>> = vec![None; workers];
    let start = Instant::now();
    let mut last_status = Instant::now() - Duration::from_secs(1);
    let mut last_liveness = Instant::now();
    let mut interrupted = false;

    // Records a final outcome durably, or re-queues the job if it may be retried.
    let mut settle = |job: Job,
                      status: Option<Status>,
                      why: &str,
                      progress: &mut Progress,
                      pending: &mut VecDeque<Job>,
                      observer: &mut dyn Observer|
     -> Result<(), GenerateError> {
        let id = plan::job_id(&job, cfg.trajectories);
        let status = match status {
            Some(s) => s,
            None => {
                let n = attempts.entry(id).or_default();
                *n += 1;
                if *n < cfg.max_attempts {
                    observer.message(&format!(
                        "robot {} trajectory {}: {why}; retrying (attempt {})",
                        job.robot,
                        job.trajectory,
                        *n + 1
                    ));
                    pending.push_front(job);
                    return Ok(());
                }
                Status::Failed { message: format!("{why} ({} attempts)", *n) }
            }
        };
        progress.record(&status);
        match &status {
            Status::Done { .. } | Status::Discarded { .. } => {}
            Status::Failed { message } => {
                observer.message(&format!("robot {} trajectory {} failed: {message}", job.robot, job.trajectory));
                // A worker killed as hung may still have finished its shard: a failed job keeps no shard.
                let shard = cfg.dir.join(SHARDS).join(shard_name(&job, cfg.sim.engine.name()));
                match std::fs::remove_file(&shard) {
                    Ok(()) => {}
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                    Err(source) => return Err(GenerateError::Dir { dir: shard.display().to_string(), source }),
                }
            }
        }
        ledger.append(&Entry { job_id: id, robot: job.robot, trajectory: job.trajectory, status })?;
        Ok(())
    };

    loop {
        // Dispatch to idle, ready workers.
        if !interrupted {
            for k in 0..workers {
                if running[k].is_none() && ipc.worker_ready(k) {
                    let Some(job) = pending.pop_front() else { break };
                    let request = JobRequest {
                        job_id: plan::job_id(&job, cfg.trajectories),
                        seed: job.seed,
                        robot: job.robot,
                        trajectory: job.trajectory,
                        engine,
                    };
                    ipc.send(k, &request)?;
                    running[k] = Some((job, Instant::now()));
                }
            }
        }
        let busy = running.iter().filter(|r| r.is_some()).count();
        if busy == 0 && (pending.is_empty() || interrupted) {
            break;
        }

        match ipc.wait(Duration::from_millis(100)) {
            Ok(reports) => {
                for (k, report) in reports {
                    let Some((job, _)) = running[k] else { continue };
                    let status = match report {
                        JobReport::Progress { .. } => continue,
                        JobReport::Done { samples, content_hash, .. } => {
                            Some(Status::Done { samples, shard_hash: content_hash })
                        }
                        JobReport::Discarded { reason, .. } => {
                            Some(Status::Discarded { reason: reason.as_str().to_string() })
                        }
                        JobReport::Failed { message, .. } => {
                            running[k] = None;
                            settle(
                                job,
                                None,
                                &format!("worker error: {}", message.as_str()),
                                &mut progress,
                                &mut pending,
                                observer,
                            )?;
                            continue;
                        }
                    };
                    running[k] = None;
                    settle(job, status, "", &mut progress, &mut pending, observer)?;
                }
            }
            Err(IpcError::Interrupted) => {
                observer.message("interrupted: stopping; jobs in flight are abandoned (their shards are written atomically or not at all)");
                interrupted = true;
                for k in 0..workers {
                    procs.kill(k);
                    running[k] = None;
                }
                continue;
            }
            Err(e) => return Err(e.into()),
        }

        // Liveness: dead processes, hung jobs.
        if last_liveness.elapsed() >= Duration::from_millis(100) {
            last_liveness = Instant::now();
            let mut lost: Vec<(usize, String)> =
                ipc.dead_workers().into_iter().map(|k| (k, "its worker died".to_string())).collect();
            for k in procs.exited() {
                if !lost.iter().any(|(s, _)| *s == k) {
                    lost.push((k, "its worker exited".into()));
                }
            }
            for (k, started) in running.iter().enumerate().filter_map(|(k, r)| r.map(|(_, t)| (k, t))) {
                if started.elapsed() > cfg.job_timeout && !lost.iter().any(|(s, _)| *s == k) {
                    lost.push((k, format!("its worker hung (no result after {} s)", cfg.job_timeout.as_secs_f64())));
                }
            }
            for (k, why) in lost {
                procs.kill(k);
                if let Some((job, _)) = running[k].take() {
                    settle(job, None, &why, &mut progress, &mut pending, observer)?;
                }
                if !interrupted && !pending.is_empty() {
                    progress.respawns += 1;
                    procs.spawn(k)?;
                    ipc.attach_worker(k)?;
                }
            }
        }

        if last_status.elapsed() >= Duration::from_millis(250) {
            last_status = Instant::now();
            let elapsed = start.elapsed().as_secs_f64();
            progress.rate = (progress.finished() - progress.resumed) as f64 / elapsed.max(1e-9);
            progress.in_flight = running.iter().filter(|r| r.is_some()).count() as u32;
            progress.workers_alive = procs.children.iter().filter(|c| c.is_some()).count() as u32;
            progress.slots = running.iter().map(|r| r.map(|(j, _)| j)).collect();
            observer.update(&progress);
            let remaining = progress.total - progress.finished();
            let status = StatusMsg {
                done: progress.done,
                discarded: progress.discarded,
                failed: progress.failed,
                in_flight: progress.in_flight,
                workers_alive: progress.workers_alive,
                total: progress.total,
                rate_per_s: progress.rate,
                updated_unix_ms: std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.as_millis() as u64),
                eta_s: if progress.rate > 0.0 { remaining as f64 / progress.rate } else { 0.0 },
                coordinator_pid: std::process::id(),
                respawns: progress.respawns,
            };
            let _ = ipc.publish_status(&status);
        }
    }
    // Tells the workers to stop, waits for them, and removes the run's shared-memory files.
    let _ = ipc.shutdown(Duration::from_secs(5));
    drop(procs);
    // Workers killed mid-write (dead, hung, interrupted) leave partial temporary files; no writer is left now.
    remove_leftovers(&cfg.dir.join(SHARDS)).map_err(dir_err)?;
    progress.in_flight = 0;
    progress.slots = vec![None; workers];
    progress.rate = (progress.finished() - progress.resumed) as f64 / start.elapsed().as_secs_f64().max(1e-9);
    observer.update(&progress);
    if interrupted {
        return Err(GenerateError::Interrupted { finished: progress.finished(), total: progress.total });
    }
    Ok(progress)
}
