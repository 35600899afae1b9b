//! From a recording (a shard, or a ROS 2 bag with its robot) to model-ready windows, and the statistics of a
//! dataset's shards.
//!
//! A window holds `L` time steps of `[q (n), qd (n), tau (n), Jacobian features (F)]`, f32, row-major.

use std::collections::BTreeMap;
use std::path::Path;

use dynforge_proto::NUM_LABELS;
use dynforge_robot::{Data, Model};

use dynforge_recording::dataset::list_shards;
use dynforge_recording::{GRID_DT, ReadError, Recording, read};

use crate::features::JacobianFeatures;
use crate::window::WindowSpec;

/// Width of a window row: q, qd, tau and the Jacobian features.
pub fn row_width(model: &Model, features: &JacobianFeatures) -> usize {
    3 * model.dof() + features.len()
}

/// All windows of a prepared recording, concatenated: `windows x L x row_width` values.
pub fn windows(p: &Recording, spec: &WindowSpec, features: &JacobianFeatures) -> (usize, Vec<f32>) {
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
    pub windows: BTreeMap<WindowSpec, usize>,
    /// Per label: (min, max).
    pub label_ranges: Vec<(f64, f64)>,
    /// Files that could not be read, with the reason.
    pub skipped: Vec<String>,
    /// The robot of the first readable shard (its kinematics define the feature list).
    pub model: Option<Model>,
}

impl Stats {
    /// Robots, trajectories, hours, the windows of each geometry in `specs` and the label ranges, as text.
    pub fn report(&self, specs: &[WindowSpec]) -> String {
        use std::fmt::Write as _;
        let mut out = format!("{} robots, {} trajectories, {:.2} h of motion\n", self.robots, self.shards, self.hours);
        out.push_str("windows (len x stride, ssr): window span, utilisation, count\n");
        for spec in specs {
            let _ = writeln!(
                out,
                "  {:>3} x {:>3}, ssr {:>3}{}: {:>6.3} s, {:>5.2} %, {}",
                spec.len,
                spec.stride,
                spec.ssr,
                if spec.overlaps() { format!(", hop {}", spec.hop) } else { String::new() },
                spec.span(GRID_DT),
                100.0 * spec.utilisation(),
                self.windows.get(spec).copied().unwrap_or(0)
            );
        }
        if self.shards > 0 {
            out.push_str("label ranges:\n");
            for (l, (lo, hi)) in dynforge_proto::LABELS.iter().zip(&self.label_ranges) {
                let _ = writeln!(out, "  {:<12} {:>12.6} .. {:<12.6} {}", l.name, lo, hi, l.kind.unit());
            }
        }
        out
    }
}

/// The window geometries `dataset stats` counts by default: the paper's grid around its best (64:64:16).
pub const AROUND_THE_BEST: [WindowSpec; 5] = [
    WindowSpec::new(32, 64, 16),
    WindowSpec::new(64, 32, 16),
    WindowSpec::new(64, 64, 16),
    WindowSpec::new(64, 64, 8),
    WindowSpec::new(128, 64, 16),
];

/// Statistics of every `*.mcap` in `dir` (a run directory's `shards/` or any folder of shards).
pub fn stats(dir: &Path, specs: &[WindowSpec]) -> Result<Stats, ReadError> {
    let paths = match dir.is_file() {
        true => vec![dir.to_path_buf()],
        false => list_shards(dir).map_err(|e| ReadError::Content {
            file: dynforge_recording::dataset::shard_dir(dir).display().to_string(),
            problem: e.to_string(),
        })?,
    };
    let mut s = Stats { label_ranges: vec![(f64::INFINITY, f64::NEG_INFINITY); NUM_LABELS], ..Stats::default() };
    let mut robots = std::collections::BTreeSet::new();
    for path in paths {
        let p = match read(&path, None) {
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
            *s.windows.entry(*spec).or_default() += spec.windows(p.trajectory.len()).len();
        }
        if let Some(y) = p.labels {
            for (range, v) in s.label_ranges.iter_mut().zip(y) {
                *range = (range.0.min(v), range.1.max(v));
            }
        }
    }
    if s.shards == 0 {
        let why = match s.skipped.first() {
            None => "it holds no .mcap file".to_string(),
            Some(first) => format!("none of its {} .mcap files is readable ({first})", s.skipped.len()),
        };
        return Err(ReadError::Content { file: dir.display().to_string(), problem: format!("no shards: {why}") });
    }
    s.robots = robots.len();
    Ok(s)
}
