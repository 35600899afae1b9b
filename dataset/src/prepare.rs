//! A run directory's training cache built ahead of training (`dynforge dataset prepare`): what each partition of a
//! bounded-disk run does before its shards are pruned.

use std::path::{Path, PathBuf};
use std::time::Duration;

use dynforge_identify::ParameterPrior;
use dynforge_proto::lock::{LockError, RunLock};
use dynforge_recording::ReadError;
use dynforge_recording::dataset::{dataset_robot, recorded_shards};

use crate::cache::evidence::{EvidenceSettings, PhysicsSet};
use crate::cache::windows::{CachedWindows, cache_path};
use crate::cache::{CacheError, Cached, Held, Skipped};
use crate::evidence::{EvidenceError, dataset_prior};
use crate::features::JacobianFeatures;
use crate::window::WindowSpec;

/// Which estimator a run trains, hence which cache it reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelKind {
    /// Physics as input: what each window's torques identify (posterior of the generator's parameter prior),
    /// mapped to the labels by a network trained on generated robots.
    Physics,
    /// The paper's transformer over downsampled windows of q, qd, tau and Jacobian features.
    Transformer,
}

#[derive(Debug, thiserror::Error)]
pub enum PrepareError {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error(transparent)]
    Evidence(#[from] EvidenceError),
    #[error(transparent)]
    Cache(#[from] CacheError),
    #[error(transparent)]
    Lock(#[from] LockError),
    /// Pruning would lose them.
    #[error(
        "{count} shard(s) could not be cached ({list}); nothing was cached: `dynforge verify --repair` then `generate` \
         remake them"
    )]
    Skipped { count: usize, list: String },
    /// A cache file that does not hold every shard the ledger records done (written by an older dynforge).
    #[error("{file}: holds {held} of the {recorded} shards the run's ledger records done; delete it and prepare again")]
    Incomplete { file: String, held: usize, recorded: usize },
}

/// What a prepared cache holds.
#[derive(Debug, Clone, PartialEq)]
pub struct Prepared {
    /// Its items, and whether it was already cached, as text.
    pub what: String,
    /// The shards it holds, with their content hashes; `None` for a file from before caches recorded them (found in a
    /// directory whose shards were pruned).
    pub held: Option<Held>,
}

impl std::fmt::Display for Prepared {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.what)
    }
}

/// Builds the cache a run of `kind` with window geometry `spec` reads from the `generate` directory `dir` (or finds
/// it current), without training, holding the directory's lock (refused while a generation, a prune or another
/// prepare runs there), calling `progress(stage, done, total)`; `false` stops (an error, nothing cached). An error
/// if any shard had to be skipped (nothing is then cached). The physics cache first fits the generator's parameter
/// prior (`crate::evidence::PRIOR_ROBOTS` robots, seconds).
pub fn prepare(
    dir: &Path,
    kind: ModelKind,
    spec: &WindowSpec,
    progress: impl FnMut(&str, usize, usize) -> bool,
) -> Result<Prepared, PrepareError> {
    let lock = RunLock::acquire(dir, Duration::ZERO, "dataset prepare")?;
    prepare_locked(dir, kind, spec, &lock, progress)
}

/// [`prepare`] by the holder of `dir`'s lock `lock` (a prune, which deletes the shards the cache holds after).
pub fn prepare_locked(
    dir: &Path,
    kind: ModelKind,
    spec: &WindowSpec,
    lock: &RunLock,
    mut progress: impl FnMut(&str, usize, usize) -> bool,
) -> Result<Prepared, PrepareError> {
    // What killed cache writers left (all of them held the lock, so none is live).
    let cache_dir = dir.join(dynforge_proto::run_dir::CACHE);
    dynforge_proto::run_dir::remove_temporaries(&cache_dir)
        .map_err(|source| CacheError::Io { path: cache_dir.display().to_string(), source })?;
    let (what, skipped, hit, held, file) = match kind {
        ModelKind::Physics => {
            let prior = dataset_prior(dir)?;
            let l = PhysicsSet::load(dir, spec, &prior, Some(lock), |k, n| progress("physics", k, n))?;
            let set = &l.cache;
            let what = format!("physics of {} windows and {} recordings", set.windows.len(), set.recordings.len());
            let file = physics_path(dir, spec, &prior)?;
            (what, l.skipped, set.hit, l.held, file)
        }
        ModelKind::Transformer => {
            let features = JacobianFeatures::new(&dataset_robot(dir)?);
            let l = CachedWindows::load(dir, spec, &features, Some(lock), |k, n| progress("windows", k, n))?;
            let w = &l.cache;
            let what = format!("{} windows of {} x {} values", w.count(), spec.len, w.width);
            (what, l.skipped, w.hit, l.held, cache_path(dir, spec, &features)?)
        }
    };
    if !skipped.is_empty() {
        let list = skipped.iter().map(Skipped::to_string).collect::<Vec<_>>().join("; ");
        return Err(PrepareError::Skipped { count: skipped.len(), list });
    }
    if let Some(held) = &held {
        let recorded = recorded_shards(dir)?.unwrap_or_default();
        if recorded.iter().any(|(name, hash)| held.get(name) != Some(hash)) {
            let file = file.display().to_string();
            return Err(PrepareError::Incomplete { file, held: held.len(), recorded: recorded.len() });
        }
    }
    let what = format!("{what} ({})", if hit { "already cached" } else { "cached" });
    Ok(Prepared { what, held })
}

/// The physics cache file of `dir` for this geometry and prior.
fn physics_path(dir: &Path, spec: &WindowSpec, prior: &ParameterPrior) -> Result<PathBuf, ReadError> {
    PhysicsSet::key(&EvidenceSettings { spec: *spec, prior: prior.clone() }).path(dir)
}
