//! `dynforge evaluate`: a checkpoint scored on its validation robots.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use dynforge_coordinator::run::GenerateConfig;
use dynforge_evaluation::{Checks, Report, write};
use dynforge_proto::manifest::{Manifest, Partition};
use dynforge_trainer::checkpoint::Checkpoint;
use dynforge_trainer::evaluation::evaluate_checkpoint;
use dynforge_trainer::training::session::Inputs;

use crate::display::bar;
use crate::generate::{default_workers, execute, worker_command};

/// How many validation recordings and robots the checks take by default.
pub const CHECKS: Checks =
    Checks { torque_recordings: 64, identify_robots: 32, spread_robots: SPREAD_ROBOTS, spread_data: None };

/// Robots the spreads are calibrated on, and logs of each when they are drawn fresh. The shares within one and two
/// are fitted per label to 68 +- 5 and 95 +- 3 %: with 128 robots a share of 95 % is known to 1.9 points (one
/// binomial standard deviation), with the 11 validation robots of `pipeline` to 6.6. Four logs give the log counts
/// 1, 2 and 4; more are interpolated to by the logarithm of the count.
const SPREAD_ROBOTS: usize = 128;
pub const SPREAD_TRAJECTORIES: u32 = 4;

/// Where the robots the spreads are calibrated on come from.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SpreadFrom {
    /// Robots drawn fresh from the training data's generator (another seed) into CHECKPOINT/spread-robots.
    Fresh,
    /// The validation robots (none under a split by trajectory or window).
    Validation,
}

#[derive(Args)]
pub struct EvaluateArgs {
    /// Checkpoint directory (from `dynforge train`).
    checkpoint: PathBuf,
    /// Dataset to evaluate on (default: the one the checkpoint was trained on); its validation robots are used.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Validation recordings to run the torque check on (0: skip it).
    #[arg(long, default_value_t = CHECKS.torque_recordings)]
    torque_recordings: usize,
    /// Validation robots to identify by physics (least squares on the regressor, and the hybrid that refines the
    /// estimate with it) from half of their recordings, scored on the other half (0: skip it).
    #[arg(long, default_value_t = CHECKS.identify_robots)]
    identify_robots: usize,
    /// Robots estimated and refined by their torques from 1, 2, 4, ... and all their logs, as simulated and with
    /// 0.3, 1 and 3 % effort noise, to calibrate the spreads `estimate` prints per label toward 68 % within one and
    /// 95 % within two (0: skip it; the RMSE and the posterior as they come).
    #[arg(long, default_value_t = CHECKS.spread_robots)]
    spread_robots: usize,
    /// Where those robots come from.
    #[arg(long, value_enum, default_value_t = SpreadFrom::Fresh)]
    spread_from: SpreadFrom,
    /// Logs generated per fresh robot.
    #[arg(long, default_value_t = SPREAD_TRAJECTORIES)]
    spread_trajectories: u32,
}

/// Where the robots drawn fresh for the spreads of the checkpoint in `dir` are generated.
pub fn spread_robots_dir(dir: &Path) -> PathBuf {
    dir.join("spread-robots")
}

/// The seed of the robots drawn fresh for the spreads of a dataset of seed `seed`: another stream of the same
/// generator, so that none of them is a training robot.
pub fn spread_seed(seed: u64) -> u64 {
    seed ^ 0x7370_7265_6164_7321
}

/// Generates (or finds, resuming) `robots` x `trajectories` robots drawn fresh from the generator that made `data`
/// into the checkpoint `dir`'s [`spread_robots_dir`]. `None` where `data` does not say how to draw more (a folder of
/// shards without a manifest, or a robot's family, whose excitations are not in it): its validation robots are used.
pub fn fresh_robots(data: &Path, dir: &Path, robots: usize, trajectories: u32) -> Result<Option<PathBuf>> {
    let validation = |why: &str| {
        eprintln!("note: {} {why}: the spreads are calibrated on its validation robots", data.display());
        Ok(None)
    };
    let manifest = match Manifest::load(data)? {
        None => return validation("has no manifest.toml to draw fresh robots from"),
        Some(m) if m.family.is_some() => return validation("is a robot's family"),
        Some(m) => m,
    };
    let out = spread_robots_dir(dir);
    let cfg = GenerateConfig {
        dir: out.clone(),
        seed: spread_seed(manifest.seed),
        robots: robots as u64,
        trajectories,
        workers: default_workers(),
        partition: Partition::WHOLE,
        generator: manifest.generator,
        sim: manifest.sim,
        family: None,
        job_timeout: std::time::Duration::from_secs(120),
        max_attempts: 3,
        worker_command: worker_command()?,
    };
    execute(&cfg, &mut std::io::stderr()).context("drawing fresh robots to calibrate the spreads on")?;
    Ok(Some(out))
}

/// Evaluates, writes `report.md`/`report.json` and prints the report.
pub fn evaluate(
    dir: &std::path::Path,
    data: &std::path::Path,
    inputs: Option<Inputs>,
    checks: Checks,
) -> Result<Report> {
    let b = bar("{msg} {bar:40} {pos}/{len}");
    let report = evaluate_checkpoint(dir, data, inputs, checks, |what, k, n| {
        b.set_message(what.to_string());
        b.set_length(n as u64);
        b.set_position(k as u64);
    })?;
    b.finish_and_clear();
    write(dir, &report).map_err(|e| anyhow::anyhow!("writing the report into {}: {e}", dir.display()))?;
    println!("{}", report.markdown());
    eprintln!("written: {0}/report.md, {0}/report.json", dir.display());
    Ok(report)
}

pub fn run(args: EvaluateArgs) -> Result<()> {
    let data = match args.data {
        Some(d) => d,
        None => PathBuf::from(Checkpoint::read(&args.checkpoint)?.dataset),
    };
    let spread_data = match (args.spread_robots, args.spread_from) {
        (0, _) | (_, SpreadFrom::Validation) => None,
        (n, SpreadFrom::Fresh) => fresh_robots(&data, &args.checkpoint, n, args.spread_trajectories)?,
    };
    let checks = Checks {
        torque_recordings: args.torque_recordings,
        identify_robots: args.identify_robots,
        spread_robots: args.spread_robots,
        spread_data,
    };
    evaluate(&args.checkpoint, &data, None, checks)?;
    Ok(())
}
