//! From a shard (or a ROS 2 bag with its robot) to model-ready windows: the stages of this module chained.
//!
//! A window holds `L` time steps of `[q (n), qd (n), tau (n), Jacobian features (F)]`, f32, row-major.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dynforge_proto::shard::{META_JOB, META_LABELS};
use dynforge_proto::{LABELS, NUM_LABELS};
use dynforge_robot::{Data, Model, urdf};

use super::features::JacobianFeatures;
use super::resample::resample;
use super::source::{JointTrajectory, from_bag};
use super::window::WindowSpec;

/// Source samples per second of the unified grid (the simulator's and the paper's 1 kHz).
pub const GRID_DT: f64 = 1e-3;

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error(transparent)]
    Shard(#[from] dynforge_shard::ShardError),
    #[error(transparent)]
    Source(#[from] super::source::SourceError),
    #[error("{file}: {problem}")]
    Content { file: String, problem: String },
}

/// A recording ready for windowing: the robot, its trajectory on the 1 kHz grid, and its labels if it has them.
#[derive(Debug, Clone)]
pub struct Prepared {
    pub path: PathBuf,
    pub model: Model,
    pub trajectory: JointTrajectory,
    /// The 38 labels (dataset shards; a user's bag has none).
    pub labels: Option<[f64; NUM_LABELS]>,
    /// Robot id within its dataset (shards only).
    pub robot: Option<u64>,
}

/// Reads a shard or bag; the robot comes from its `/robot_description` unless `model` is given.
pub fn prepare(path: &Path, model: Option<&Model>) -> Result<Prepared, DataError> {
    let file = path.display().to_string();
    let content = |problem: String| DataError::Content { file: file.clone(), problem };
    let bag = dynforge_shard::read(path)?;
    let model = match (model, &bag.robot_description) {
        (Some(m), _) => m.clone(),
        (None, Some(text)) => {
            urdf::parse(text, &format!("{file} (/robot_description)")).map_err(|e| content(e.to_string()))?
        }
        (None, None) => return Err(content("no /robot_description in the file: give the robot's URDF".into())),
    };
    let names: Vec<String> = model.joints().iter().map(|j| j.name.clone()).collect();
    let trajectory = resample(&from_bag(&bag, &names, path)?, GRID_DT);
    let labels = match bag.metadata.get(META_LABELS) {
        Some(map) => {
            let mut y = [0.0; NUM_LABELS];
            for (v, l) in y.iter_mut().zip(LABELS.iter()) {
                *v = map
                    .get(l.name)
                    .and_then(|s| s.parse().ok())
                    .ok_or_else(|| content(format!("label {} missing", l.name)))?;
            }
            Some(y)
        }
        None => None,
    };
    let robot = bag.metadata.get(META_JOB).and_then(|m| m.get("robot")).and_then(|r| r.parse().ok());
    Ok(Prepared { path: path.to_path_buf(), model, trajectory, labels, robot })
}

/// The robot of a dataset directory: that of its first readable shard (every shard of a dataset shares the
/// kinematics, which is all the features depend on).
pub fn dataset_robot(dir: &Path) -> Result<Model, DataError> {
    let shards = super::follow::shard_dir(dir);
    let paths = super::follow::list_shards(&shards)
        .map_err(|e| DataError::Content { file: shards.display().to_string(), problem: e.to_string() })?;
    let mut last = None;
    for p in &paths {
        match prepare(p, None) {
            Ok(prep) => return Ok(prep.model),
            Err(e) => last = Some(e),
        }
    }
    Err(last.unwrap_or_else(|| DataError::Content {
        file: shards.display().to_string(),
        problem: "no shards (generate a dataset with `dynforge generate` first)".into(),
    }))
}

/// Width of a window row: q, qd, tau and the Jacobian features.
pub fn row_width(model: &Model, features: &JacobianFeatures) -> usize {
    3 * model.dof() + features.len()
}

/// All windows of a prepared recording, concatenated: `windows x L x row_width` values.
pub fn windows(p: &Prepared, spec: &WindowSpec, features: &JacobianFeatures) -> (usize, Vec<f32>) {
    let n = p.model.dof();
    let width = row_width(&p.model, features);
    let list = spec.windows(p.trajectory.len());
    let mut out = Vec::with_capacity(list.len() * spec.len * width);
    let mut data = Data::new(&p.model);
    let mut jac = Vec::with_capacity(features.len());
    let t = &p.trajectory;
    for w in &list {
        for i in spec.indices(w) {
            let row = i * n..(i + 1) * n;
            out.extend(t.q[row.clone()].iter().map(|v| *v as f32));
            out.extend(t.qd[row.clone()].iter().map(|v| *v as f32));
            out.extend(t.tau[row.clone()].iter().map(|v| *v as f32));
            features.evaluate(&p.model, &mut data, &t.q[row], &mut jac);
            out.extend(jac.iter().map(|v| *v as f32));
        }
    }
    (list.len(), out)
}

/// What `dataset stats` reports.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    pub shards: usize,
    pub robots: usize,
    pub hours: f64,
    /// Windows per window geometry.
    pub windows: BTreeMap<(usize, usize, usize), usize>,
    /// Per label: (min, max).
    pub label_ranges: Vec<(f64, f64)>,
    /// Files that could not be read, with the reason.
    pub skipped: Vec<String>,
    /// The robot of the first readable shard (its kinematics define the feature list).
    pub model: Option<Model>,
}

/// Statistics of every `*.mcap` in `dir` (a run directory's `shards/` or any folder of shards).
pub fn stats(dir: &Path, specs: &[WindowSpec]) -> Result<Stats, DataError> {
    let paths = super::follow::list_shards(dir).map_err(|e| DataError::Content {
        file: super::follow::shard_dir(dir).display().to_string(),
        problem: e.to_string(),
    })?;
    let mut s = Stats { label_ranges: vec![(f64::INFINITY, f64::NEG_INFINITY); NUM_LABELS], ..Stats::default() };
    let mut robots = std::collections::BTreeSet::new();
    for path in paths {
        let p = match prepare(&path, None) {
            Ok(p) => p,
            Err(e) => {
                s.skipped.push(e.to_string());
                continue;
            }
        };
        s.shards += 1;
        if s.model.is_none() {
            s.model = Some(p.model.clone());
        }
        s.hours += p.trajectory.len() as f64 * GRID_DT / 3600.0;
        if let Some(r) = p.robot {
            robots.insert(r);
        }
        for spec in specs {
            *s.windows.entry((spec.len, spec.stride, spec.ssr)).or_default() += spec.windows(p.trajectory.len()).len();
        }
        if let Some(y) = p.labels {
            for (range, v) in s.label_ranges.iter_mut().zip(y) {
                *range = (range.0.min(v), range.1.max(v));
            }
        }
    }
    s.robots = robots.len();
    Ok(s)
}
