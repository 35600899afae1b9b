//! `dynforge identify`: calibrates a robot's URDF to its logs by physics alone (no trained network).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use dynforge_identify::{NormalEquations, calibrate};
use dynforge_proto::LABELS;
use dynforge_recording::read;
use dynforge_robot::urdf;

#[derive(Args)]
pub struct IdentifyArgs {
    /// Logs of one robot: shards or ROS 2 bags (MCAP) holding /joint_states with position, velocity and effort.
    #[arg(required = true)]
    logs: Vec<PathBuf>,
    /// The robot's URDF, the starting point and prior (default: the first log's /robot_description).
    #[arg(long)]
    urdf: Option<PathBuf>,
    /// How far the URDF's values are trusted, relative (0.5: each label within ~50 % of its value; floors of
    /// 0.1 N m, 0.1 N m s/rad, 0.1 kg, 1 cm, 1e-4 kg m^2 for values near zero).
    #[arg(long, default_value_t = 0.5)]
    spread: f64,
    /// Where to write the calibrated URDF (default: the first log with extension .calibrated.urdf).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the result as JSON instead of a table.
    #[arg(long)]
    json: bool,
}

pub fn run(args: IdentifyArgs) -> Result<()> {
    if !(args.spread > 0.0 && args.spread.is_finite()) {
        bail!("--spread {} is not a positive number", args.spread);
    }
    let mut model = match &args.urdf {
        Some(p) => Some(urdf::load(p)?),
        None => None,
    };
    let mut ne: Option<NormalEquations> = None;
    for log in &args.logs {
        let p = read(log, model.as_ref())?;
        let this = NormalEquations::of(&p.model, &p.trajectory)
            .with_context(|| format!("identifying from {}", log.display()))?;
        match &mut ne {
            Some(sum) => sum.merge(&this),
            None => ne = Some(this),
        }
        model.get_or_insert(p.model);
    }
    let (Some(model), Some(ne)) = (model, ne) else { bail!("no log given") };
    let first = &args.logs[0];
    let c = calibrate(&model, &ne, args.spread).with_context(|| format!("calibrating to {}", first.display()))?;
    let out = args.out.unwrap_or_else(|| first.with_extension("calibrated.urdf"));
    dynforge_proto::run_dir::write_atomic(&out, urdf::to_string(&c.model, &urdf::BaseLink::default()).as_bytes())
        .with_context(|| format!("writing {}", out.display()))?;
    if args.json {
        let parameters: serde_json::Map<String, serde_json::Value> = LABELS
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let v = serde_json::json!({"value": c.labels[k], "urdf": c.before[k], "unit": l.kind.unit()});
                (l.name.to_string(), v)
            })
            .collect();
        let summary = serde_json::json!({
            "logs": args.logs, "torque_rows": ne.rows(), "identifiable": c.rank, "parameters": parameters,
            "torque_nrmse": {"urdf": c.nrmse_before, "least_squares": c.nrmse_least_squares, "calibrated": c.nrmse_after},
            "projections": c.projections, "urdf": out,
        });
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print!("{} log(s), {} torque rows, {c}", args.logs.len(), ne.rows());
        println!("calibrated URDF: {}", out.display());
    }
    Ok(())
}
