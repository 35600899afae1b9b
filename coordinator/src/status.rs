//! `dynforge status`: how a generation stands, live from its coordinator (the status service) or, when none runs,
//! from its ledger.

use std::path::Path;
use std::time::Duration;

use dynforge_ipc::{RunId, StatusMsg, StatusReader};
use dynforge_proto::run_dir::LEDGER;

use crate::plan::Plan;
use crate::run::Progress;
use dynforge_proto::ledger;
use dynforge_proto::manifest::Manifest;

#[derive(Debug, thiserror::Error)]
pub enum StatusError {
    #[error("{0}: no run manifest (not a dynforge generate directory)")]
    NoManifest(String),
    #[error(transparent)]
    Manifest(#[from] dynforge_proto::manifest::ManifestError),
    #[error(transparent)]
    Ledger(#[from] ledger::LedgerError),
    #[error(transparent)]
    Ipc(#[from] dynforge_ipc::IpcError),
}

/// A run's standing.
pub enum RunStatus {
    /// A coordinator runs and published this.
    Live(StatusMsg),
    /// None publishes here: the ledger's counts for the manifest's jobs. `holder` is who holds the directory's lock
    /// if someone does: a coordinator on another host sharing the directory (its status is in that host's memory).
    Stopped { progress: Progress, pending: u64, holder: Option<dynforge_proto::lock::Holder> },
}

/// The standing of the run in `dir`.
pub fn status(dir: &Path) -> Result<RunStatus, StatusError> {
    let run = RunId::for_dir(dir)?;
    if let Some(mut reader) = StatusReader::open(&run)?
        && let Some(s) = reader.latest_timeout(Duration::from_millis(500))
    {
        return Ok(RunStatus::Live(s));
    }
    stopped(dir)
}

/// The standing of the run in `dir` as its manifest and ledger tell it (no coordinator publishes here).
fn stopped(dir: &Path) -> Result<RunStatus, StatusError> {
    let manifest = Manifest::load(dir)?.ok_or_else(|| StatusError::NoManifest(dir.display().to_string()))?;
    let plan = Plan::of(&manifest);
    // Records of jobs the manifest does not plan are not its progress (`verify` names them).
    let entries: Vec<ledger::Entry> =
        ledger::read(&dir.join(LEDGER))?.into_iter().filter(|e| plan.records(e)).collect();
    let total = plan.len();
    let progress = Progress::from_ledger(total, &entries);
    let pending = total.saturating_sub(progress.finished());
    Ok(RunStatus::Stopped { progress, pending, holder: dynforge_proto::lock::holder(dir) })
}

impl RunStatus {
    /// The same figures as JSON (`live` tells which kind).
    pub fn json(&self) -> serde_json::Value {
        match self {
            RunStatus::Live(s) => serde_json::json!({
                "live": true, "total": s.total, "done": s.done, "discarded": s.discarded, "failed": s.failed,
                "in_flight": s.in_flight, "workers_alive": s.workers_alive, "rate_per_s": s.rate_per_s,
                "eta_s": s.eta_s, "respawns": s.respawns, "coordinator_pid": s.coordinator_pid,
            }),
            RunStatus::Stopped { progress: p, pending, holder } => serde_json::json!({
                "live": holder.is_some(), "total": p.total, "done": p.done, "discarded": p.discarded,
                "failed": p.failed, "reasons": p.reasons, "pending": pending,
                "holder": holder.as_ref().map(|h| h.to_string()),
            }),
        }
    }
}

impl std::fmt::Display for RunStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunStatus::Live(s) => write!(
                f,
                "running (coordinator pid {}): {}/{} jobs finished: done {}, discarded {}, failed {}; {} in flight on {} \
                 workers; {:.1} jobs/s, ETA {:.0} s",
                s.coordinator_pid,
                s.done + s.discarded + s.failed,
                s.total,
                s.done,
                s.discarded,
                s.failed,
                s.in_flight,
                s.workers_alive,
                s.rate_per_s,
                s.eta_s
            ),
            RunStatus::Stopped { progress: p, pending, holder } => {
                let reasons: Vec<String> = p.reasons.iter().map(|(r, n)| format!("{r} {n}")).collect();
                let state = match holder {
                    Some(h) => format!("running ({h}), no live figures on this host; the ledger has"),
                    None => "not running:".into(),
                };
                write!(
                    f,
                    "{state} {}/{} jobs finished (done {}, discarded {}{}, failed {}); {pending} pending",
                    p.finished(),
                    p.total,
                    p.done,
                    p.discarded,
                    if reasons.is_empty() { String::new() } else { format!(": {}", reasons.join(", ")) },
                    p.failed
                )
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::job_id;
    use dynforge_proto::generator::GeneratorConfig;
    use dynforge_proto::ledger::{Entry, Ledger, Status};
    use dynforge_proto::manifest::Partition;
    use dynforge_proto::sim::SimConfig;

    const TRAJECTORIES: u32 = 2;

    /// A run directory of 5 robots' partition 0/2 (robots 0, 2, 4: 6 jobs) whose ledger holds `records`
    /// (robot, trajectory, status).
    fn run_dir(records: &[(u64, u32, Status)]) -> (tempfile::TempDir, Plan) {
        let tmp = tempfile::tempdir().unwrap();
        let partition = Partition { index: 0, count: 2 };
        let m = Manifest::new(11, 5, TRAJECTORIES, partition, GeneratorConfig::default(), SimConfig::default());
        m.create_or_check(tmp.path()).unwrap();
        let (mut ledger, _) = Ledger::open(&tmp.path().join(LEDGER)).unwrap();
        for (robot, trajectory, status) in records {
            let job = dynforge_proto::job::Job { seed: m.seed, robot: *robot, trajectory: *trajectory };
            let e = Entry {
                job_id: job_id(&job, TRAJECTORIES),
                robot: *robot,
                trajectory: *trajectory,
                status: status.clone(),
            };
            ledger.append(&e).unwrap();
        }
        (tmp, Plan::of(&m))
    }

    /// Without a coordinator, `status` reads the ledger: a record of a job the manifest does not plan (another
    /// partition's, another run's) must neither count as progress nor shrink what is pending.
    #[test]
    fn a_stopped_run_counts_only_its_own_jobs_and_the_rest_are_pending() {
        let done = Status::Done { samples: 3, shard_hash: 4 };
        let (dir, plan) = run_dir(&[
            (0, 0, done.clone()),
            (0, 1, Status::Discarded { reason: "collision".into() }),
            (2, 0, Status::Failed { message: "disk full".into() }),
            (1, 0, done.clone()), // robot 1 is partition 1/2's
        ]);
        let RunStatus::Stopped { progress, pending, holder } = stopped(dir.path()).unwrap() else {
            panic!("a run without a coordinator is stopped")
        };
        assert_eq!(progress.total, plan.len());
        assert_eq!((progress.done, progress.discarded, progress.failed), (1, 1, 1));
        assert_eq!(pending, plan.len() - 3);
        assert_eq!(holder, None);
    }

    #[test]
    fn a_stopped_run_reads_as_live_while_someone_holds_its_directory() {
        let (dir, plan) = run_dir(&[]);
        let free = stopped(dir.path()).unwrap();
        assert_eq!(free.json()["live"], false);
        assert_eq!(free.json()["pending"], plan.len());
        assert!(free.to_string().starts_with("not running"), "{free}");
        let _lock = dynforge_proto::lock::RunLock::acquire(dir.path(), Duration::ZERO, "generate").unwrap();
        let held = stopped(dir.path()).unwrap();
        assert_eq!(held.json()["live"], true, "a coordinator on another host shares the directory");
        let holder = held.json()["holder"].as_str().unwrap().to_string();
        assert!(holder.contains("generate"), "{holder}");
        assert!(held.to_string().contains(&holder), "{held}");
    }

    #[test]
    fn a_missing_manifest_is_not_a_run() {
        let tmp = tempfile::tempdir().unwrap();
        assert!(matches!(stopped(tmp.path()), Err(StatusError::NoManifest(_))));
    }

    #[test]
    fn a_live_status_counts_every_outcome_as_finished() {
        let s = StatusMsg {
            done: 5,
            discarded: 3,
            failed: 1,
            in_flight: 2,
            workers_alive: 2,
            total: 20,
            rate_per_s: 1.5,
            updated_unix_ms: 0,
            eta_s: 7.0,
            coordinator_pid: 42,
            respawns: 0,
        };
        let line = RunStatus::Live(s).to_string();
        let finished = s.done + s.discarded + s.failed;
        assert!(line.contains(&format!("{finished}/{} jobs finished", s.total)), "{line}");
        assert_eq!(RunStatus::Live(s).json()["live"], true);
    }
}
