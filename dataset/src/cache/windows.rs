//! The transformer's cache: every window of a dataset, preprocessed (`crate::windows`), with its labels and robot.

use std::ops::Range;
use std::path::{Path, PathBuf};

use dynforge_proto::NUM_LABELS;
use dynforge_proto::lock::RunLock;
use dynforge_recording::{GRID_DT, read_shard_bytes};

use super::codec::{Decoder, Encoder};
use super::{CacheError, CacheKey, Cached, CombineError, Loaded, Skipped};
use crate::features::JacobianFeatures;
use crate::split::{Origin, origins};
use crate::window::WindowSpec;
use crate::windows::{row_width, windows};

const MAGIC: &[u8; 8] = b"DFWIN002";

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
    /// Per window, its robot's trajectory index (the recording it was cut from).
    pub trajectories: Vec<u32>,
    /// Whether this came from the cache file.
    pub hit: bool,
}

/// What determines a window cache besides the dataset.
#[derive(Debug, Clone)]
pub struct WindowSettings {
    pub spec: WindowSpec,
    pub features: JacobianFeatures,
}

/// One shard's windows, before they join a [`CachedWindows`].
pub struct ShardWindows {
    robot: u64,
    trajectory: u32,
    labels: [f64; NUM_LABELS],
    width: usize,
    count: usize,
    data: Vec<f32>,
}

impl CachedWindows {
    pub fn new(spec: WindowSpec) -> Self {
        CachedWindows {
            spec,
            width: 0,
            data: Vec::new(),
            labels: Vec::new(),
            robots: Vec::new(),
            trajectories: Vec::new(),
            hit: false,
        }
    }

    /// Where each window comes from.
    pub fn origins(&self) -> Vec<Origin> {
        origins(&self.robots, &self.trajectories, self.spec.offsets().count())
    }

    pub fn count(&self) -> usize {
        self.labels.len()
    }

    /// The windows of every shard of the `generate` directory `dir` (see [`super::load_or_build`]), with the shards
    /// that had to be skipped.
    pub fn load_or_build(
        dir: &Path,
        spec: &WindowSpec,
        features: &JacobianFeatures,
        progress: impl FnMut(usize, usize) -> bool,
    ) -> Result<(Self, Vec<Skipped>), CacheError> {
        Self::load(dir, spec, features, None, progress).map(|l| (l.cache, l.skipped))
    }

    /// [`Self::load_or_build`] with all it found out, by the holder of `dir`'s lock `lock` if given.
    pub fn load(
        dir: &Path,
        spec: &WindowSpec,
        features: &JacobianFeatures,
        lock: Option<&RunLock>,
        progress: impl FnMut(usize, usize) -> bool,
    ) -> Result<Loaded<Self>, CacheError> {
        super::load_or_build(dir, &WindowSettings { spec: *spec, features: features.clone() }, lock, progress)
    }

    /// Appends the windows of the dataset shards `paths` (see [`super::add_shards`]): for each shard its robot and
    /// the indices of its new windows, or why it was skipped.
    pub fn add_shards(
        &mut self,
        paths: &[PathBuf],
        features: &JacobianFeatures,
    ) -> Vec<Result<(u64, Range<usize>), Skipped>> {
        let settings = WindowSettings { spec: self.spec, features: features.clone() };
        super::add_shards(self, paths, &settings, None, |_, _| true).into_iter().map(|r| r.map(|(a, _)| a)).collect()
    }
}

/// Cache file of a run directory for this preprocessing.
pub fn cache_path(dir: &Path, spec: &WindowSpec, features: &JacobianFeatures) -> Result<PathBuf, CacheError> {
    let settings = WindowSettings { spec: *spec, features: features.clone() };
    Ok(CachedWindows::key(&settings).path(dir)?)
}

impl Cached for CachedWindows {
    const KIND: &'static str = "windows";
    const CHUNK_PER_THREAD: usize = 16;
    type Settings = WindowSettings;
    type Shard = ShardWindows;
    type Added = (u64, Range<usize>);

    fn key(s: &WindowSettings) -> CacheKey {
        let spec = &s.spec;
        let mut material = format!("|{}:{}:{}|{}|", spec.len, spec.stride, spec.ssr, GRID_DT).into_bytes();
        for e in &s.features.entries {
            material.extend(e.name.bytes());
        }
        material.extend(MAGIC);
        CacheKey::new(Self::KIND, &material)
    }

    fn empty(s: &WindowSettings) -> Self {
        CachedWindows::new(s.spec)
    }

    fn read_shard(path: &Path, bytes: &[u8], s: &WindowSettings) -> Result<ShardWindows, Skipped> {
        let prep = read_shard_bytes(bytes, path, None)?;
        let (Some(labels), Some(robot), Some(trajectory)) = (prep.labels, prep.robot, prep.trajectory_index) else {
            return Err(Skipped::new(path, "no labels, robot or trajectory index (not a dataset shard)"));
        };
        let width = row_width(&prep.model, &s.features);
        let (count, data) = windows(&prep, &s.spec, &s.features);
        Ok(ShardWindows { robot, trajectory, labels, width, count, data })
    }

    fn append(&mut self, path: &Path, w: ShardWindows) -> Result<(u64, Range<usize>), Skipped> {
        if self.count() > 0 && w.width != self.width {
            let problem = format!("{} values per step, the dataset has {}", w.width, self.width);
            return Err(Skipped::new(path, problem));
        }
        self.width = w.width;
        let start = self.count();
        self.data.extend(w.data);
        self.labels.extend(std::iter::repeat_n(w.labels, w.count));
        self.robots.extend(std::iter::repeat_n(w.robot, w.count));
        self.trajectories.extend(std::iter::repeat_n(w.trajectory, w.count));
        Ok((w.robot, start..start + w.count))
    }

    fn encode(&self) -> Vec<u8> {
        let mut e = Encoder::new(MAGIC, self.data.len() * 4 + self.labels.len() * (NUM_LABELS * 8 + 8));
        e.u64s([self.spec.len, self.spec.stride, self.spec.ssr, self.width, self.count()].map(|v| v as u64));
        e.f32s(&self.data).f64s(&self.labels.concat()).u64s(self.robots.iter().copied());
        e.u64s(self.trajectories.iter().map(|&t| t as u64));
        e.finish()
    }

    fn decode(bytes: &[u8]) -> Option<Self> {
        let mut d = Decoder::open(bytes, MAGIC)?;
        let (len, stride, ssr, width, count) = (d.usize()?, d.usize()?, d.usize()?, d.usize()?, d.usize()?);
        let data = d.f32s(count.checked_mul(len)?.checked_mul(width)?)?;
        let labels = d.label_rows(count)?;
        let robots = d.u64s(count)?;
        let trajectories = d.u64s(count)?.into_iter().map(u32::try_from).collect::<Result<_, _>>().ok()?;
        d.done().then_some(CachedWindows {
            spec: WindowSpec { len, stride, ssr },
            width,
            data,
            labels,
            robots,
            trajectories,
            hit: true,
        })
    }

    fn combine(parts: &[CachedWindows]) -> Result<CachedWindows, CombineError> {
        let mut out = CachedWindows::new(parts.first().map_or(WindowSpec::default(), |p| p.spec));
        let robots: Vec<&[u64]> = parts.iter().map(|p| &p.robots[..]).collect();
        for (p, items) in super::merged_order(&robots) {
            let part = &parts[p];
            if out.count() > 0 && part.width != out.width {
                return Err(CombineError(format!("windows of {} and {} values per step", part.width, out.width)));
            }
            out.width = part.width;
            let step = out.spec.len * part.width;
            out.data.extend_from_slice(&part.data[items.start * step..items.end * step]);
            out.labels.extend_from_slice(&part.labels[items.clone()]);
            out.robots.extend_from_slice(&part.robots[items.clone()]);
            out.trajectories.extend_from_slice(&part.trajectories[items]);
        }
        Ok(out)
    }
}
