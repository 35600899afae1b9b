//! `dynforge robot`: generate or inspect robots.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use dynforge_proto::generator::GeneratorConfig;
use dynforge_robot::generator::generate;
use dynforge_robot::urdf;

#[derive(Args)]
pub struct RobotArgs {
    /// Dataset seed: robot `--id` of seed `--seed` is always the same robot.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Robot index within the dataset.
    #[arg(long, default_value_t = 0)]
    id: u64,
    /// Write the URDF to this file (atomically) instead of standard output.
    #[arg(long, short)]
    out: Option<PathBuf>,
    /// Generator configuration (TOML); fields left out keep their defaults.
    #[arg(long, value_name = "TOML")]
    config: Option<PathBuf>,
    /// Load this URDF and print its links, joints, masses, inertias and friction instead of generating.
    #[arg(long, value_name = "URDF", conflicts_with_all = ["seed", "id", "out", "config"])]
    inspect: Option<PathBuf>,
}

pub fn run(args: RobotArgs) -> Result<()> {
    if let Some(path) = &args.inspect {
        let model = urdf::load(path)?;
        print!("{}", dynforge_robot::summary::describe(&model));
        return Ok(());
    }
    let config = GeneratorConfig::load(args.config.as_deref())?;
    let robot = generate(&config, args.seed, args.id)?;
    let text = robot.urdf();
    match &args.out {
        Some(path) => {
            dynforge_proto::run_dir::write_atomic(path, text.as_bytes())
                .with_context(|| format!("writing {}", path.display()))?;
            eprintln!("wrote robot {} of seed {} ({}) to {}", args.id, args.seed, robot.model.name(), path.display());
        }
        None => std::io::stdout().write_all(text.as_bytes()).context("writing to standard output")?,
    }
    Ok(())
}
