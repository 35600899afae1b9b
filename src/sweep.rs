//! `dynforge sweep`: the paper's dataset and architecture grids at a chosen scale.

use std::path::PathBuf;

use crate::flags::RecipeFlags;
use anyhow::Result;
use clap::{Args, ValueEnum};
use dynforge_evaluation::sweep::Grid;
use dynforge_trainer::model::Preset;
use dynforge_trainer::sweep::Sweep;

use crate::display::{Bars, STOP, catch_interrupts};

#[derive(Clone, Copy, PartialEq, ValueEnum)]
pub enum GridArg {
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
    /// Which grid to run (the architecture grid trains transformers).
    #[arg(long, value_enum, default_value = "both")]
    grid: GridArg,
    /// The estimator of the dataset grid and everything the grids do not set [default epochs: 5].
    #[command(flatten)]
    recipe: RecipeFlags,
}

pub fn run(args: SweepArgs) -> Result<()> {
    let base = args.recipe.recipe(Preset::Paper, Some(5))?;
    let grid = match args.grid {
        GridArg::Dataset => Grid::Dataset,
        GridArg::Architecture => Grid::Architecture,
        GridArg::Both => Grid::Both,
    };
    catch_interrupts();
    let sweep = Sweep { data: &args.data, out: &args.out, grid, base: &base, stop: &STOP };
    println!("{}", sweep.run(&mut Bars::new(base.train.batch))?);
    Ok(())
}
