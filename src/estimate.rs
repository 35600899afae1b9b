//! `dynforge estimate`: a robot's parameters from a recording, refined by physics, written into its URDF.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use dynforge_proto::LABELS;
use dynforge_robot::urdf;
use dynforge_trainer::inference::Predictor;

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
    let predictor = Predictor::load(&args.checkpoint)?;
    let base = args.urdf.as_ref().map(urdf::load).transpose()?;
    let (rec, e) = predictor.estimate_file(&args.checkpoint, &args.log, base.as_ref())?;
    // A log the torques of which cannot refine the estimate (no joint moves) keeps the estimator's, with a warning.
    let refinement = match args.no_refine {
        true => None,
        false => predictor
            .refine(&args.checkpoint, &rec, &e)
            .inspect_err(|err| eprintln!("warning: the estimate is not refined by physics: {err}"))
            .ok(),
    };
    let wanted = refinement.as_ref().map_or(e.labels, |r| r.labels);
    let (model, notes) = dynforge_robot::parameters::with_labels(&rec.model, &wanted)
        .with_context(|| format!("applying the estimate to the robot of {}", args.log.display()))?;
    // What is reported is what the URDF carries: the labels after any projection into physics.
    let values = dynforge_robot::parameters::labels(&model)?;
    let out = args.out.unwrap_or_else(|| args.log.with_extension("estimated.urdf"));
    dynforge_proto::run_dir::write_atomic(&out, urdf::to_string(&model, &urdf::BaseLink::default()).as_bytes())
        .with_context(|| format!("writing {}", out.display()))?;
    if args.json {
        let parameters: serde_json::Map<String, serde_json::Value> = LABELS
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let v = serde_json::json!({
                    "value": values[k], "estimator": e.labels[k], "spread": e.spread[k], "unit": l.kind.unit()
                });
                (l.name.to_string(), v)
            })
            .collect();
        let refined = refinement.as_ref().map(|r| {
            serde_json::json!({
                "identifiable": r.identifiable, "prior_from_validation": r.prior_from_validation,
                "torque_nrmse_estimator": r.nrmse_network, "torque_nrmse_refined": r.nrmse_refined,
            })
        });
        let summary = serde_json::json!({
            "windows": e.windows, "parameters": parameters, "refinement": refined, "projections": notes, "urdf": out
        });
        println!("{}", serde_json::to_string_pretty(&summary)?);
        return Ok(());
    }
    println!("{}: {} windows", args.log.display(), e.windows);
    println!("{:<12} {:>12} {:>12} {:>12}  unit", "parameter", "estimate", "estimator", "spread");
    for (k, l) in LABELS.iter().enumerate() {
        println!("{:<12} {:>12.6} {:>12.6} {:>12.6}  {}", l.name, values[k], e.labels[k], e.spread[k], l.kind.unit());
    }
    match &refinement {
        Some(r) => println!(
            "refined by physics ({} identifiable parameter combinations; prior spread from {}): torque NRMSE on this \
             log {:.4} (estimator alone {:.4})",
            r.identifiable,
            if r.prior_from_validation { "the checkpoint's report.json" } else { "the training labels" },
            r.nrmse_refined,
            r.nrmse_network
        ),
        None if args.no_refine => println!("estimator output only (--no-refine)"),
        None => println!("estimator output only (not refined: see the warning above)"),
    }
    for n in &notes {
        println!("projected: {n}");
    }
    println!("URDF with the estimated parameters: {}", out.display());
    Ok(())
}
