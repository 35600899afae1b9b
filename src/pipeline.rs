//! `dynforge pipeline`: generate a small dataset, train, evaluate: the whole system in one command.

use std::path::{Path, PathBuf};

use crate::flags::RecipeFlags;
use anyhow::{Context, Result, bail};
use clap::Args;
use dynforge_trainer::model::Preset;
use dynforge_trainer::training::resumable;
use dynforge_trainer::training::session::Session;

use crate::display::{Bars, STOP, catch_interrupts};
use crate::evaluate::{CHECKS, SPREAD_TRAJECTORIES, spread_robots_dir, spread_seed};
use dynforge_evaluation::Checks;

#[derive(Args)]
pub struct PipelineArgs {
    /// Directory for the dataset (DIR/data) and the checkpoint (DIR/model).
    #[arg(long, default_value = "dynforge-pipeline")]
    out: PathBuf,
    /// Robots to generate (16 trajectories each).
    #[arg(long, default_value_t = 48)]
    robots: usize,
    /// Worker processes of the generation.
    #[arg(long, default_value_t = 2)]
    workers: usize,
    /// Dataset seed.
    #[arg(long, default_value_t = 1)]
    dataset_seed: u64,
    #[command(flatten)]
    recipe: RecipeFlags,
}

/// Runs `dynforge generate` of `robots` x `trajectories` robots of `seed` into `out` with `workers` processes, as a
/// process of its own: its coordinator owns the signals while it runs.
fn generate(out: &Path, robots: usize, trajectories: u32, workers: usize, seed: u64) -> Result<()> {
    let exe = std::env::current_exe().context("locating the dynforge executable")?;
    let status = std::process::Command::new(exe)
        .args(["generate", "--out"])
        .arg(out)
        .args(["--robots", &robots.to_string(), "--trajectories", &trajectories.to_string()])
        .args(["--workers", &workers.to_string(), "--seed", &seed.to_string()])
        .status()
        .context("starting the generation")?;
    if !status.success() {
        bail!("generation into {} failed ({status}); rerun the same command to resume it", out.display());
    }
    Ok(())
}

pub fn run(args: PipelineArgs) -> Result<()> {
    let (data, model) = (args.out.join("data"), args.out.join("model"));
    let recipe = args.recipe.recipe(Preset::Fast, args.recipe.model_is_transformer().then_some(12))?;
    eprintln!("== 1/3 generate {} robots x 16 trajectories into {}", args.robots, data.display());
    generate(&data, args.robots, 16, args.workers, args.dataset_seed)?;
    eprintln!("== 2/3 train into {}", model.display());
    catch_interrupts();
    let session =
        Session { data: &data, out: &model, resume: resumable(&model), follow: false, recipe: &recipe, stop: &STOP };
    let trained = session.run(&mut Bars::new(recipe.train.batch))?;
    let fresh = spread_robots_dir(&model);
    let checks = Checks { spread_data: Some(fresh.clone()), ..CHECKS };
    eprintln!(
        "== 3/3 evaluate on the validation robots, and calibrate the spreads on {} robots drawn fresh into {}",
        checks.spread_robots,
        fresh.display()
    );
    generate(&fresh, checks.spread_robots, SPREAD_TRAJECTORIES, args.workers, spread_seed(args.dataset_seed))?;
    crate::evaluate::evaluate(&model, &data, Some(trained.inputs), checks)?;
    Ok(())
}
