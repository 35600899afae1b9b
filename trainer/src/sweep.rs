//! The paper's two ablations, trained and scored at a chosen scale: the dataset grid (sequence length x stride x
//! SSR, fixed architecture) and the architecture grid (layers x heads x embedding of the transformer, fixed dataset
//! configuration), written as the paper's two tables with its values beside ours (`sweep.md`, `sweep.json`). A
//! configuration the dataset cannot serve becomes a row saying why, and the grid goes on; a rerun resumes.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use serde::Serialize;

use crate::checkpoint::Checkpoint;
use crate::data::window::WindowSpec;
use crate::evaluation::evaluate_checkpoint;
use crate::model::NetworkConfig;
use crate::training::resumable;
use crate::training::session::{ModelKind, Recipe, Session, SessionError, SessionObserver};

/// The paper's dataset grid: (sequence length, stride, SSR, its validation R2).
pub const DATASET_GRID: [(usize, usize, usize, f64); 16] = [
    (16, 32, 8, 0.7880),
    (16, 64, 16, 0.8090),
    (16, 128, 32, 0.8333),
    (16, 256, 32, 0.8446),
    (32, 32, 8, 0.8134),
    (32, 64, 16, 0.8428),
    (32, 128, 128, 0.8383),
    (64, 32, 8, 0.8328),
    (64, 32, 16, 0.8331),
    (64, 64, 16, 0.8633),
    (64, 64, 32, 0.8592),
    (64, 64, 64, 0.8571),
    (128, 16, 8, 0.8181),
    (128, 32, 8, 0.8451),
    (128, 32, 16, 0.8459),
    (128, 64, 16, 0.8479),
];

/// The paper's architecture grid: (layers, heads, embedding, its validation R2 and RMSE).
pub const ARCHITECTURE_GRID: [(usize, usize, usize, f64, f64); 4] = [
    (2, 16, 256, 0.8460, 0.1185),
    (4, 16, 128, 0.8555, 0.1148),
    (4, 32, 128, 0.8633, 0.1116),
    (8, 32, 128, 0.8410, 0.1200),
];

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Grid {
    Dataset,
    Architecture,
    Both,
}

#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub name: String,
    pub len: usize,
    pub stride: usize,
    pub ssr: usize,
    pub layers: usize,
    pub heads: usize,
    pub dim: usize,
    pub r2: f64,
    pub rmse: f64,
    pub train_seconds: f64,
    /// CPU seconds of the training steps (all threads): the cost side of accuracy per CPU-hour.
    pub cpu_seconds: f64,
    pub windows: usize,
    pub paper_r2: f64,
    pub paper_rmse: Option<f64>,
    /// Why the configuration was not trained (e.g. windows longer than the recordings); its scores are NaN.
    pub skipped: Option<String>,
}

/// A sweep over `data` into `out`: one checkpoint per configuration (`out/NAME`), `base` for everything a grid does
/// not set (the architecture grid trains transformers).
pub struct Sweep<'a> {
    pub data: &'a Path,
    pub out: &'a Path,
    pub grid: Grid,
    pub base: &'a Recipe,
    pub stop: &'a AtomicBool,
}

impl Sweep<'_> {
    /// Runs the grids and returns the tables (markdown), also written to `out/sweep.md` and `out/sweep.json`.
    pub fn run(&self, observer: &mut dyn SessionObserver) -> Result<String, SessionError> {
        std::fs::create_dir_all(self.out).map_err(|e| self.io(e))?;
        let (mut dataset, mut arch) = (Vec::new(), Vec::new());
        if self.grid != Grid::Architecture {
            for (len, stride, ssr, paper) in DATASET_GRID {
                let recipe = Recipe { window: WindowSpec { len, stride, ssr }, ..self.base.clone() };
                dataset.push(self.one(&format!("dataset-L{len}-s{stride}-r{ssr}"), recipe, (paper, None), observer)?);
                self.write(&dataset, &arch)?;
            }
        }
        if self.grid != Grid::Dataset {
            for (layers, heads, dim, paper, paper_rmse) in ARCHITECTURE_GRID {
                let mut recipe = Recipe { window: WindowSpec::default(), ..self.base.clone() };
                recipe.model.kind = ModelKind::Transformer;
                (recipe.model.layers, recipe.model.heads, recipe.model.dim) = (Some(layers), Some(heads), Some(dim));
                arch.push(self.one(
                    &format!("arch-{layers}x{heads}x{dim}"),
                    recipe,
                    (paper, Some(paper_rmse)),
                    observer,
                )?);
                self.write(&dataset, &arch)?;
            }
        }
        self.write(&dataset, &arch)
    }

    fn io(&self, e: impl std::fmt::Display) -> SessionError {
        SessionError::Setup(format!("{}: {e}", self.out.display()))
    }

    /// Trains and scores one configuration; one the dataset cannot serve becomes a row saying why. An interruption
    /// stops the sweep.
    fn one(
        &self,
        name: &str,
        recipe: Recipe,
        paper: (f64, Option<f64>),
        observer: &mut dyn SessionObserver,
    ) -> Result<Row, SessionError> {
        let shape = recipe.model.transformer(1, recipe.window.len);
        let w = recipe.window;
        let planned = Row {
            name: name.into(),
            len: w.len,
            stride: w.stride,
            ssr: w.ssr,
            layers: shape.layers,
            heads: shape.heads,
            dim: shape.d_model,
            r2: f64::NAN,
            rmse: f64::NAN,
            train_seconds: 0.0,
            cpu_seconds: 0.0,
            windows: 0,
            paper_r2: paper.0,
            paper_rmse: paper.1,
            skipped: None,
        };
        observer.message(&format!("== {name}"));
        match self.train_and_score(&planned, &recipe, observer) {
            Ok(row) => Ok(row),
            Err(e) if self.stop.load(Ordering::Relaxed) => Err(e),
            Err(e) => {
                observer.message(&format!("warning: {name} not run: {e}"));
                Ok(Row { skipped: Some(e.to_string()), ..planned })
            }
        }
    }

    fn train_and_score(
        &self,
        planned: &Row,
        recipe: &Recipe,
        observer: &mut dyn SessionObserver,
    ) -> Result<Row, SessionError> {
        let out = self.out.join(&planned.name);
        let started = Instant::now();
        let session =
            Session { data: self.data, out: &out, resume: resumable(&out), follow: false, recipe, stop: self.stop };
        let trained = session.run(observer)?;
        let train_seconds = started.elapsed().as_secs_f64();
        let report = evaluate_checkpoint(&out, self.data, Some(trained.inputs), 0, 0, |_, _, _| {})
            .map_err(|e| SessionError::Setup(e.to_string()))?;
        crate::evaluation::write(&out, &report).map_err(|e| self.io(e))?;
        let c = Checkpoint::read(&out)?;
        let (layers, heads, dim) = match &c.model {
            NetworkConfig::Transformer(m) => (m.layers, m.heads, m.d_model),
            NetworkConfig::Physics(m) => (m.layers, 0, m.hidden),
        };
        Ok(Row {
            layers,
            heads,
            dim,
            r2: report.windows.r2,
            rmse: report.windows.rmse,
            train_seconds,
            cpu_seconds: trained.summary.history.iter().map(|m| m.cpu_seconds).sum(),
            windows: report.windows.count,
            ..planned.clone()
        })
    }

    fn write(&self, dataset: &[Row], arch: &[Row]) -> Result<String, SessionError> {
        let md = tables(dataset, arch);
        dynforge_proto::run_dir::write_atomic(&self.out.join("sweep.md"), md.as_bytes()).map_err(|e| self.io(e))?;
        let json = serde_json::json!({ "dataset": dataset, "architecture": arch });
        let text = serde_json::to_string_pretty(&json).map_err(|e| self.io(e))?;
        dynforge_proto::run_dir::write_atomic(&self.out.join("sweep.json"), text.as_bytes()).map_err(|e| self.io(e))?;
        Ok(md)
    }
}

/// R2 and RMSE cells, or the reason the configuration was not run.
fn scores(r: &Row) -> String {
    match &r.skipped {
        Some(reason) => format!("not run: {} | -", reason.replace('|', "/")),
        None => format!("{:.4} | {:.4}", r.r2, r.rmse),
    }
}

/// Both tables, markdown.
pub fn tables(dataset: &[Row], arch: &[Row]) -> String {
    let mut md = String::new();
    if !dataset.is_empty() {
        let _ = writeln!(md, "**Dataset configurations** (fixed architecture)\n");
        let _ = writeln!(
            md,
            "| Seq Len | Stride | SSR | Effective time (s) | Windows | Val R2 | Val RMSE | Paper Val R2 |"
        );
        let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|");
        for r in dataset {
            let span = (r.len * r.stride) as f64 / 1000.0;
            let _ = writeln!(
                md,
                "| {} | {} | {} | {span:.3} | {} | {} | {:.4} |",
                r.len,
                r.stride,
                r.ssr,
                r.windows,
                scores(r),
                r.paper_r2
            );
        }
        md.push('\n');
    }
    if !arch.is_empty() {
        let _ = writeln!(md, "**Architectures** (fixed dataset configuration)\n");
        let _ = writeln!(
            md,
            "| Layers | Heads | Embedding | Val R2 | Val RMSE | Train time (s) | CPU hours | Paper Val R2 | Paper Val RMSE |"
        );
        let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        for r in arch {
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {:.0} | {:.3} | {:.4} | {:.4} |",
                r.layers,
                r.heads,
                r.dim,
                scores(r),
                r.train_seconds,
                r.cpu_seconds / 3600.0,
                r.paper_r2,
                r.paper_rmse.unwrap_or(f64::NAN)
            );
        }
    }
    md
}
