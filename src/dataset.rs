//! `dynforge dataset stats`: what a dataset holds and how many windows each preprocessing geometry makes of it.

use std::path::PathBuf;

use anyhow::Result;
use clap::{Args, Subcommand};
use dynforge_trainer::data::dataset::stats;
use dynforge_trainer::data::features::JacobianFeatures;
use dynforge_trainer::data::window::WindowSpec;

#[derive(Subcommand)]
pub enum DatasetCommand {
    /// Robots, trajectories, hours of motion, windows per configuration and label ranges of a dataset.
    Stats(StatsArgs),
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

pub fn run(cmd: DatasetCommand) -> Result<()> {
    let DatasetCommand::Stats(args) = cmd;
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
