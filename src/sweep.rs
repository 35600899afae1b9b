//! `dynforge sweep`: the paper's two ablations — the dataset grid (sequence length x stride x SSR, fixed
//! architecture) and the architecture grid (layers x heads x embedding, fixed dataset configuration) — trained and
//! scored at a chosen scale, written as the paper's two tables with its values beside ours.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use dynforge_trainer::checkpoint::Checkpoint;
use dynforge_trainer::evaluation::evaluate_checkpoint;
use dynforge_trainer::model::Preset;
use serde::Serialize;

use crate::train::{ModelArgs, OptimArgs, Recipe, TrainJob, WindowArgs, interrupted, run_training};

/// The paper's dataset grid: (sequence length, stride, SSR, its validation R2).
const DATASET_GRID: [(usize, usize, usize, f64); 16] = [
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
const ARCHITECTURE_GRID: [(usize, usize, usize, f64, f64); 4] = [
    (2, 16, 256, 0.8460, 0.1185),
    (4, 16, 128, 0.8555, 0.1148),
    (4, 32, 128, 0.8633, 0.1116),
    (8, 32, 128, 0.8410, 0.1200),
];

#[derive(Clone, Copy, PartialEq, ValueEnum)]
pub enum Grid {
    Dataset,
    Architecture,
    Both,
}

#[derive(Args)]
pub struct SweepArgs {
    /// A `dynforge generate` output directory.
    data: PathBuf,
    /// Directory for one checkpoint per configuration and the tables (sweep.md, sweep.json).
    #[arg(long)]
    out: PathBuf,
    /// Which grid to run.
    #[arg(long, value_enum, default_value = "both")]
    grid: Grid,
    /// Architecture of the dataset grid and patch of the architecture grid's models.
    #[command(flatten)]
    model: ModelArgs,
    #[command(flatten)]
    optim: OptimArgs,
}

#[derive(Clone, Serialize)]
struct Row {
    name: String,
    len: usize,
    stride: usize,
    ssr: usize,
    layers: usize,
    heads: usize,
    dim: usize,
    r2: f64,
    rmse: f64,
    train_seconds: f64,
    /// CPU seconds of the training steps (all threads): the cost side of accuracy per CPU-hour.
    cpu_seconds: f64,
    windows: usize,
    paper_r2: f64,
    paper_rmse: Option<f64>,
    /// Why the configuration was not trained (e.g. windows longer than the recordings); its scores are NaN.
    skipped: Option<String>,
}

/// Trains and scores one configuration; a configuration this dataset cannot serve (no windows in a split, a
/// geometry the model refuses) becomes a row saying why, so the rest of the grid still runs. An interruption
/// stops the sweep.
fn run_one(
    args: &SweepArgs,
    name: &str,
    window: WindowArgs,
    model: ModelArgs,
    paper: (f64, Option<f64>),
) -> Result<Row> {
    let shape = model.config(1, window.len, Preset::Paper);
    let planned = Row {
        name: name.into(),
        len: window.len,
        stride: window.stride,
        ssr: window.ssr,
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
    eprintln!("== {name}");
    match train_and_score(args, &planned, Recipe { model, window, optim: args.optim.clone() }) {
        Ok(row) => Ok(row),
        Err(e) if interrupted() => Err(e),
        Err(e) => {
            let reason = format!("{e:#}");
            eprintln!("warning: {name} not run: {reason}");
            Ok(Row { skipped: Some(reason), ..planned })
        }
    }
}

fn train_and_score(args: &SweepArgs, planned: &Row, recipe: Recipe) -> Result<Row> {
    let out = args.out.join(&planned.name);
    let started = Instant::now();
    let (summary, windows) = run_training(&TrainJob {
        defaults: (Preset::Paper, 5),
        data: &args.data,
        out: &out,
        resume: dynforge_trainer::training::resumable(&out),
        follow: false,
        recipe: &recipe,
    })?;
    let train_seconds = started.elapsed().as_secs_f64();
    let report = evaluate_checkpoint(&out, &windows, &args.data, 0, 0, |_, _, _| {})?;
    std::fs::write(out.join("report.md"), report.markdown()).with_context(|| format!("writing {}", out.display()))?;
    let c = Checkpoint::read(&out)?;
    Ok(Row {
        layers: c.model.layers,
        heads: c.model.heads,
        dim: c.model.d_model,
        r2: report.windows.r2,
        rmse: report.windows.rmse,
        train_seconds,
        cpu_seconds: summary.history.iter().map(|m| m.cpu_seconds).sum(),
        windows: windows.count(),
        ..planned.clone()
    })
}

/// R2 and RMSE cells, or the reason the configuration was not run.
fn scores(r: &Row) -> String {
    match &r.skipped {
        Some(reason) => format!("not run: {} | -", reason.replace('|', "/")),
        None => format!("{:.4} | {:.4}", r.r2, r.rmse),
    }
}

fn write_tables(out: &Path, dataset: &[Row], arch: &[Row]) -> Result<String> {
    let mut md = String::new();
    if !dataset.is_empty() {
        let _ = writeln!(md, "**Dataset configurations** (fixed architecture)\n");
        let _ = writeln!(
            md,
            "| Seq Len | Stride | SSR | Effective time (s) | Windows | Val R2 | Val RMSE | Paper Val R2 |"
        );
        let _ = writeln!(md, "|---:|---:|---:|---:|---:|---:|---:|---:|");
        for r in dataset {
            let _ = writeln!(
                md,
                "| {} | {} | {} | {:.3} | {} | {} | {:.4} |",
                r.len,
                r.stride,
                r.ssr,
                (r.len * r.stride) as f64 / 1000.0,
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
    std::fs::write(out.join("sweep.md"), &md).with_context(|| format!("writing {}/sweep.md", out.display()))?;
    let json = serde_json::json!({ "dataset": dataset, "architecture": arch });
    std::fs::write(out.join("sweep.json"), serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("writing {}/sweep.json", out.display()))?;
    Ok(md)
}

pub fn run(args: SweepArgs) -> Result<()> {
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let (mut dataset, mut arch) = (Vec::new(), Vec::new());
    if args.grid != Grid::Architecture {
        for (len, stride, ssr, paper) in DATASET_GRID {
            let name = format!("dataset-L{len}-s{stride}-r{ssr}");
            let window = WindowArgs { len, stride, ssr };
            dataset.push(run_one(&args, &name, window, args.model.clone(), (paper, None))?);
            write_tables(&args.out, &dataset, &arch)?;
        }
    }
    if args.grid != Grid::Dataset {
        for (layers, heads, dim, paper, paper_rmse) in ARCHITECTURE_GRID {
            let name = format!("arch-{layers}x{heads}x{dim}");
            let model = ModelArgs { layers: Some(layers), heads: Some(heads), dim: Some(dim), ..args.model.clone() };
            arch.push(run_one(
                &args,
                &name,
                WindowArgs { len: 64, stride: 64, ssr: 16 },
                model,
                (paper, Some(paper_rmse)),
            )?);
            write_tables(&args.out, &dataset, &arch)?;
        }
    }
    println!("{}", write_tables(&args.out, &dataset, &arch)?);
    Ok(())
}
