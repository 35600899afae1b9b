//! The transformer's cache: every window of a dataset, preprocessed (`crate::windows`), with its labels and robot.

use std::io::{self, Read, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

use dynforge_proto::NUM_LABELS;
use dynforge_proto::lock::RunLock;
use dynforge_recording::{GRID_DT, read_shard_bytes};

use super::codec::{Decoder, Encoder};
use super::partitions::PartitionsError;
use super::{CacheError, CacheKey, Cached, CombineError, Loaded, Skipped, Stored};
use crate::features::JacobianFeatures;
use crate::split::{Origin, back_to_back, origins};
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
        origins(&self.robots, &self.trajectories, &self.spec)
    }

    /// Which windows are back to back ([`WindowSpec::back_to_back`]).
    pub fn back_to_back(&self) -> Vec<bool> {
        back_to_back(&self.robots, &self.trajectories, &self.spec)
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
        let mut material = format!("|{spec}|{GRID_DT}|").into_bytes();
        for e in &s.features.entries {
            material.extend(e.name.bytes());
        }
        material.extend(MAGIC);
        CacheKey::new(Self::KIND, &material)
    }

    fn empty(s: &WindowSettings) -> Self {
        CachedWindows::new(s.spec)
    }

    fn restore(&mut self, s: &WindowSettings) {
        self.spec = s.spec;
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

    fn encode<W: Write>(&self, out: W) -> io::Result<W> {
        let mut e = Encoder::new(out, MAGIC);
        e.u64s([self.spec.len, self.spec.stride, self.spec.ssr, self.width, self.count()].map(|v| v as u64));
        e.f32s(&self.data);
        self.labels.iter().for_each(|l| _ = e.f64s(l));
        e.u64s(self.robots.iter().copied()).u64s(self.trajectories.iter().map(|&t| t as u64));
        e.finish()
    }

    fn decode<R: Read>(input: R, len: u64) -> Option<Self> {
        let mut d = Decoder::open(input, len, MAGIC)?;
        let head = Head::read(&mut d)?;
        let data = d.f32s(head.values()?)?;
        let Index { labels, robots, trajectories } = Index::read(&mut d, head.count)?;
        d.finish()?;
        Some(CachedWindows { spec: head.spec, width: head.width, data, labels, robots, trajectories, hit: true })
    }

    /// Streamed: each part is read twice (its index and checksum, then its windows' values block by block in merged
    /// order, copied as they are), so the merge of the paper's 8,192 robots holds only the parts' labels in memory.
    fn combine_into<W: Write>(parts: &[Stored], out: W) -> Result<W, PartitionsError> {
        let damaged = |s: &Stored| PartitionsError::Damaged(s.path.display().to_string(), Self::KIND);
        let mut heads = Vec::new();
        let mut indices = Vec::new();
        for s in parts {
            let read = |input| {
                let mut d = Decoder::open(input, s.len, MAGIC)?;
                let head = Head::read(&mut d)?;
                d.pass(head.values()?.checked_mul(4)?, |_| {})?;
                let index = Index::read(&mut d, head.count)?;
                d.finish().map(|_| (head, index))
            };
            let (head, index) = s.reader().ok().and_then(read).ok_or_else(|| damaged(s))?;
            if let Some(first) = heads.first().filter(|f: &&Head| f.width != head.width) {
                let problem = format!("windows of {} and {} values per step", first.width, head.width);
                return Err(PartitionsError::Combine { kind: Self::KIND, source: CombineError(problem) });
            }
            heads.push(head);
            indices.push(index);
        }
        let spec = heads.first().map_or(WindowSpec::default(), |h| h.spec);
        let width = heads.first().map_or(0, |h| h.width);
        let count: usize = heads.iter().map(|h| h.count).sum();
        let mut e = Encoder::new(out, MAGIC);
        e.u64s([spec.len, spec.stride, spec.ssr, width, count].map(|v| v as u64));
        let order = super::merged_order(&indices.iter().map(|i| &i.robots[..]).collect::<Vec<_>>());
        let window_bytes = (spec.len * width * 4) as u64;
        let mut buffer = vec![0; 1 << 16];
        for (p, items) in &order {
            let s = &parts[*p];
            let mut input = s.reader_at(Head::BYTES + items.start as u64 * window_bytes).map_err(|_| damaged(s))?;
            let mut rest = items.len() as u64 * window_bytes;
            while rest > 0 {
                let k = rest.min(buffer.len() as u64) as usize;
                input.read_exact(&mut buffer[..k]).map_err(|_| damaged(s))?;
                e.raw(&buffer[..k]);
                rest -= k as u64;
            }
        }
        for (p, items) in &order {
            indices[*p].labels[items.clone()].iter().for_each(|l| _ = e.f64s(l));
        }
        for (p, items) in &order {
            e.u64s(indices[*p].robots[items.clone()].iter().copied());
        }
        for (p, items) in &order {
            e.u64s(indices[*p].trajectories[items.clone()].iter().map(|&t| t as u64));
        }
        e.finish().map_err(PartitionsError::Write)
    }
}

/// What precedes a window cache's values.
struct Head {
    spec: WindowSpec,
    width: usize,
    count: usize,
}

impl Head {
    /// The magic and five numbers.
    const BYTES: u64 = 8 + 5 * 8;

    fn read<R: Read>(d: &mut Decoder<R>) -> Option<Head> {
        let (len, stride, ssr, width, count) = (d.usize()?, d.usize()?, d.usize()?, d.usize()?, d.usize()?);
        Some(Head { spec: WindowSpec::new(len, stride, ssr), width, count })
    }

    /// The values of all windows.
    fn values(&self) -> Option<usize> {
        self.count.checked_mul(self.spec.len)?.checked_mul(self.width)
    }
}

/// What follows a window cache's values: per window, its labels, robot and trajectory.
struct Index {
    labels: Vec<[f64; NUM_LABELS]>,
    robots: Vec<u64>,
    trajectories: Vec<u32>,
}

impl Index {
    fn read<R: Read>(d: &mut Decoder<R>, count: usize) -> Option<Index> {
        let labels = d.label_rows(count)?;
        let robots = d.u64s(count)?;
        let trajectories = d.u64s(count)?.into_iter().map(u32::try_from).collect::<Result<_, _>>().ok()?;
        Some(Index { labels, robots, trajectories })
    }
}
