//! `generate`: the coordinator. Plans the jobs not yet in the ledger, starts the worker processes, then loops:
//! [`dispatch`] hands jobs to idle workers and records every final report durably, [`liveness`] replaces dead or
//! hung workers and re-queues their jobs, [`progress`] tells displays and monitors how the run goes. The worker
//! processes themselves are started and stopped by [`processes`].

mod dispatch;
mod liveness;
mod processes;
mod progress;

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use dynforge_ipc::{Coordinator, IpcError, RunId};
use dynforge_proto::family::{Family, Sources};
use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::job::Job;
use dynforge_proto::run_dir::{CACHE, LEDGER, LOGS, MANIFEST, SHARDS, remove_temporaries};
use dynforge_proto::sim::SimConfig;

use crate::plan::{self, Plan};
use dynforge_proto::ledger::{Entry, Ledger, LedgerError, Status};
use dynforge_proto::lock::{LockError, RunLock};
use dynforge_proto::manifest::Partition;
use dynforge_proto::manifest::{Manifest, ManifestError};
use liveness::Start;
use processes::Processes;
pub use progress::{Observer, Progress};

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
    /// A robot's family instead of the generator's robots: its manifest record and its files, copied into the run
    /// directory for the workers.
    pub family: Option<(Family, Sources)>,
    /// A job running longer than this marks its worker as hung: it is killed and replaced.
    pub job_timeout: Duration,
    /// A job whose worker died (or failed) this many times is recorded as failed.
    pub max_attempts: u32,
    /// Program and leading arguments that start a worker; `--dir DIR --slot K` are appended.
    pub worker_command: Vec<OsString>,
}

#[derive(Debug, thiserror::Error)]
pub enum GenerateError {
    #[error("{dir}: cannot use as the output directory: {source}")]
    Dir { dir: String, source: std::io::Error },
    /// Settings no run can have (nothing to do, more trajectories than a tour).
    #[error("{0}")]
    Settings(String),
    #[error(transparent)]
    Lock(#[from] LockError),
    #[error(
        "{dir}: {LEDGER} records {entries} job(s) but {MANIFEST} is missing, so the settings they were made with are \
         unknown (other settings would reinterpret them); restore {MANIFEST} or use a new directory"
    )]
    NoManifest { dir: String, entries: usize },
    #[error(transparent)]
    Manifest(#[from] ManifestError),
    #[error(transparent)]
    Ledger(#[from] LedgerError),
    #[error(transparent)]
    Ipc(#[from] IpcError),
    #[error("{file}: cannot open the worker's log: {source}")]
    WorkerLog { file: String, source: std::io::Error },
    #[error("starting worker {slot} ({program}): {source}")]
    Spawn { slot: usize, program: String, source: std::io::Error },
    #[error("interrupted: {finished} of {total} jobs are recorded; run the same command again to resume")]
    Interrupted { finished: u64, total: u64 },
    #[error("no worker could be started ({why}); {finished} of {total} jobs are recorded, the same command resumes")]
    NoWorkers { why: String, finished: u64, total: u64 },
    #[error(
        "{dir}/{LEDGER} records {count} job(s) that {dir}/{MANIFEST} does not plan (the first: {first}): the ledger \
         and the manifest are of different runs; restore the run's own manifest, or use a new directory"
    )]
    Foreign { dir: String, count: usize, first: String },
    #[error(
        "{failed} job(s) failed (reasons in {dir}/{LEDGER} and the worker logs in {dir}/{LOGS}); rerun the same \
         command to retry them"
    )]
    Failed { failed: u64, dir: String },
}

/// How long a starting run waits for the directory's previous holder to go away: the orphan workers of a killed
/// coordinator get their kill signal as it dies, and release the lock within milliseconds.
const LOCK_WAIT: Duration = Duration::from_secs(5);

/// Removes the temporary files that killed writers left in the run directory, its shards and its caches (only the
/// lock's holder may: see [`RunLock`]); how many.
fn remove_leftovers(dir: &Path) -> std::io::Result<usize> {
    let mut n = 0;
    for d in [dir.to_path_buf(), dir.join(SHARDS), dir.join(CACHE)] {
        n += remove_temporaries(&d)?;
    }
    Ok(n)
}

/// The lock's description of a generation, for anyone refused meanwhile.
pub const GENERATING: &str = "generate";

/// A generation in progress: the queue, what each worker runs, and the durable record.
struct Run<'a> {
    cfg: &'a GenerateConfig,
    ledger: Ledger,
    pending: Queue,
    /// Per worker slot: its job and when it was sent.
    running: Vec<Option<(Job, Instant)>>,
    /// Per worker slot: its start-up ([`liveness`]).
    starts: Vec<Start>,
    /// Failed attempts per job id.
    attempts: HashMap<u64, u32>,
    progress: Progress,
    ipc: Coordinator,
    procs: Processes,
    interrupted: bool,
    /// Why the run ends before its jobs do: no worker could be started.
    no_workers: Option<String>,
    started: Instant,
}

/// The jobs left to hand out: jobs to retry first, then the plan's jobs not finished in an earlier run, made as they
/// are needed (a run of any size holds none of its jobs in memory).
struct Queue {
    retries: VecDeque<Job>,
    planned: std::iter::Peekable<Box<dyn Iterator<Item = Job>>>,
}

impl Queue {
    fn pop_front(&mut self) -> Option<Job> {
        self.retries.pop_front().or_else(|| self.planned.next())
    }

    fn push_front(&mut self, job: Job) {
        self.retries.push_front(job);
    }

    fn is_empty(&mut self) -> bool {
        self.retries.is_empty() && self.planned.peek().is_none()
    }
}

/// Worker processes per core a run starts at most: more only wait for a core, each holding its memory (~35 MB).
pub const WORKERS_PER_CORE: usize = 4;

/// Runs (or resumes) a generation. Returns the final progress.
pub fn generate(cfg: &GenerateConfig, observer: &mut dyn Observer) -> Result<Progress, GenerateError> {
    check_settings(cfg)?;
    // Nothing in the directory is touched before it is ours.
    let lock = RunLock::acquire(&cfg.dir, LOCK_WAIT, GENERATING)?;
    let (ledger, finished) = open_run_dir(cfg, observer)?;
    let plan = Plan { seed: cfg.seed, robots: cfg.robots, trajectories: cfg.trajectories, partition: cfg.partition };
    let mut progress = Progress { total: plan.len(), ..Progress::default() };
    for status in finished.values() {
        progress.record(status);
    }
    progress.resumed = progress.finished();
    let left = progress.total - progress.resumed;
    if left == 0 {
        observer.update(&progress);
        return Ok(progress);
    }
    let done: std::collections::BTreeSet<u64> = finished.into_keys().collect();
    let trajectories = cfg.trajectories;
    let planned: Box<dyn Iterator<Item = Job>> =
        Box::new(plan.jobs().filter(move |j| !done.contains(&plan::job_id(j, trajectories))));
    let pending = Queue { retries: VecDeque::new(), planned: planned.peekable() };
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let most = WORKERS_PER_CORE * cores;
    let wanted = cfg.workers.min(usize::try_from(left).unwrap_or(usize::MAX));
    if wanted > most {
        observer.message(&format!(
            "--workers {}: starting {most} ({WORKERS_PER_CORE} per core, {cores} here): more worker processes only \
             wait for a core, each holding its memory",
            cfg.workers
        ));
    }
    let workers = wanted.min(most);
    progress.slots = vec![None; workers];

    let id = RunId::for_dir(&cfg.dir)?;
    dynforge_ipc::cleanup_stale(&id)?;
    let mut ipc = Coordinator::new(&id, workers)?;
    let mut procs = Processes::new(cfg.worker_command.clone(), cfg.dir.clone(), workers, lock);
    for k in 0..workers {
        procs.spawn(k)?;
        ipc.attach_worker(k)?;
    }
    let run = Run {
        cfg,
        ledger,
        pending,
        running: vec![None; workers],
        starts: vec![Start::new(); workers],
        attempts: HashMap::new(),
        progress,
        ipc,
        procs,
        interrupted: false,
        no_workers: None,
        started: Instant::now(),
    };
    run.drive(observer)
}

impl Progress {
    /// An error naming the failed jobs of a finished run in `dir`, if any: the run ended, but a resume has work.
    pub fn check_failures(&self, dir: &Path) -> Result<(), GenerateError> {
        match self.failed {
            0 => Ok(()),
            failed => Err(GenerateError::Failed { failed, dir: dir.display().to_string() }),
        }
    }
}

/// Settings no run can have: nothing to do, or more trajectories than a tour.
fn check_settings(cfg: &GenerateConfig) -> Result<(), GenerateError> {
    if cfg.robots == 0 || cfg.trajectories == 0 || cfg.workers == 0 {
        return Err(GenerateError::Settings(format!(
            "--robots {}, --trajectories {} and --workers {} must all be at least 1",
            cfg.robots, cfg.trajectories, cfg.workers
        )));
    }
    if let Some((family, _)) = &cfg.family {
        let n = family.excitation_hashes.len();
        return match cfg.trajectories as usize == n {
            true => Ok(()),
            false => Err(GenerateError::Settings(format!(
                "--trajectories {}: a family's robots run each of its {n} excitation(s), once",
                cfg.trajectories
            ))),
        };
    }
    // Trajectory t is the move from waypoint t to t + 1 of a closed tour: there are as many as waypoints.
    let tour = cfg.sim.trajectory.waypoints;
    if cfg.trajectories as usize > tour {
        return Err(GenerateError::Settings(format!(
            "--trajectories {} is more than a robot has: its tour has {tour} waypoints, so {tour} trajectories",
            cfg.trajectories
        )));
    }
    Ok(())
}

/// Makes the locked directory a run directory of `cfg` (or checks it is one, growing it to more robots), removes
/// partial files, and opens its ledger: the ledger, and the final status of every job that needs no rerun.
fn open_run_dir(
    cfg: &GenerateConfig,
    observer: &mut dyn Observer,
) -> Result<(Ledger, BTreeMap<u64, Status>), GenerateError> {
    let dir_err = |source| GenerateError::Dir { dir: cfg.dir.display().to_string(), source };
    std::fs::create_dir_all(cfg.dir.join(SHARDS)).map_err(dir_err)?;
    std::fs::create_dir_all(cfg.dir.join(LOGS)).map_err(dir_err)?;
    // The ledger's lines name jobs by number, which only the manifest's settings map back to robots and trajectories.
    if !cfg.dir.join(MANIFEST).exists() {
        let entries = dynforge_proto::ledger::read(&cfg.dir.join(LEDGER))?.len();
        if entries > 0 {
            return Err(GenerateError::NoManifest { dir: cfg.dir.display().to_string(), entries });
        }
    }
    let manifest =
        Manifest::new(cfg.seed, cfg.robots, cfg.trajectories, cfg.partition, cfg.generator.clone(), cfg.sim.clone())
            .with_family(cfg.family.as_ref().map(|(f, _)| f.clone()));
    let pruned = dynforge_proto::run_dir::read_pruned(&cfg.dir).map_err(|e| {
        dir_err(std::io::Error::new(e.kind(), format!("reading {}: {e}", dynforge_proto::run_dir::PRUNED)))
    })?;
    if !pruned.is_empty() && Manifest::load(&cfg.dir)?.is_some_and(|m| m.robots < cfg.robots) {
        return Err(GenerateError::Settings(format!(
            "{}: {} shards were pruned (their data are only in the caches, which a larger dataset makes stale), so \
             it cannot grow; delete {} to have the pruned shards remade by this generate, or generate the larger \
             dataset into a new directory",
            cfg.dir.display(),
            pruned.len(),
            dynforge_proto::run_dir::PRUNED
        )));
    }
    if let Some(before) = manifest.create_or_check(&cfg.dir)? {
        observer.message(&format!("growing the dataset from {before} to {} robots", cfg.robots));
    }
    if let Some((_, sources)) = &cfg.family {
        // The manifest matched, so these are the bytes its hashes name: rewriting them repairs a lost copy.
        sources.write_to(&cfg.dir).map_err(dir_err)?;
    }
    let (ledger, entries) = Ledger::open(&cfg.dir.join(LEDGER))?;
    let plan = Plan { seed: cfg.seed, robots: cfg.robots, trajectories: cfg.trajectories, partition: cfg.partition };
    let foreign: Vec<&Entry> = entries.iter().filter(|e| !plan.records(e)).collect();
    if let Some(e) = foreign.first() {
        return Err(GenerateError::Foreign {
            dir: cfg.dir.display().to_string(),
            count: foreign.len(),
            first: format!("job {}, robot {} trajectory {}", e.job_id, e.robot, e.trajectory),
        });
    }
    let removed = remove_leftovers(&cfg.dir).map_err(dir_err)?;
    if removed > 0 {
        observer.message(&format!("removed {removed} partial file(s) left by an interrupted run"));
    }
    Ok((ledger, finished_jobs(cfg, &entries, &pruned, observer)))
}

/// The jobs a resume need not run again, with their final status. A job's latest entry counts. Done and discarded
/// are final (a discard is a property of the robot and its trajectory); a failure (a killed or hung worker, a full
/// disk, an unwritable directory) says nothing about the job, so a resume runs it again. A recorded shard that is
/// gone (deleted, lost with a disk) is made again: the job is deterministic. (A damaged one takes reading every
/// file: `verify --repair` finds those and records them failed, so they rerun too.) A pruned one is not gone: its
/// data are in the caches.
fn finished_jobs(
    cfg: &GenerateConfig,
    entries: &[Entry],
    pruned: &std::collections::BTreeSet<String>,
    observer: &mut dyn Observer,
) -> BTreeMap<u64, Status> {
    let latest = dynforge_proto::ledger::latest(entries);
    let failed = |e: &Entry| matches!(e.status, Status::Failed { .. });
    let retried = latest.values().filter(|e| failed(e)).count();
    if retried > 0 {
        observer.message(&format!("retrying {retried} job(s) that failed in an earlier run"));
    }
    let shards = cfg.dir.join(SHARDS);
    let lost = |e: &Entry| {
        let name = e.shard_name(cfg.seed, cfg.sim.engine.name());
        matches!(e.status, Status::Done { .. }) && !pruned.contains(&name) && !shards.join(&name).exists()
    };
    let missing = latest.values().filter(|e| !failed(e) && lost(e)).count();
    if missing > 0 {
        observer.message(&format!("{missing} recorded shard(s) are missing: running their jobs again"));
    }
    latest.into_iter().filter(|(_, e)| !failed(e) && !lost(e)).map(|(id, e)| (id, e.status.clone())).collect()
}

impl Run<'_> {
    /// Hands out jobs and takes reports until every job is recorded (or the run is interrupted), watching the
    /// workers and publishing the status on the way.
    fn drive(mut self, observer: &mut dyn Observer) -> Result<Progress, GenerateError> {
        let (mut last_status, mut last_liveness) = (Instant::now() - Duration::from_secs(1), Instant::now());
        loop {
            self.dispatch()?;
            if self.busy() == 0 && (self.pending.is_empty() || self.interrupted || self.no_workers.is_some()) {
                break;
            }
            self.receive(observer)?;
            if last_liveness.elapsed() >= LIVENESS_TICK {
                last_liveness = Instant::now();
                self.liveness(observer)?;
            }
            if last_status.elapsed() >= STATUS_TICK {
                last_status = Instant::now();
                // Freed workers get their next job before the snapshot: otherwise the pool looks half idle.
                self.dispatch()?;
                self.publish(observer);
            }
        }
        self.finish(observer)
    }
}

/// This process's CPU time (user + system) in seconds, from /proc (in USER_HZ = 100 ticks per second).
fn own_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// How often dead and hung workers are looked for (a scan of the run's nodes costs ~0.1-0.3 ms per node).
const LIVENESS_TICK: Duration = Duration::from_millis(100);
/// How often displays and monitors are updated.
const STATUS_TICK: Duration = Duration::from_millis(250);

impl Run<'_> {
    /// Workers with a job.
    fn busy(&self) -> usize {
        self.running.iter().filter(|r| r.is_some()).count()
    }

    /// Stops the workers, removes what killed writers left, and returns the final progress.
    fn finish(mut self, observer: &mut dyn Observer) -> Result<Progress, GenerateError> {
        // Tells the workers to stop, waits for them, and removes the run's shared-memory files.
        let _ = self.ipc.shutdown(Duration::from_secs(5));
        drop(self.procs);
        // Workers killed mid-write (dead, hung, interrupted) leave partial temporary files; no writer is left now.
        let dir_err = |source| GenerateError::Dir { dir: self.cfg.dir.display().to_string(), source };
        remove_leftovers(&self.cfg.dir).map_err(dir_err)?;
        let p = &mut self.progress;
        p.in_flight = 0;
        p.slots = vec![None; self.running.len()];
        p.rate = (p.finished() - p.resumed) as f64 / self.started.elapsed().as_secs_f64().max(1e-9);
        p.cpu_seconds = own_cpu_seconds().unwrap_or(0.0);
        observer.update(p);
        if self.interrupted {
            return Err(GenerateError::Interrupted { finished: p.finished(), total: p.total });
        }
        if let Some(why) = self.no_workers {
            return Err(GenerateError::NoWorkers { why, finished: p.finished(), total: p.total });
        }
        Ok(self.progress)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynforge_proto::run_dir::temporary_path;

    /// Collects what a run tells its display.
    #[derive(Default)]
    struct Messages(Vec<String>);

    impl Observer for Messages {
        fn update(&mut self, _: &Progress) {}
        fn message(&mut self, text: &str) {
            self.0.push(text.to_string());
        }
    }

    fn config(dir: &Path) -> GenerateConfig {
        GenerateConfig {
            dir: dir.to_path_buf(),
            seed: 7,
            robots: 3,
            trajectories: 2,
            workers: 2,
            partition: Partition::WHOLE,
            generator: GeneratorConfig::default(),
            sim: SimConfig::default(),
            family: None,
            job_timeout: Duration::from_secs(60),
            max_attempts: 3,
            worker_command: vec!["dynforge-worker".into()],
        }
    }

    fn queue(planned: Vec<Job>) -> Queue {
        let planned: Box<dyn Iterator<Item = Job>> = Box::new(planned.into_iter());
        Queue { retries: VecDeque::new(), planned: planned.peekable() }
    }

    fn job(robot: u64, trajectory: u32) -> Job {
        Job { seed: 7, robot, trajectory }
    }

    #[test]
    fn a_requeued_job_is_handed_out_before_the_planned_ones_and_none_is_lost() {
        let planned = vec![job(0, 0), job(0, 1), job(1, 0)];
        let mut q = queue(planned.clone());
        let first = q.pop_front().unwrap();
        assert_eq!(first, planned[0]);
        q.push_front(first);
        let mut handed = Vec::new();
        // Asking whether it is empty (it peeks at the plan) must not use a job up.
        while !q.is_empty() {
            assert!(!q.is_empty());
            handed.push(q.pop_front().unwrap());
        }
        assert_eq!(handed, planned, "the retry first, then the rest of the plan in order");
        assert_eq!(q.pop_front(), None);
    }

    /// A resume must redo exactly the jobs whose record says nothing final about them (failed) or whose shard is
    /// gone, and must not redo a pruned shard's job (its data live on in the caches).
    #[test]
    fn a_resume_skips_final_jobs_and_reruns_failed_and_lost_ones() {
        let tmp = tempfile::tempdir().unwrap();
        let cfg = config(tmp.path());
        let engine = cfg.sim.engine.name();
        std::fs::create_dir_all(cfg.dir.join(SHARDS)).unwrap();
        let entry = |robot, trajectory, status| {
            let id = plan::job_id(&job(robot, trajectory), cfg.trajectories);
            Entry { job_id: id, robot, trajectory, status }
        };
        let done = || Status::Done { samples: 10, shard_hash: 1 };
        let failed = || Status::Failed { message: "worker died (3 attempts)".into() };
        let present = |robot, trajectory| {
            std::fs::write(cfg.dir.join(SHARDS).join(job(robot, trajectory).shard_name(engine)), b"shard").unwrap()
        };
        present(0, 0);
        present(2, 0);
        present(2, 1);
        let pruned: std::collections::BTreeSet<String> = [job(1, 0).shard_name(engine)].into();
        let entries = vec![
            entry(0, 0, done()),                                           // kept: its shard is there
            entry(0, 1, done()),                                           // rerun: its shard is gone
            entry(1, 0, done()),                                           // kept: pruned, not gone
            entry(1, 1, Status::Discarded { reason: "collision".into() }), // kept: a discard is final
            entry(2, 0, failed()),
            entry(2, 0, done()), // kept: the retry that succeeded counts
            entry(2, 1, done()),
            entry(2, 1, failed()), // rerun: marked failed later (verify --repair)
        ];
        let mut messages = Messages::default();
        let finished = finished_jobs(&cfg, &entries, &pruned, &mut messages);

        let kept = [(0, 0), (1, 0), (1, 1), (2, 0)].map(|(r, t)| plan::job_id(&job(r, t), cfg.trajectories));
        assert_eq!(finished.keys().copied().collect::<Vec<_>>(), kept.to_vec());
        let latest = dynforge_proto::ledger::latest(&entries);
        for (id, status) in &finished {
            assert_eq!(status, &latest[id].status, "job {id} keeps its latest status");
        }
        assert!(messages.0.iter().any(|m| m.contains("failed")), "the retries are announced: {:?}", messages.0);
        assert!(messages.0.iter().any(|m| m.contains("missing")), "the lost shards are announced: {:?}", messages.0);
    }

    #[test]
    fn settings_with_nothing_to_do_or_more_trajectories_than_a_tour_are_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let good = config(tmp.path());
        assert!(check_settings(&good).is_ok());
        let tour = good.sim.trajectory.waypoints;
        let all = GenerateConfig { trajectories: tour as u32, ..good.clone() };
        assert!(check_settings(&all).is_ok(), "a robot has as many trajectories as waypoints");
        for bad in [
            GenerateConfig { robots: 0, ..good.clone() },
            GenerateConfig { trajectories: 0, ..good.clone() },
            GenerateConfig { workers: 0, ..good.clone() },
            GenerateConfig { trajectories: tour as u32 + 1, ..good.clone() },
        ] {
            assert!(
                matches!(check_settings(&bad), Err(GenerateError::Settings(_))),
                "robots {} trajectories {} workers {}",
                bad.robots,
                bad.trajectories,
                bad.workers
            );
        }
    }

    #[test]
    fn a_finished_run_is_an_error_exactly_when_a_job_failed() {
        let dir = Path::new("/runs/a");
        let mut p = Progress { total: 4, done: 3, discarded: 1, ..Progress::default() };
        assert!(p.check_failures(dir).is_ok());
        p.failed = 2;
        assert!(matches!(p.check_failures(dir), Err(GenerateError::Failed { failed: 2, .. })));
    }

    /// Partial files of writers a crash killed would otherwise read as extra shards or caches.
    #[test]
    fn leftover_temporary_files_are_removed_and_finished_files_kept() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let mut finished = Vec::new();
        let mut partial = Vec::new();
        for sub in [dir.to_path_buf(), dir.join(SHARDS), dir.join(CACHE)] {
            std::fs::create_dir_all(&sub).unwrap();
            let file = sub.join("kept.bin");
            std::fs::write(&file, b"x").unwrap();
            std::fs::write(temporary_path(&file), b"half").unwrap();
            partial.push(temporary_path(&file));
            finished.push(file);
        }
        assert_eq!(remove_leftovers(dir).unwrap(), partial.len());
        assert!(finished.iter().all(|f| f.exists()));
        assert!(partial.iter().all(|f| !f.exists()));
        assert_eq!(remove_leftovers(dir).unwrap(), 0, "nothing is left the second time");
    }
}
