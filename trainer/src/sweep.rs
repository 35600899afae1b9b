//! The paper's two ablations, trained and scored at a chosen scale: the dataset grid (sequence length x stride x
//! SSR, fixed architecture) and the architecture grid (layers x heads x embedding of the transformer, fixed dataset
//! configuration), written as the paper's two tables with its values beside ours (`sweep.md`, `sweep.json`). A
//! configuration the dataset cannot serve becomes a row saying why, and the grid goes on; a rerun resumes.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crate::checkpoint::Checkpoint;
use crate::evaluation::evaluate_checkpoint;
use crate::model::NetworkConfig;
use crate::training::recipe::Recipe;
use crate::training::resumable;
use crate::training::session::{Session, SessionError, SessionObserver};
use dynforge_dataset::prepare::ModelKind;
use dynforge_dataset::window::WindowSpec;
use dynforge_evaluation::Checks;
use dynforge_evaluation::sweep::{ARCHITECTURE_GRID, DATASET_GRID, Grid, Row, tables};

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
                let recipe = Recipe { window: WindowSpec::new(len, stride, ssr), ..self.base.clone() };
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
        let report = evaluate_checkpoint(&out, self.data, Some(trained.inputs), Checks::NONE, |_, _, _| {})
            .map_err(|e| SessionError::Setup(e.to_string()))?;
        dynforge_evaluation::write(&out, &report).map_err(|e| self.io(e))?;
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
