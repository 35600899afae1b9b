//! `dynforge estimate`: a robot's parameters from a recording, refined by physics, written into its URDF.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use dynforge_recording::robot_document;
use dynforge_trainer::inference::estimate_to_urdf;

#[derive(Args)]
pub struct EstimateArgs {
    /// Checkpoint directory (from `dynforge train`).
    #[arg(long)]
    checkpoint: PathBuf,
    /// A shard or a ROS 2 bag (MCAP) holding /joint_states.
    log: PathBuf,
    /// The robot's URDF, when the log has no /robot_description (joints are matched by name).
    #[arg(long)]
    urdf: Option<PathBuf>,
    /// Where to write the URDF with the estimated parameters (default: LOG with extension .estimated.urdf).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the estimate as JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Keep the estimator's output as it is. By default it is refined by physics: the labels that best explain the
    /// log's torques (least squares on the regressor), with the estimate as prior for what the torques cannot tell
    /// apart.
    #[arg(long)]
    no_refine: bool,
}

pub fn run(args: EstimateArgs) -> Result<()> {
    let (document, source) = robot_document(args.urdf.as_deref(), &args.log)?;
    let out = args.out.clone().unwrap_or_else(|| args.log.with_extension("estimated.urdf"));
    let inputs: Vec<PathBuf> = std::iter::once(&args.log).chain(&args.urdf).cloned().collect();
    dynforge_recording::check_not_an_input(&out, &inputs)?;
    let report = estimate_to_urdf(&args.checkpoint, &args.log, (&document, &source), &out, !args.no_refine)?;
    for w in report.calibration_warning.iter().chain(&report.warning) {
        eprintln!("warning: {w}");
    }
    match args.json {
        true => println!("{}", serde_json::to_string_pretty(&report.json())?),
        false => print!("{report}"),
    }
    Ok(())
}
