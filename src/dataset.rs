//! `dynforge dataset`: what a dataset holds and how many windows each preprocessing geometry makes of it (`stats`);
//! its training cache built ahead of training, and its shards pruned once cached (`prepare`).

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, Subcommand};
use dynforge_trainer::data::dataset::stats;
use dynforge_trainer::data::features::JacobianFeatures;
use dynforge_trainer::data::window::WindowSpec;
use dynforge_trainer::training::session::{self, ModelKind};

use crate::progress::{Bars, STOP, catch_interrupts};

#[derive(Subcommand)]
pub enum DatasetCommand {
    /// Robots, trajectories, hours of motion, windows per configuration and label ranges of a dataset.
    Stats(StatsArgs),
    /// Build the cache `train` reads (physics or windows) without training; with --prune, then delete the shards,
    /// whose data the cache holds (bounded disk: generate, prepare --prune and merge a run partition by partition).
    Prepare(PrepareArgs),
}

#[derive(Args)]
pub struct PrepareArgs {
    /// A finished `dynforge generate` directory (or partition).
    dir: PathBuf,
    /// The estimator whose cache to build.
    #[arg(long, value_enum, default_value = "physics")]
    model: ModelKind,
    /// Window geometry, as `train` takes it.
    #[arg(long = "window", value_name = "LEN:STRIDE:SSR", default_value = "64:64:16")]
    window: String,
    /// Then delete the shards (recorded in DIR/pruned.txt): `train` with these settings, `merge` and `verify` still
    /// work; other settings, the torque and identification checks need shards.
    #[arg(long)]
    prune: bool,
}

#[derive(Args)]
pub struct StatsArgs {
    /// A `generate` output directory, or a folder of shards.
    dir: PathBuf,
    /// Window geometries to count, as LEN:STRIDE:SSR (default: the paper's grid around its best, 64:64:16).
    #[arg(long = "window", value_name = "LEN:STRIDE:SSR")]
    windows: Vec<String>,
    /// Also list the input features of a time step (for the first readable shard's robot).
    #[arg(long)]
    features: bool,
}

#[derive(Args)]
pub struct InfoArgs {
    /// An MCAP log: a dataset shard or a ROS 2 bag (file or rosbag2 directory).
    log: PathBuf,
}

pub fn info(args: InfoArgs) -> Result<()> {
    print!("{}", dynforge_recording::info::Info::of(&args.log)?);
    Ok(())
}

fn parse_spec(s: &str) -> Result<WindowSpec> {
    let parts: Vec<usize> = s
        .split(':')
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--window {s}: expected LEN:STRIDE:SSR"))?;
    match parts[..] {
        [len, stride, ssr] if len > 0 && stride > 0 && ssr > 0 => Ok(WindowSpec { len, stride, ssr }),
        _ => anyhow::bail!("--window {s}: expected three positive numbers LEN:STRIDE:SSR"),
    }
}

fn prepare(args: PrepareArgs) -> Result<()> {
    let spec = parse_spec(&args.window)?;
    catch_interrupts();
    let build = || {
        let mut bars = Bars::new(1);
        session::prepare(&args.dir, args.model, &spec, &STOP, &mut bars)
    };
    let held = if args.prune {
        let mut held = String::new();
        let pruned = dynforge_coordinator::prune::prune(
            &args.dir,
            |_, _| {},
            || {
                held = build().map_err(|e| e.to_string())?;
                Ok(())
            },
        )?;
        format!("{held}; {pruned} shards pruned")
    } else {
        build()?
    };
    println!("{}: {held}", args.dir.display());
    Ok(())
}

pub fn run(cmd: DatasetCommand) -> Result<()> {
    let args = match cmd {
        DatasetCommand::Stats(args) => args,
        DatasetCommand::Prepare(args) => return prepare(args),
    };
    let specs: Vec<WindowSpec> = if args.windows.is_empty() {
        [(32, 64, 16), (64, 32, 16), (64, 64, 16), (64, 64, 8), (128, 64, 16)]
            .map(|(len, stride, ssr)| WindowSpec { len, stride, ssr })
            .to_vec()
    } else {
        args.windows.iter().map(|s| parse_spec(s)).collect::<Result<_>>()?
    };
    let s = stats(&args.dir, &specs)?;
    print!("{}: {}", args.dir.display(), s.report(&specs));
    if args.features
        && let Some(model) = &s.model
    {
        let jac = JacobianFeatures::new(model);
        let joints: Vec<&str> = model.joints().iter().map(|j| j.name.as_str()).collect();
        println!(
            "features per time step: {} = q, qd, tau of {} joints + {} Jacobian entries",
            3 * joints.len() + jac.len(),
            joints.len(),
            jac.len()
        );
        for kind in ["q", "qd", "tau"] {
            println!("  {kind}: {}", joints.join(" "));
        }
        println!("  jacobian: {}", jac.entries.iter().map(|e| e.name.as_str()).collect::<Vec<_>>().join(" "));
    }
    for skipped in &s.skipped {
        eprintln!("skipped: {skipped}");
    }
    Ok(())
}
