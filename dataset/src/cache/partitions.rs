//! The caches of one run's partitions combined into the caches of the merged directory (`dynforge merge`), so that
//! partitions whose shards were pruned once cached still merge into a directory that trains.
//!
//! A cache lists its items (windows, recordings) shard by shard in shard-name order. Partitions split a run by robot,
//! so each robot's items are one contiguous block in exactly one partition, and the merged directory's order is
//! those blocks sorted by the robot's place in shard-name order: the combined cache is byte for byte the one the
//! merged directory would build from its shards.

use std::collections::BTreeSet;
use std::io::Write;
use std::path::{Path, PathBuf};

use dynforge_proto::run_dir::{CACHE, LEDGER, PRUNED, read_pruned, write_with};

use super::evidence::PhysicsSet;
use super::windows::CachedWindows;
use super::{CacheKey, Cached, Held, Stored, dataset_hash, dataset_hash_of, held_prefix};

const KINDS: [&str; 2] = [CachedWindows::KIND, PhysicsSet::KIND];

/// Why the caches of a run's partitions cannot be merged.
#[derive(Debug, thiserror::Error)]
pub enum PartitionsError {
    #[error(transparent)]
    Read(#[from] dynforge_recording::ReadError),
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error(
        "{dir} has no current {kind} cache {preprocessing:016x}, which another partition has, and shards were pruned: \
         run `dynforge dataset prepare` with the same settings on every partition"
    )]
    Missing { dir: String, kind: &'static str, preprocessing: u64 },
    #[error("shards were pruned, but the partitions have no current cache")]
    NoCommonCache,
    #[error("{0}: not an intact {1} cache")]
    Damaged(String, &'static str),
    #[error("combining the {kind} caches: {source}")]
    Combine { kind: &'static str, source: super::CombineError },
    #[error("writing the combined cache: {0}")]
    Write(std::io::Error),
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> PartitionsError {
    let path = path.display().to_string();
    move |source| PartitionsError::Io { path: path.clone(), source }
}

/// The caches current in every partition of a run, which [`Plan::combine`] merges.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    keys: Vec<CacheKey>,
}

/// The plan for `parts`. An error when a partition lacks a cache another has while shards were pruned (the merged
/// directory would hold the pruned shards' data for no settings), or when pruned shards are in no current cache.
pub fn plan(parts: &[PathBuf]) -> Result<Plan, PartitionsError> {
    let mut current: Vec<BTreeSet<CacheKey>> = Vec::new();
    for dir in parts {
        let dataset = dataset_hash_of(dir)?;
        let names = std::fs::read_dir(dir.join(CACHE))
            .map(|l| l.filter_map(Result::ok).map(|e| e.file_name().to_string_lossy().to_string()).collect())
            .unwrap_or_else(|_| Vec::new());
        current.push(
            names
                .iter()
                .filter_map(|n| CacheKey::parse(n, &KINDS))
                .filter(|(_, d)| *d == dataset)
                .map(|(k, _)| k)
                .collect(),
        );
    }
    let all: BTreeSet<CacheKey> = current.iter().flatten().copied().collect();
    let mut any_pruned = false;
    for dir in parts {
        any_pruned |= !read_pruned(dir).map_err(io(&dir.join(PRUNED)))?.is_empty();
    }
    let common: Vec<CacheKey> = all.iter().copied().filter(|k| current.iter().all(|c| c.contains(k))).collect();
    if any_pruned {
        if let Some((dir, key)) =
            all.iter().find_map(|k| parts.iter().zip(&current).find(|(_, c)| !c.contains(k)).map(|(d, _)| (d, k)))
        {
            let dir = dir.display().to_string();
            return Err(PartitionsError::Missing { dir, kind: key.kind, preprocessing: key.preprocessing });
        }
        if common.is_empty() {
            return Err(PartitionsError::NoCommonCache);
        }
    }
    Ok(Plan { keys: common })
}

impl Plan {
    /// How many caches the merge will combine.
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// Writes into the merged directory `out` (its ledger written, its manifest to be `manifest`) the combination
    /// of each cache of the plan made for `parts`; returns the file names written.
    pub fn combine(&self, parts: &[PathBuf], out: &Path, manifest: &[u8]) -> Result<Vec<String>, PartitionsError> {
        let ledger = std::fs::read(out.join(LEDGER)).map_err(io(&out.join(LEDGER)))?;
        let merged_dataset = dataset_hash(manifest, &ledger);
        std::fs::create_dir_all(out.join(CACHE)).map_err(io(&out.join(CACHE)))?;
        let mut written = Vec::new();
        for &key in &self.keys {
            let mut files = Vec::new();
            for dir in parts {
                let path = key.path(dir)?;
                let damaged = || PartitionsError::Damaged(path.display().to_string(), key.kind);
                files.push(Stored::open(&path).ok_or_else(damaged)?);
            }
            let name = key.file_name(merged_dataset);
            let path = out.join(CACHE).join(&name);
            let fill = |file| match key.kind {
                PhysicsSet::KIND => combine_files::<PhysicsSet, _>(&files, file),
                _ => combine_files::<CachedWindows, _>(&files, file),
            };
            write_with(&path, fill, |p, e| io(p)(e))?;
            written.push(name);
        }
        Ok(written)
    }
}

/// The cache files `files` of kind `C` combined and written to `out`, holding the shards all of them hold (a
/// partition's file from before caches recorded their shards makes one without the list); an error names the first
/// that is not an intact cache of the kind.
fn combine_files<C: Cached, W: Write>(files: &[Stored], out: W) -> Result<W, PartitionsError> {
    let held: Option<Vec<&Held>> = files.iter().map(|f| f.held.as_ref()).collect();
    let out = match held {
        Some(lists) => {
            let joined: Held = lists.into_iter().flat_map(|h| h.iter().map(|(k, v)| (k.clone(), *v))).collect();
            held_prefix(&joined, out).map_err(PartitionsError::Write)?
        }
        None => out,
    };
    C::combine_into(files, out)
}
