//! `dynforge evaluate`: a checkpoint scored on its validation robots.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use dynforge_evaluation::{Checks, Report, write};
use dynforge_trainer::checkpoint::Checkpoint;
use dynforge_trainer::evaluation::evaluate_checkpoint;
use dynforge_trainer::training::session::Inputs;

use crate::display::bar;

/// How many validation recordings and robots the checks take by default.
pub const CHECKS: Checks = Checks { torque_recordings: 64, identify_robots: 32, spread_robots: 256 };

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
    /// Validation robots estimated and refined by their torques from 1, 2, 4, ... and all their logs, as simulated
    /// and with 0.3, 1 and 3 % effort noise, to calibrate the spreads `estimate` prints per label toward 68 % within
    /// one and 95 % within two (0: skip it; the RMSE and the posterior as they come).
    #[arg(long, default_value_t = CHECKS.spread_robots)]
    spread_robots: usize,
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
    let checks = Checks {
        torque_recordings: args.torque_recordings,
        identify_robots: args.identify_robots,
        spread_robots: args.spread_robots,
    };
    evaluate(&args.checkpoint, &data, None, checks)?;
    Ok(())
}
