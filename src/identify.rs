//! `dynforge identify`: calibrates a robot's URDF to its logs by physics alone (no trained network).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use dynforge_identify::calibrate::{Options, held_out, nominal};
use dynforge_identify::identify_logs;
use dynforge_identify::signals::{Conditioning, EffortConvention, VelocitySource};
use dynforge_proto::run_dir::write_atomic;
use dynforge_robot::parameters::dynamic_parameters;
use dynforge_robot::urdf;

#[derive(Args)]
pub struct IdentifyArgs {
    /// Logs of one robot: shards or ROS 2 bags (MCAP files or rosbag2 directories) with /joint_states.
    #[arg(required = true)]
    logs: Vec<PathBuf>,
    /// The robot's URDF, the starting point and prior (default: the first log's /robot_description).
    #[arg(long)]
    urdf: Option<PathBuf>,
    /// How far the URDF's values are trusted, relative: masses and inertias within ~this share, centres of mass
    /// within this share of their offset or of the link's radius of gyration, friction within this share or 2 % of
    /// the joint's effort limit.
    #[arg(long, default_value_t = 0.5)]
    spread: f64,
    /// What the logged effort is: the torque held until the next sample (zero-order hold, a commanded torque), or
    /// the torque sampled at its stamp (a measured one). Auto: the one that fits the logs better.
    #[arg(long, value_enum, default_value_t = Effort::Auto)]
    effort: Effort,
    /// Where the velocity comes from. Auto: the log's, unless it has none or it is the difference of its encoder
    /// positions; then differences of the positions low-passed at --cutoff.
    #[arg(long, value_enum, default_value_t = Velocity::Auto)]
    velocity: Velocity,
    /// Low-pass cut-off [Hz] for velocities from positions (default: chosen from the positions' noise).
    #[arg(long)]
    cutoff: Option<f64>,
    /// Weld this joint at its mean logged position (a joint the logs do not move, e.g. a gripper's); repeatable.
    #[arg(long, value_name = "JOINT")]
    fix: Vec<String>,
    /// Logs held out of the calibration: the torque error of the URDF as given and of the calibrated one on them is
    /// reported.
    #[arg(long, value_name = "LOG")]
    holdout: Vec<PathBuf>,
    /// Where to write the calibrated URDF (default: the first log with extension .calibrated.urdf).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the result as JSON instead of tables.
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, ValueEnum)]
enum Effort {
    Auto,
    Held,
    Sampled,
}

#[derive(Clone, Copy, ValueEnum)]
enum Velocity {
    Auto,
    Logged,
    Positions,
}

pub fn run(args: IdentifyArgs) -> Result<()> {
    if !(args.spread > 0.0 && args.spread.is_finite()) {
        bail!("--spread {} is not a positive number", args.spread);
    }
    if let Some(fc) = args.cutoff.filter(|fc| !(*fc > 0.0 && fc.is_finite())) {
        bail!("--cutoff {fc} is not a positive frequency");
    }
    let out = args.out.clone().unwrap_or_else(|| args.logs[0].with_extension("calibrated.urdf"));
    let inputs: Vec<PathBuf> = args.logs.iter().chain(&args.holdout).chain(&args.urdf).cloned().collect();
    dynforge_recording::check_not_an_input(&out, &inputs)?;
    let given = match &args.urdf {
        Some(path) => Some((
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?,
            path.display().to_string(),
        )),
        None => None,
    };
    let document = given.as_ref().map(|(text, source)| (text.as_str(), source.as_str()));
    let options = Options {
        spread: args.spread,
        conditioning: Conditioning {
            velocity: match args.velocity {
                Velocity::Auto => None,
                Velocity::Logged => Some(VelocitySource::Logged),
                Velocity::Positions => Some(VelocitySource::Positions),
            },
            effort: match args.effort {
                Effort::Auto => None,
                Effort::Held => Some(EffortConvention::Held),
                Effort::Sampled => Some(EffortConvention::Sampled),
            },
            cutoff: args.cutoff,
        },
        fixed: args.fix.clone(),
    };
    let (mut id, logs) = identify_logs(&args.logs, document, &options)?;
    let log = &logs[0];
    let (text, notes) = urdf::patch_welded(&log.document, &log.source, &id.model, &log.welds)?;
    id.notes.extend(notes);
    write_atomic(&out, text.as_bytes()).with_context(|| format!("writing {}", out.display()))?;
    // What is reported is what the file holds: the written URDF read back.
    let written = urdf::parse_welded(&text, &out.display().to_string(), &log.welds)?;
    id.report_values_of(&written);
    let holdout = match args.holdout.is_empty() {
        true => None,
        false => {
            let ne = held_out(&args.holdout, document, &options, &id)?;
            Some((ne.mean_nrmse(&nominal(&log.model)), ne.mean_nrmse(&dynamic_parameters(&written))))
        }
    };
    if args.json {
        let mut v = serde_json::to_value(&id)?;
        v["urdf"] = serde_json::json!(out);
        if let Some((urdf, calibrated)) = holdout {
            v["held_out"] =
                serde_json::json!({"logs": args.holdout, "nrmse_urdf": urdf, "nrmse_calibrated": calibrated});
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    print!("{id}");
    if let Some((urdf, calibrated)) = holdout {
        println!(
            "torque NRMSE on {} held-out log(s): calibrated {calibrated:.4}, URDF as given {urdf:.4}",
            args.holdout.len()
        );
    }
    println!("calibrated URDF: {}", out.display());
    Ok(())
}
