//! A run directory's caches: what its shards become for an estimator, built once and reused across runs. One
//! mechanism serves every kind ([`Cached`]: the transformer's windows, [`windows::CachedWindows`]; the physics
//! estimator's evidence, [`evidence::PhysicsSet`]): shards read on all cores a chunk at a time and appended in
//! shard-name order, so the result does not depend on the core count; one file per kind and settings, named by what
//! determines it ([`CacheKey`]), written atomically (a crash mid-write leaves the previous state) and checksummed (a
//! damaged file fails its check and is rebuilt); and the caches of a run's partitions combined into the merged
//! directory's ([`partitions`]).

pub(crate) mod codec;
pub mod evidence;
pub mod partitions;
pub mod windows;

use std::path::{Path, PathBuf};

use dynforge_proto::run_dir::{CACHE, LEDGER, MANIFEST, PRUNED, SHARDS, read_pruned};
use dynforge_recording::ReadError;
use dynforge_recording::dataset::list_shards;
use dynforge_shard::content_hash;

/// Why a cache could not be had.
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    /// Shards were pruned and no current cache of this kind holds them.
    #[error(
        "{dir}: {pruned} shards were pruned ({PRUNED}): their data are only in the caches, and no intact {kind} cache \
         for these settings is current (cache/ holds: {held}). Use the settings the directory was prepared with, or \
         delete {PRUNED} and rerun its `dynforge generate` command to remake the shards"
    )]
    Pruned { dir: String, pruned: usize, kind: &'static str, held: String },
    #[error("{0}: interrupted while reading the shards; nothing was cached")]
    Interrupted(String),
    /// The prior or other settings the cache is built with could not be made.
    #[error("{0}")]
    Settings(String),
}

/// A shard left out of a cache, with the reason.
#[derive(Debug, thiserror::Error)]
pub enum Skipped {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error(transparent)]
    Evidence(#[from] crate::evidence::EvidenceError),
    /// Not a dataset shard, or not like the others.
    #[error("{file}: {problem}")]
    Content { file: String, problem: String },
}

impl Skipped {
    pub fn new(file: &Path, problem: impl ToString) -> Self {
        Skipped::Content { file: file.display().to_string(), problem: problem.to_string() }
    }
}

/// The caches of several partitions cannot be combined (they hold items of different shapes).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct CombineError(pub String);

/// A kind of cache: what one shard contributes, how contributions join, and the file format.
pub trait Cached: Sized {
    /// The kind's name: the first part of its file names.
    const KIND: &'static str;
    /// Shards read per core before the next progress call.
    const CHUNK_PER_THREAD: usize;
    /// What, besides the dataset, determines the cache (window geometry, features, the parameter prior).
    type Settings: Sync;
    /// One shard's contribution, computed on any core.
    type Shard: Send;
    /// What [`Cached::append`] tells about the items it added.
    type Added;

    /// The preprocessing half of the file name.
    fn key(settings: &Self::Settings) -> CacheKey;
    fn empty(settings: &Self::Settings) -> Self;
    fn read_shard(path: &Path, settings: &Self::Settings) -> Result<Self::Shard, Skipped>;
    fn append(&mut self, path: &Path, shard: Self::Shard) -> Result<Self::Added, Skipped>;
    fn encode(&self) -> Vec<u8>;
    /// `None` unless `bytes` is an intact cache of this kind; the result says it came from a file.
    fn decode(bytes: &[u8]) -> Option<Self>;
    /// The caches of a run's partitions as the merged directory's ([`partitions`]).
    fn combine(parts: &[Self]) -> Result<Self, CombineError>;
}

/// Appends the shards `paths` to `cache`, in their order: for each, what was added or why it was skipped. Shards
/// are read on all cores, a chunk at a time, and appended in order, so the result is that of reading them one by
/// one. `progress(done, total)` before each chunk and at the end; `false` stops before the next chunk (the result
/// then has fewer entries than `paths`).
pub fn add_shards<C: Cached>(
    cache: &mut C,
    paths: &[PathBuf],
    settings: &C::Settings,
    mut progress: impl FnMut(usize, usize) -> bool,
) -> Vec<Result<C::Added, Skipped>> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut out = Vec::with_capacity(paths.len());
    for chunk in paths.chunks(C::CHUNK_PER_THREAD * threads) {
        if !progress(out.len(), paths.len()) {
            return out;
        }
        let read = dynforge_proto::parallel::map_in_order(chunk, |p| C::read_shard(p, settings));
        for (p, r) in chunk.iter().zip(read) {
            out.push(r.and_then(|s| cache.append(p, s)));
        }
    }
    progress(out.len(), paths.len());
    out
}

/// The cache of kind `C` of every shard of the `generate` directory `dir`: from its file if current, else built
/// (calling `progress(done, total)` per chunk of shards; `false` stops, an error, with nothing cached) and written.
/// Shards that cannot be read, or are not dataset shards, are skipped and returned.
pub fn load_or_build<C: Cached>(
    dir: &Path,
    settings: &C::Settings,
    progress: impl FnMut(usize, usize) -> bool,
) -> Result<(C, Vec<Skipped>), CacheError> {
    let path = C::key(settings).path(dir)?;
    if let Some(c) = std::fs::read(&path).ok().and_then(|b| C::decode(&b)) {
        return Ok((c, Vec::new()));
    }
    check_not_pruned(dir, C::KIND)?;
    let io = |p: &Path| {
        let shown = p.display().to_string();
        move |source| CacheError::Io { path: shown.clone(), source }
    };
    let shards = dir.join(SHARDS);
    let paths = list_shards(&shards).map_err(io(&shards))?;
    let mut cache = C::empty(settings);
    let added = add_shards(&mut cache, &paths, settings, progress);
    if added.len() < paths.len() {
        return Err(CacheError::Interrupted(dir.display().to_string()));
    }
    let skipped = added.into_iter().filter_map(Result::err).collect();
    let cache_dir = dir.join(CACHE);
    std::fs::create_dir_all(&cache_dir).map_err(io(&cache_dir))?;
    dynforge_proto::run_dir::write_atomic(&path, &cache.encode()).map_err(io(&path))?;
    Ok((cache, skipped))
}

/// Names a cache file of a run directory: `KIND-PPPPPPPPPPPPPPPP-DDDDDDDDDDDDDDDD.bin`, where P hashes the
/// preprocessing (whatever besides the data determines the cached values) and D the dataset (its manifest and its
/// ledger's records, sorted: completion order differs from run to run). Kept apart, so that the partitions of one
/// run, prepared alike, show which of their caches go together (same kind and P) when they are merged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct CacheKey {
    pub kind: &'static str,
    pub preprocessing: u64,
}

impl CacheKey {
    pub fn new(kind: &'static str, material: &[u8]) -> Self {
        CacheKey { kind, preprocessing: content_hash(material) }
    }

    pub fn file_name(&self, dataset: u64) -> String {
        format!("{}-{:016x}-{dataset:016x}.bin", self.kind, self.preprocessing)
    }

    /// The file of this cache in the run directory `dir`, as its manifest and ledger are now.
    pub fn path(&self, dir: &Path) -> Result<PathBuf, ReadError> {
        Ok(dir.join(CACHE).join(self.file_name(dataset_hash_of(dir)?)))
    }

    /// The key and dataset hash a cache file name carries, for a kind in `kinds`.
    pub fn parse(name: &str, kinds: &[&'static str]) -> Option<(CacheKey, u64)> {
        let rest = name.strip_suffix(".bin")?;
        let (head, dataset) = rest.rsplit_once('-')?;
        let (kind, p) = head.rsplit_once('-')?;
        let kind = *kinds.iter().find(|k| **k == kind)?;
        let hex = |s: &str| (s.len() == 16).then(|| u64::from_str_radix(s, 16).ok()).flatten();
        Some((CacheKey { kind, preprocessing: hex(p)? }, hex(dataset)?))
    }
}

/// The dataset hash of a run directory with this manifest and ledger.
pub(crate) fn dataset_hash(manifest: &[u8], ledger: &[u8]) -> u64 {
    let ledger = String::from_utf8_lossy(ledger);
    let mut lines: Vec<&str> = ledger.lines().collect();
    lines.sort_unstable();
    let mut material = manifest.to_vec();
    material.extend(lines.join("\n").bytes());
    content_hash(&material)
}

/// The dataset hash of the run directory `dir`.
pub(crate) fn dataset_hash_of(dir: &Path) -> Result<u64, ReadError> {
    let read_file = |name: &str| {
        std::fs::read(dir.join(name))
            .map_err(|e| ReadError::Content { file: dir.join(name).display().to_string(), problem: e.to_string() })
    };
    Ok(dataset_hash(&read_file(MANIFEST)?, &read_file(LEDGER)?))
}

/// After a cache miss: an error when shards of `dir` were pruned, whose data only a current cache could hold.
fn check_not_pruned(dir: &Path, kind: &'static str) -> Result<(), CacheError> {
    let list = dir.join(PRUNED);
    let pruned = read_pruned(dir).map_err(|source| CacheError::Io { path: list.display().to_string(), source })?;
    if pruned.is_empty() {
        return Ok(());
    }
    let mut held: Vec<String> = std::fs::read_dir(dir.join(CACHE))
        .map(|l| l.filter_map(Result::ok).map(|e| e.file_name().to_string_lossy().to_string()).collect())
        .unwrap_or_default();
    held.sort();
    Err(CacheError::Pruned {
        dir: dir.display().to_string(),
        pruned: pruned.len(),
        kind,
        held: if held.is_empty() { "nothing".to_string() } else { held.join(", ") },
    })
}
