//! `dynforge pipeline`: generate a small dataset, train, evaluate: the whole system in one command.

use std::path::PathBuf;

use crate::flags::RecipeFlags;
use anyhow::{Context, Result, bail};
use clap::Args;
use dynforge_trainer::model::Preset;
use dynforge_trainer::training::resumable;
use dynforge_trainer::training::session::Session;

use crate::display::{Bars, STOP, catch_interrupts};

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

pub fn run(args: PipelineArgs) -> Result<()> {
    let (data, model) = (args.out.join("data"), args.out.join("model"));
    eprintln!("== 1/3 generate {} robots x 16 trajectories into {}", args.robots, data.display());
    // The generation runs as its own process: its coordinator owns the signals while it runs.
    let exe = std::env::current_exe().context("locating the dynforge executable")?;
    let status = std::process::Command::new(exe)
        .args(["generate", "--out"])
        .arg(&data)
        .args(["--robots", &args.robots.to_string(), "--workers", &args.workers.to_string()])
        .args(["--seed", &args.dataset_seed.to_string()])
        .status()
        .context("starting the generation")?;
    if !status.success() {
        bail!("generation failed ({status}); rerun the same command to resume it");
    }
    eprintln!("== 2/3 train into {}", model.display());
    let recipe = args.recipe.recipe(Preset::Fast, args.recipe.model_is_transformer().then_some(12));
    catch_interrupts();
    let session =
        Session { data: &data, out: &model, resume: resumable(&model), follow: false, recipe: &recipe, stop: &STOP };
    let trained = session.run(&mut Bars::new(recipe.train.batch))?;
    eprintln!("== 3/3 evaluate on the validation robots");
    crate::evaluate::evaluate(&model, &data, Some(trained.inputs), crate::evaluate::CHECKS)?;
    Ok(())
}
