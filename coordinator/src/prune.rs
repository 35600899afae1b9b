//! Pruning: a finished run directory's shards deleted once the trainer has cached their data, so that a dataset too
//! large for the disk can still be generated and trained on, a partition at a time (raw shards ~1 MB each, their
//! physics ~25 KB). What was pruned is recorded in `DIR/pruned.txt` (`dynforge_proto::run_dir`).

use std::path::Path;
use std::time::Duration;

use dynforge_dataset::prepare::{ModelKind, PrepareError, prepare_locked};
use dynforge_dataset::window::WindowSpec;
use dynforge_proto::manifest::Manifest;
use dynforge_proto::run_dir::{self, LEDGER, SHARDS};

use crate::verify::{VerifyError, verify};
use dynforge_proto::ledger;
use dynforge_proto::lock::RunLock;

#[derive(Debug, thiserror::Error)]
pub enum PruneError {
    #[error("{dir}: cannot prune: {problem}")]
    NotReady { dir: String, problem: String },
    #[error("{dir}: caching before pruning: {source}; no shard was deleted")]
    Cache { dir: String, source: PrepareError },
    #[error(transparent)]
    Verify(#[from] VerifyError),
    #[error(transparent)]
    Manifest(#[from] dynforge_proto::manifest::ManifestError),
    #[error(transparent)]
    Ledger(#[from] ledger::LedgerError),
    #[error(transparent)]
    Lock(#[from] dynforge_proto::lock::LockError),
}

/// What a prune did: the cache that holds the shards' data (as `dynforge_dataset::prepare` describes it), and how
/// many shards were deleted.
#[derive(Debug, Clone, PartialEq)]
pub struct Pruned {
    pub cache: String,
    pub shards: usize,
}

/// The lock's description of a prune, for anyone refused meanwhile.
pub const PRUNING: &str = "dataset prepare --prune";

/// Prunes the run directory `dir`: takes its lock (no generate, prepare or other prune may change it meanwhile),
/// checks that it verifies complete (every shard hashes to its ledger record), builds the cache of the estimator
/// `kind` with window geometry `spec` that will hold the shards' data (`dynforge_dataset::prepare`), then records
/// every present shard in the pruned list and deletes it: each only if the cache lists it with the same content
/// hash, so what is deleted is what the cache holds.
/// `progress(stage, done, total)` follows the verification and the caching; `false` stops (before any shard is
/// deleted).
///
/// The list is written before any file is deleted: a crash in between leaves shards both listed and present, which
/// read as present, and the next prune deletes them.
pub fn prune(
    dir: &Path,
    kind: ModelKind,
    spec: &WindowSpec,
    mut progress: impl FnMut(&str, usize, usize) -> bool,
) -> Result<Pruned, PruneError> {
    let lock = RunLock::acquire(dir, Duration::ZERO, PRUNING)?;
    let not_ready = |problem: String| PruneError::NotReady { dir: dir.display().to_string(), problem };
    let report = verify(dir, |k, n| {
        progress("verify", k, n);
    })?;
    // The lock is ours: a live holder seen by verify is this process.
    if !report.is_ok() {
        return Err(not_ready(format!("it does not verify: {}", report.to_string().trim_end().replace('\n', "; "))));
    }
    if report.pending + report.failed > 0 {
        return Err(not_ready(format!(
            "{} job(s) pending and {} failed; finish the generation first (its ledger is part of the caches' key, so \
             a cache made now would not hold the later shards)",
            report.pending, report.failed
        )));
    }
    let cache = prepare_locked(dir, kind, spec, &lock, &mut progress)
        .map_err(|source| PruneError::Cache { dir: dir.display().to_string(), source })?;
    let manifest = Manifest::load(dir)?.ok_or_else(|| VerifyError::NoManifest(dir.display().to_string()))?;
    let engine = manifest.sim.engine.name();
    let entries = ledger::read(&dir.join(LEDGER))?;
    let shards = dir.join(SHARDS);
    let io = |p: &Path, source| VerifyError::Io { path: p.display().to_string(), source };
    let list = dir.join(run_dir::PRUNED);
    let mut pruned = run_dir::read_pruned(dir).map_err(|e| io(&list, e))?;
    let present: Vec<(String, u64)> = ledger::done_shards(&entries, manifest.seed, engine)
        .into_iter()
        .filter(|(name, _)| shards.join(name).exists())
        .collect();
    let unheld: Vec<&str> = present
        .iter()
        .filter(|(name, hash)| cache.held.as_ref().and_then(|h| h.get(name)) != Some(hash))
        .map(|(name, _)| name.as_str())
        .collect();
    if let Some(first) = unheld.first() {
        return Err(not_ready(format!(
            "the cache ({cache}) does not hold {} present shard(s) as the ledger records them ({first} ...): no shard \
             was deleted",
            unheld.len()
        )));
    }
    let present: Vec<String> = present.into_iter().map(|(name, _)| name).collect();
    pruned.extend(present.iter().cloned());
    run_dir::write_pruned(dir, &pruned).map_err(|e| io(&list, e))?;
    for name in &present {
        let path = shards.join(name);
        std::fs::remove_file(&path).map_err(|e| io(&path, e))?;
    }
    std::fs::File::open(&shards).and_then(|d| d.sync_all()).map_err(|e| io(&shards, e))?;
    Ok(Pruned { cache: cache.what, shards: present.len() })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::{Plan, job_id};
    use dynforge_proto::generator::GeneratorConfig;
    use dynforge_proto::ledger::{Entry, Ledger, Status};
    use dynforge_proto::manifest::Partition;
    use dynforge_proto::sim::SimConfig;
    use std::path::PathBuf;

    /// A run directory of 2 robots x 2 trajectories whose ledger records its jobs with `statuses` (in plan order);
    /// a `Done` job's shard holds `shard` (bytes a worker did not write).
    fn run_dir(statuses: &[Status], shard: &[u8]) -> (tempfile::TempDir, Vec<PathBuf>) {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let m = Manifest::new(4, 2, 2, Partition::WHOLE, GeneratorConfig::default(), SimConfig::default());
        m.create_or_check(dir).unwrap();
        std::fs::create_dir_all(dir.join(SHARDS)).unwrap();
        let (mut ledger, _) = Ledger::open(&dir.join(LEDGER)).unwrap();
        let mut shards = Vec::new();
        for (j, status) in Plan::of(&m).jobs().zip(statuses) {
            if let Status::Done { .. } = status {
                let path = dir.join(SHARDS).join(j.shard_name(m.sim.engine.name()));
                std::fs::write(&path, shard).unwrap();
                shards.push(path);
            }
            let e = Entry {
                job_id: job_id(&j, m.trajectories),
                robot: j.robot,
                trajectory: j.trajectory,
                status: status.clone(),
            };
            ledger.append(&e).unwrap();
        }
        (tmp, shards)
    }

    fn discarded() -> Status {
        Status::Discarded { reason: "collision".into() }
    }

    fn prune_it(dir: &Path) -> Result<Pruned, PruneError> {
        prune(dir, ModelKind::Physics, &WindowSpec::default(), |_, _, _| true)
    }

    /// The caches' key includes the ledger: a cache made before the last jobs are recorded would not hold them.
    #[test]
    fn a_run_with_pending_jobs_is_not_pruned() {
        let (tmp, _) = run_dir(&[discarded(), discarded(), discarded()], b"");
        assert!(matches!(prune_it(tmp.path()), Err(PruneError::NotReady { .. })));
        assert!(!tmp.path().join(run_dir::PRUNED).exists(), "nothing is recorded pruned");
    }

    /// Pruning deletes data for good: a shard that does not match its ledger record is never deleted.
    #[test]
    fn a_run_whose_shards_do_not_verify_keeps_every_shard() {
        let bytes = b"not an mcap file";
        let done = Status::Done { samples: 100, shard_hash: dynforge_proto::content_hash(bytes) };
        let (tmp, shards) = run_dir(&[done, discarded(), discarded(), discarded()], bytes);
        assert!(matches!(prune_it(tmp.path()), Err(PruneError::NotReady { .. })));
        for s in &shards {
            assert_eq!(std::fs::read(s).unwrap(), bytes, "{} untouched", s.display());
        }
        assert!(!tmp.path().join(run_dir::PRUNED).exists());
    }

    #[test]
    fn a_run_directory_someone_holds_is_not_pruned() {
        let (tmp, _) = run_dir(&[discarded(), discarded(), discarded(), discarded()], b"");
        let _generating =
            dynforge_proto::lock::RunLock::acquire(tmp.path(), Duration::ZERO, crate::run::GENERATING).unwrap();
        assert!(matches!(prune_it(tmp.path()), Err(PruneError::Lock(_))));
    }
}
