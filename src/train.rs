//! `dynforge train`: flags -> a training session.

use std::path::PathBuf;

use crate::flags::RecipeFlags;
use anyhow::Result;
use clap::Args;
use dynforge_trainer::model::Preset;
use dynforge_trainer::training::session::Session;

use crate::display::{Bars, STOP, catch_interrupts};

#[derive(Args)]
pub struct TrainArgs {
    /// A `dynforge generate` output directory.
    data: PathBuf,
    /// Checkpoint directory to write (model, statistics, metrics, resume state).
    #[arg(long)]
    out: PathBuf,
    /// Continue the interrupted or finished run in --out (same data and settings) instead of starting anew.
    #[arg(long)]
    resume: bool,
    /// Train while the dataset is being generated (transformer): wait for shards, and add the shards that appear
    /// before each epoch (the preprocessing statistics stay those of the first shards).
    #[arg(long)]
    follow: bool,
    #[command(flatten)]
    recipe: RecipeFlags,
}

pub fn run(args: TrainArgs) -> Result<()> {
    let recipe = args.recipe.recipe(Preset::Paper, None)?;
    catch_interrupts();
    let session = Session {
        data: &args.data,
        out: &args.out,
        resume: args.resume,
        follow: args.follow,
        recipe: &recipe,
        stop: &STOP,
    };
    session.run(&mut Bars::new(recipe.train.batch))?;
    Ok(())
}
