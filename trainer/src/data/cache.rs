//! The window cache: a run directory's preprocessed windows on disk, keyed by a hash of what determines them (the
//! run manifest, the ledger's records, the window geometry, the feature list and this format's version: [`CacheKey`]),
//! reused across trainer runs and rebuilt when any of these changes. Written atomically (temporary file, fsync, rename):
//! a crash mid-write leaves the previous state; a damaged file fails its checksum and is rebuilt.

use std::path::{Path, PathBuf};

use dynforge_proto::NUM_LABELS;
use dynforge_proto::run_dir::{CACHE, LEDGER, MANIFEST, PRUNED, SHARDS, read_pruned};
use dynforge_shard::content_hash;

use dynforge_recording::dataset::list_shards;
use dynforge_recording::{GRID_DT, ReadError, read};

use super::codec::{Decoder, Encoder};
use super::dataset::{row_width, windows};
use super::features::JacobianFeatures;
use super::window::WindowSpec;

const MAGIC: &[u8; 8] = b"DFWIN001";

/// Windows of a whole dataset, with one label vector and robot id per window.
#[derive(Debug, Clone, PartialEq)]
pub struct CachedWindows {
    pub spec: WindowSpec,
    /// Values per time step of a window.
    pub width: usize,
    /// `count x len x width` values.
    pub data: Vec<f32>,
    pub labels: Vec<[f64; NUM_LABELS]>,
    pub robots: Vec<u64>,
    /// Whether this came from the cache file.
    pub hit: bool,
}

impl CachedWindows {
    pub fn count(&self) -> usize {
        self.labels.len()
    }

    /// Appends the windows of the dataset shards `paths`, in their order; for each shard, its robot and the
    /// indices of its new windows, or why it was skipped (unreadable, not a dataset shard, or another row width
    /// than the windows held). Shards are read and windowed on all cores, a chunk at a time, and appended in
    /// order, so the result is the same as reading them one by one. `progress(done, total)` before each chunk and at the
    /// end; `false` stops before the next chunk (the result then has fewer entries than `paths`).
    pub fn add_shards(
        &mut self,
        paths: &[PathBuf],
        features: &JacobianFeatures,
        mut progress: impl FnMut(usize, usize) -> bool,
    ) -> Vec<Result<(u64, std::ops::Range<usize>), String>> {
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let spec = self.spec;
        let mut out = Vec::with_capacity(paths.len());
        for chunk in paths.chunks(16 * threads) {
            if !progress(out.len(), paths.len()) {
                return out;
            }
            let read = crate::parallel::map_in_order(chunk, |p| read_shard(p, &spec, features));
            for (p, r) in chunk.iter().zip(read) {
                out.push(r.and_then(|w| self.append(p, w)));
            }
        }
        progress(out.len(), paths.len());
        out
    }

    /// The windows of a run's partitions as one (`crate::data::partitions`), in merged order.
    pub(crate) fn combine(parts: &[CachedWindows]) -> Result<CachedWindows, String> {
        let spec = parts.first().map_or(WindowSpec::default(), |p| p.spec);
        let mut out =
            CachedWindows { spec, width: 0, data: Vec::new(), labels: Vec::new(), robots: Vec::new(), hit: false };
        let robots: Vec<&[u64]> = parts.iter().map(|p| &p.robots[..]).collect();
        for (p, items) in super::partitions::merged_order(&robots) {
            let part = &parts[p];
            if out.count() > 0 && part.width != out.width {
                return Err(format!("windows of {} and {} values per step", part.width, out.width));
            }
            out.width = part.width;
            let step = spec.len * part.width;
            out.data.extend_from_slice(&part.data[items.start * step..items.end * step]);
            out.labels.extend_from_slice(&part.labels[items.clone()]);
            out.robots.extend_from_slice(&part.robots[items]);
        }
        Ok(out)
    }

    fn append(&mut self, path: &Path, w: ShardWindows) -> Result<(u64, std::ops::Range<usize>), String> {
        if self.count() > 0 && w.width != self.width {
            return Err(format!("{}: {} values per step, the dataset has {}", path.display(), w.width, self.width));
        }
        self.width = w.width;
        let start = self.count();
        self.data.extend(w.data);
        self.labels.extend(std::iter::repeat_n(w.labels, w.count));
        self.robots.extend(std::iter::repeat_n(w.robot, w.count));
        Ok((w.robot, start..start + w.count))
    }
}

/// One shard's windows, before they join a [`CachedWindows`].
struct ShardWindows {
    robot: u64,
    labels: [f64; NUM_LABELS],
    width: usize,
    count: usize,
    data: Vec<f32>,
}

fn read_shard(path: &Path, spec: &WindowSpec, features: &JacobianFeatures) -> Result<ShardWindows, String> {
    let prep = read(path, None).map_err(|e| e.to_string())?;
    let (Some(labels), Some(robot)) = (prep.labels, prep.robot) else {
        return Err(format!("{}: no labels or robot id (not a dataset shard)", path.display()));
    };
    let width = row_width(&prep.model, features);
    let (count, data) = windows(&prep, spec, features);
    Ok(ShardWindows { robot, labels, width, count, data })
}

/// Names a cache file of a run directory: `KIND-PPPPPPPPPPPPPPPP-DDDDDDDDDDDDDDDD.bin`, where P hashes the
/// preprocessing (whatever besides the data determines the cached values) and D the dataset (its manifest and its
/// ledger's records, sorted: completion order differs from run to run). Kept apart, so that the partitions of one
/// run, prepared alike, show which of their caches go together (same kind and P) when they are merged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) struct CacheKey {
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
pub(crate) fn check_not_pruned(dir: &Path, what: &str) -> Result<(), ReadError> {
    let pruned = read_pruned(dir)
        .map_err(|e| ReadError::Content { file: dir.join(PRUNED).display().to_string(), problem: e.to_string() })?;
    if pruned.is_empty() {
        return Ok(());
    }
    let mut held: Vec<String> = std::fs::read_dir(dir.join(CACHE))
        .map(|l| l.filter_map(Result::ok).map(|e| e.file_name().to_string_lossy().to_string()).collect())
        .unwrap_or_default();
    held.sort();
    Err(ReadError::Content {
        file: dir.display().to_string(),
        problem: format!(
            "{} shards were pruned ({PRUNED}): their data are only in the caches, and no intact {what} cache for \
             these settings is current (cache/ holds: {}). Use the settings the directory was prepared with, or \
             delete {PRUNED} and rerun its `dynforge generate` command to remake the shards",
            pruned.len(),
            if held.is_empty() { "nothing".to_string() } else { held.join(", ") }
        ),
    })
}

pub(crate) const KIND: &str = "windows";

fn key(spec: &WindowSpec, features: &JacobianFeatures) -> CacheKey {
    let mut material = format!("|{}:{}:{}|{}|", spec.len, spec.stride, spec.ssr, GRID_DT).into_bytes();
    for e in &features.entries {
        material.extend(e.name.bytes());
    }
    material.extend(MAGIC);
    CacheKey::new(KIND, &material)
}

pub(crate) fn encode(w: &CachedWindows) -> Vec<u8> {
    let mut e = Encoder::new(MAGIC, w.data.len() * 4 + w.labels.len() * (NUM_LABELS * 8 + 8));
    e.u64s([w.spec.len, w.spec.stride, w.spec.ssr, w.width, w.count()].map(|v| v as u64));
    e.f32s(&w.data).f64s(&w.labels.concat()).u64s(w.robots.iter().copied());
    e.finish()
}

pub(crate) fn decode(bytes: &[u8]) -> Option<CachedWindows> {
    let mut d = Decoder::open(bytes, MAGIC)?;
    let (len, stride, ssr, width, count) = (d.usize()?, d.usize()?, d.usize()?, d.usize()?, d.usize()?);
    let data = d.f32s(count.checked_mul(len)?.checked_mul(width)?)?;
    let flat = d.f64s(count.checked_mul(NUM_LABELS)?)?;
    let labels = flat.chunks_exact(NUM_LABELS).map(|c| c.try_into().expect("38")).collect();
    let robots = d.u64s(count)?;
    d.done().then_some(CachedWindows { spec: WindowSpec { len, stride, ssr }, width, data, labels, robots, hit: true })
}

/// Cache file of a run directory for this preprocessing.
pub fn cache_path(dir: &Path, spec: &WindowSpec, features: &JacobianFeatures) -> Result<PathBuf, ReadError> {
    key(spec, features).path(dir)
}

/// The windows of every shard of the `generate` directory `dir`: from the cache if it is current, else built
/// (calling `progress(done, total)` per group of shards; `false` stops, an error, with nothing cached) and cached.
/// Shards that cannot be read are skipped and returned.
pub fn load_or_build(
    dir: &Path,
    spec: &WindowSpec,
    features: &JacobianFeatures,
    mut progress: impl FnMut(usize, usize) -> bool,
) -> Result<(CachedWindows, Vec<String>), ReadError> {
    let path = cache_path(dir, spec, features)?;
    if let Some(w) = std::fs::read(&path).ok().and_then(|b| decode(&b)) {
        return Ok((w, Vec::new()));
    }
    check_not_pruned(dir, KIND)?;
    let io = |p: &Path| {
        let shown = p.display().to_string();
        move |e: std::io::Error| ReadError::Content { file: shown.clone(), problem: e.to_string() }
    };
    let shards = dir.join(SHARDS);
    let paths = list_shards(&shards).map_err(io(&shards))?;
    let mut out =
        CachedWindows { spec: *spec, width: 0, data: Vec::new(), labels: Vec::new(), robots: Vec::new(), hit: false };
    let added = out.add_shards(&paths, features, &mut progress);
    if added.len() < paths.len() {
        let problem = "interrupted while reading the shards; nothing was cached".to_string();
        return Err(ReadError::Content { file: dir.display().to_string(), problem });
    }
    let skipped = added.into_iter().filter_map(Result::err).collect();
    let cache_dir = dir.join(CACHE);
    std::fs::create_dir_all(&cache_dir).map_err(io(&cache_dir))?;
    dynforge_proto::run_dir::write_atomic(&path, &encode(&out)).map_err(io(&path))?;
    Ok((out, skipped))
}
