//! A run directory's caches: what its shards become for an estimator, built once and reused across runs. One
//! mechanism serves every kind ([`Cached`]: the transformer's windows, [`windows::CachedWindows`]; the physics
//! estimator's evidence, [`evidence::PhysicsSet`]): shards read on all cores a chunk at a time and appended in
//! shard-name order, so the result does not depend on the core count; one file per kind and settings, named by what
//! determines it ([`CacheKey`]), written atomically (a crash mid-write leaves the previous state) and checksummed (a
//! damaged file fails its check and is rebuilt); and the caches of a run's partitions combined into the merged
//! directory's ([`partitions`]).
//!
//! A cache is all a pruned shard's data, so it is never partial: each shard is checked against the content hash the
//! run's ledger recorded when its worker wrote it (a shard changed since, or not recorded, is skipped), a cache is
//! written only when it holds every shard the ledger records done, and its file lists those shards with their hashes
//! ([`Held`]), which is what `prepare --prune` checks before it deletes one. Only the holder of the run directory's
//! lock writes a cache ([`dynforge_proto::lock`]); `train` takes it for the moment of the write, or leaves the cache
//! unwritten when another command holds it.

pub(crate) mod codec;
pub mod evidence;
pub mod partitions;
pub mod windows;

use std::collections::{BTreeMap, BTreeSet};
use std::fs::File;
use std::io::{self, BufReader, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

use dynforge_proto::content_hash;
use dynforge_proto::lock::RunLock;
use dynforge_proto::run_dir::{CACHE, LEDGER, MANIFEST, PRUNED, SHARDS, read_pruned, remove_temporaries};
use dynforge_recording::ReadError;
use dynforge_recording::dataset::{check_recorded, list_shards, recorded_shards};

use codec::{Decoder, Encoder};
use partitions::PartitionsError;

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
    /// What a cache read back from its file takes from the settings its name was made of and its file does not hold:
    /// the windows' hop (the name says it; the header keeps the layout caches had before windows could overlap).
    fn restore(&mut self, settings: &Self::Settings);
    /// One shard's contribution, from the file's `bytes` (read and checked by the caller).
    fn read_shard(path: &Path, bytes: &[u8], settings: &Self::Settings) -> Result<Self::Shard, Skipped>;
    fn append(&mut self, path: &Path, shard: Self::Shard) -> Result<Self::Added, Skipped>;
    /// The kind's encoding (magic, content, checksum) written to `out`.
    fn encode<W: Write>(&self, out: W) -> io::Result<W>;
    /// `None` unless the `len` bytes of `input` are an intact cache of this kind; the result says it came from a
    /// file.
    fn decode<R: Read>(input: R, len: u64) -> Option<Self>;
    /// The caches of a run's partitions, stored in `parts`, encoded to `out` as the merged directory's
    /// ([`partitions`]).
    fn combine_into<W: Write>(parts: &[Stored], out: W) -> Result<W, PartitionsError>;
}

/// The shards a cache holds, by file name, with the content hash each had when it was read (the ledger's record).
pub type Held = BTreeMap<String, u64>;

/// Appends the shards `paths` to `cache`, in their order: for each, what was added (and the shard's content hash) or
/// why it was skipped. With `recorded` (a run's ledger: name -> content hash), a shard whose bytes do not hash to its
/// record, or that has none, is skipped. Shards are read on all cores, a chunk at a time, and appended in order, so
/// the result is that of reading them one by one. `progress(done, total)` before each chunk and at the end; `false`
/// stops before the next chunk (the result then has fewer entries than `paths`).
pub fn add_shards<C: Cached>(
    cache: &mut C,
    paths: &[PathBuf],
    settings: &C::Settings,
    recorded: Option<&Held>,
    mut progress: impl FnMut(usize, usize) -> bool,
) -> Vec<Result<(C::Added, u64), Skipped>> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut out = Vec::with_capacity(paths.len());
    for chunk in paths.chunks(C::CHUNK_PER_THREAD * threads) {
        if !progress(out.len(), paths.len()) {
            return out;
        }
        let read = dynforge_proto::parallel::map_in_order(chunk, |p| read_checked::<C>(p, settings, recorded));
        for (p, r) in chunk.iter().zip(read) {
            out.push(r.and_then(|(s, hash)| Ok((cache.append(p, s)?, hash))));
        }
    }
    progress(out.len(), paths.len());
    out
}

/// The shard `path` read for `C`, with its content hash, after the check against `recorded` (see [`add_shards`]).
fn read_checked<C: Cached>(
    path: &Path,
    settings: &C::Settings,
    recorded: Option<&Held>,
) -> Result<(C::Shard, u64), Skipped> {
    let bytes = std::fs::read(path).map_err(|e| Skipped::new(path, e))?;
    if let Some(recorded) = recorded {
        match recorded.get(&file_name(path)) {
            Some(&hash) => check_recorded(&bytes, path, hash)?,
            None => {
                return Err(Skipped::new(
                    path,
                    format!(
                        "not recorded done in the run's {LEDGER} (a generation still writing, or a file of another run)"
                    ),
                ));
            }
        }
    }
    Ok((C::read_shard(path, &bytes, settings)?, content_hash(&bytes)))
}

fn file_name(path: &Path) -> String {
    path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

/// A run directory's cache of one kind: from its file, or built from the shards.
#[derive(Debug)]
pub struct Loaded<C> {
    pub cache: C,
    /// Whether it came from its file.
    pub hit: bool,
    /// The shards it holds; `None` for a file written before caches recorded them (read only where the shards were
    /// pruned: anywhere else it is rebuilt).
    pub held: Option<Held>,
    /// Shards left out of a cache just built: it was then not written.
    pub skipped: Vec<Skipped>,
    /// Why a cache just built was not written, when it was not (shards skipped, the directory locked by another
    /// command).
    pub unwritten: Option<String>,
}

/// The cache of kind `C` of every shard the ledger of the `generate` directory `dir` records done: from its file if
/// current, else built (calling `progress(done, total)` per chunk of shards; `false` stops, an error, with nothing
/// cached) and, if no shard had to be skipped, written. `lock` is the directory's lock when the caller holds it
/// (`prepare`); without it the lock is taken for the write, and the cache is left unwritten when another command
/// holds it. Shards that cannot be read, are not dataset shards, or do not match the ledger are skipped and returned.
pub fn load_or_build<C: Cached>(
    dir: &Path,
    settings: &C::Settings,
    lock: Option<&RunLock>,
    progress: impl FnMut(usize, usize) -> bool,
) -> Result<Loaded<C>, CacheError> {
    let path = C::key(settings).path(dir)?;
    let io = |p: &Path| {
        let shown = p.display().to_string();
        move |source| CacheError::Io { path: shown.clone(), source }
    };
    let list = dir.join(PRUNED);
    let pruned = read_pruned(dir).map_err(io(&list))?;
    if let Some((mut cache, held)) = read_file::<C>(&path) {
        // A file from before caches recorded their shards is read only where nothing else is left.
        if held.is_some() || !pruned.is_empty() {
            cache.restore(settings);
            return Ok(Loaded { cache, hit: true, held, skipped: Vec::new(), unwritten: None });
        }
    }
    let recorded = recorded_shards(dir)?.unwrap_or_default();
    let shards = dir.join(SHARDS);
    let paths = list_shards(&shards).map_err(io(&shards))?;
    // After the listing: a prune records a shard in its list before deleting it, so a shard the listing missed
    // because a prune deleted it is in the list read now.
    check_not_pruned(dir, C::KIND)?;
    let mut cache = C::empty(settings);
    let added = add_shards(&mut cache, &paths, settings, Some(&recorded), progress);
    if added.len() < paths.len() {
        return Err(CacheError::Interrupted(dir.display().to_string()));
    }
    let mut held = Held::new();
    let mut skipped = Vec::new();
    for (p, r) in paths.iter().zip(added) {
        match r {
            Ok((_, hash)) => {
                held.insert(file_name(p), hash);
            }
            Err(s) => skipped.push(s),
        }
    }
    let listed: BTreeSet<String> = paths.iter().map(|p| file_name(p)).collect();
    for name in recorded.keys().filter(|n| !listed.contains(*n)) {
        let problem = "recorded done in the ledger, but missing (`dynforge verify --repair` then `generate` remake it)";
        skipped.push(Skipped::new(&shards.join(name), problem));
    }
    let unwritten = match skipped.len() {
        0 => write_cache(dir, &path, |f| encode_file(&cache, &held, f), lock)?,
        n => Some(format!("not cached: {n} shard(s) skipped")),
    };
    Ok(Loaded { cache, hit: false, held: Some(held), skipped, unwritten })
}

/// Writes the cache file `path` (its bytes written by `fill`) in the run directory `dir` holding its lock (`lock`,
/// else taken here: `Some(why)` instead of writing when another command holds it). Temporary files of killed cache
/// writers go first.
fn write_cache(
    dir: &Path,
    path: &Path,
    fill: impl FnOnce(File) -> io::Result<File>,
    lock: Option<&RunLock>,
) -> Result<Option<String>, CacheError> {
    let _taken = match lock {
        Some(_) => None,
        None => match RunLock::acquire(dir, Duration::ZERO, "cache write (train or evaluate)") {
            Ok(l) => Some(l),
            Err(e) => return Ok(Some(format!("not cached: {e}"))),
        },
    };
    let cache_dir = dir.join(CACHE);
    let io = |source| CacheError::Io { path: cache_dir.display().to_string(), source };
    std::fs::create_dir_all(&cache_dir).map_err(io)?;
    remove_temporaries(&cache_dir).map_err(io)?;
    dynforge_proto::run_dir::write_with(path, fill, |_, e| e)
        .map_err(|source| CacheError::Io { path: path.display().to_string(), source })?;
    Ok(None)
}

/// A cache file: [`FILE_MAGIC`], the length of the checksummed list of the shards it holds, the list, then the kind's
/// own encoding (checksummed itself: the list's check does not read the whole file).
const FILE_MAGIC: &[u8; 8] = b"DFCACHE2";
const HELD_MAGIC: &[u8; 8] = b"DFHELD01";

/// A cache file, written to `out`: the list of the shards `held`, then `cache`'s own encoding.
pub(crate) fn encode_file<C: Cached, W: Write>(cache: &C, held: &Held, out: W) -> io::Result<W> {
    cache.encode(held_prefix(held, out)?)
}

/// What comes before a kind's encoding in a cache file that holds the shards `held`.
fn held_prefix<W: Write>(held: &Held, mut out: W) -> io::Result<W> {
    let mut list = Encoder::new(Vec::with_capacity(held.len() * 48), HELD_MAGIC);
    list.u64s([held.len() as u64]);
    for (name, hash) in held {
        list.bytes(name.as_bytes()).u64s([*hash]);
    }
    let list = list.into_bytes();
    out.write_all(FILE_MAGIC)?;
    out.write_all(&(list.len() as u64).to_le_bytes())?;
    out.write_all(&list)?;
    Ok(out)
}

/// A cache file's content and held shards (`None` for the format before caches recorded them: the kind's encoding
/// alone); `None` unless intact.
pub(crate) fn read_file<C: Cached>(path: &Path) -> Option<(C, Option<Held>)> {
    let stored = Stored::open(path)?;
    let cache = C::decode(stored.reader().ok()?, stored.len)?;
    Some((cache, stored.held))
}

/// Where a cache file keeps its kind's encoding, and the shards it lists.
pub struct Stored {
    pub path: PathBuf,
    /// Where the kind's encoding starts in the file, and its length.
    offset: u64,
    len: u64,
    /// `None` for a file from before caches listed their shards.
    pub held: Option<Held>,
}

impl Stored {
    /// The layout of the cache file `path`; `None` if it cannot be read or its list of shards is not intact.
    pub fn open(path: &Path) -> Option<Stored> {
        let file = File::open(path).ok()?;
        let size = file.metadata().ok()?.len();
        let mut input = BufReader::new(file);
        let mut magic = [0; 8];
        input.read_exact(&mut magic).ok()?;
        let path = path.to_path_buf();
        if magic != *FILE_MAGIC {
            return Some(Stored { path, offset: 0, len: size, held: None });
        }
        let mut len = [0; 8];
        input.read_exact(&mut len).ok()?;
        // A damaged length claims no more than the file holds.
        let list = u64::from_le_bytes(len).min(size.saturating_sub(16));
        let mut d = Decoder::open((&mut input).take(list), list, HELD_MAGIC)?;
        let mut held = Held::new();
        for _ in 0..d.usize()? {
            let name = String::from_utf8(d.bytes()?).ok()?;
            held.insert(name, d.u64()?);
        }
        d.finish()?;
        let offset = list.checked_add(16)?;
        Some(Stored { path, offset, len: size.checked_sub(offset)?, held: Some(held) })
    }

    /// The kind's encoding, `len` bytes from the start of it.
    pub(crate) fn reader(&self) -> io::Result<io::Take<BufReader<File>>> {
        self.reader_at(0)
    }

    /// The kind's encoding from `at` bytes into it, to its end.
    pub(crate) fn reader_at(&self, at: u64) -> io::Result<io::Take<BufReader<File>>> {
        let mut input = BufReader::with_capacity(1 << 20, File::open(&self.path)?);
        input.seek(SeekFrom::Start(self.offset + at))?;
        Ok(input.take(self.len.saturating_sub(at)))
    }

    /// This part's cache, decoded whole; an error names the file.
    pub(crate) fn decode<C: Cached>(&self) -> Result<C, PartitionsError> {
        let damaged = || PartitionsError::Damaged(self.path.display().to_string(), C::KIND);
        C::decode(self.reader().map_err(|_| damaged())?, self.len).ok_or_else(damaged)
    }
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

/// The items of several partitions' lists (each the robot of every item), in merged order: (partition, items).
pub(crate) fn merged_order(parts: &[&[u64]]) -> Vec<(usize, std::ops::Range<usize>)> {
    let mut blocks = Vec::new();
    for (p, robots) in parts.iter().enumerate() {
        let mut start = 0;
        for i in 1..=robots.len() {
            if i == robots.len() || robots[i] != robots[start] {
                blocks.push((dynforge_proto::shard::robot_prefix(robots[start]), p, start..i));
                start = i;
            }
        }
    }
    blocks.sort_by(|a, b| a.0.cmp(&b.0));
    blocks.into_iter().map(|(_, p, r)| (p, r)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robots_merge_in_shard_name_order_blocks_kept_whole() {
        // Partition a: robots 999999 (two items) and 4; b: 1000000 and 100000. Shard names sort r000004 <
        // r100000-t < r1000000 < r999999: not numeric past six digits.
        let a = [999_999, 999_999, 4];
        let b = [1_000_000, 100_000, 100_000];
        let order = merged_order(&[&a, &b]);
        assert_eq!(order, vec![(0, 2..3), (1, 1..3), (1, 0..1), (0, 0..2)]);
        let mut names: Vec<String> = [999_999, 4, 1_000_000, 100_000]
            .iter()
            .map(|&r| dynforge_proto::shard::file_name(r, 0, "native"))
            .collect();
        names.sort();
        let robots = |p: usize, i: usize| if p == 0 { a[i] } else { b[i] };
        let by_order: Vec<String> =
            order.iter().map(|(p, r)| dynforge_proto::shard::file_name(robots(*p, r.start), 0, "native")).collect();
        assert_eq!(by_order, names);
    }
}
