//! The window cache: a run directory's preprocessed windows on disk, keyed by a hash of what determines them (the
//! run manifest, the ledger's records, the window geometry, the feature list and this format's version), reused
//! across trainer runs and rebuilt when any of these changes. Written atomically (temporary file, fsync, rename):
//! a crash mid-write leaves the previous state; a damaged file fails its checksum and is rebuilt.

use std::path::{Path, PathBuf};

use dynforge_proto::NUM_LABELS;
use dynforge_proto::run_dir::{CACHE, LEDGER, MANIFEST, SHARDS};
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

/// The key of a cache of the run directory `dir`: a hash of its manifest, its ledger's records (sorted: completion
/// order differs from run to run) and `preprocessing`, whatever else determines the cached values.
pub(crate) fn dataset_key(dir: &Path, preprocessing: &[u8]) -> Result<u64, ReadError> {
    let read_file = |name: &str| {
        std::fs::read(dir.join(name))
            .map_err(|e| ReadError::Content { file: dir.join(name).display().to_string(), problem: e.to_string() })
    };
    let mut material = read_file(MANIFEST)?;
    let ledger = String::from_utf8_lossy(&read_file(LEDGER)?).to_string();
    let mut lines: Vec<&str> = ledger.lines().collect();
    lines.sort_unstable();
    material.extend(lines.join("\n").bytes());
    material.extend(preprocessing);
    Ok(content_hash(&material))
}

fn key(dir: &Path, spec: &WindowSpec, features: &JacobianFeatures) -> Result<u64, ReadError> {
    let mut material = format!("|{}:{}:{}|{}|", spec.len, spec.stride, spec.ssr, GRID_DT).into_bytes();
    for e in &features.entries {
        material.extend(e.name.bytes());
    }
    material.extend(MAGIC);
    dataset_key(dir, &material)
}

fn encode(w: &CachedWindows) -> Vec<u8> {
    let mut e = Encoder::new(MAGIC, w.data.len() * 4 + w.labels.len() * (NUM_LABELS * 8 + 8));
    e.u64s([w.spec.len, w.spec.stride, w.spec.ssr, w.width, w.count()].map(|v| v as u64));
    e.f32s(&w.data).f64s(&w.labels.concat()).u64s(w.robots.iter().copied());
    e.finish()
}

fn decode(bytes: &[u8]) -> Option<CachedWindows> {
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
    Ok(dir.join(CACHE).join(format!("windows-{:016x}.bin", key(dir, spec, features)?)))
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
