//! A run directory's training cache built ahead of training (`dynforge dataset prepare`): what each partition of a
//! bounded-disk run does before its shards are pruned.

use std::path::Path;

use dynforge_recording::ReadError;
use dynforge_recording::dataset::dataset_robot;

use crate::cache::evidence::PhysicsSet;
use crate::cache::windows::CachedWindows;
use crate::cache::{CacheError, Skipped};
use crate::evidence::{EvidenceError, dataset_prior};
use crate::features::JacobianFeatures;
use crate::window::WindowSpec;

/// Which estimator a run trains, hence which cache it reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
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
    /// Pruning would lose them.
    #[error("{count} shard(s) could not be cached ({list}); `dynforge verify --repair` then `generate` remake them")]
    Skipped { count: usize, list: String },
}

/// Builds the cache a run of `kind` with window geometry `spec` reads from the `generate` directory `dir` (or finds
/// it current), without training, calling `progress(stage, done, total)`; `false` stops (an error, nothing
/// cached). Returns what the cache holds. An error if any shard had to be skipped. The physics cache first fits the
/// generator's parameter prior (`crate::evidence::PRIOR_ROBOTS` robots, seconds).
pub fn prepare(
    dir: &Path,
    kind: ModelKind,
    spec: &WindowSpec,
    mut progress: impl FnMut(&str, usize, usize) -> bool,
) -> Result<String, PrepareError> {
    let (what, skipped, hit) = match kind {
        ModelKind::Physics => {
            let prior = dataset_prior(dir)?;
            let (set, skipped) = PhysicsSet::load_or_build(dir, spec, &prior, |k, n| progress("physics", k, n))?;
            let what = format!("physics of {} windows and {} recordings", set.windows.len(), set.recordings.len());
            (what, skipped, set.hit)
        }
        ModelKind::Transformer => {
            let features = JacobianFeatures::new(&dataset_robot(dir)?);
            let (w, skipped) = CachedWindows::load_or_build(dir, spec, &features, |k, n| progress("windows", k, n))?;
            (format!("{} windows of {} x {} values", w.count(), spec.len, w.width), skipped, w.hit)
        }
    };
    if !skipped.is_empty() {
        let list = skipped.iter().map(Skipped::to_string).collect::<Vec<_>>().join("; ");
        return Err(PrepareError::Skipped { count: skipped.len(), list });
    }
    Ok(format!("{what} ({})", if hit { "already cached" } else { "cached" }))
}
