//! `dynforge identify`: calibrates a robot's URDF to its logs by physics alone (no trained network).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use dynforge_identify::calibrate_files;
use dynforge_proto::run_dir::write_atomic;
use dynforge_recording::robot_document;
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
    // The calibration is written into the user's URDF, or else into the first log's description.
    let (document, source) = robot_document(args.urdf.as_deref(), &args.logs[0])?;
    let model = args.urdf.as_ref().map(|_| urdf::parse(&document, &source)).transpose()?;
    let c = calibrate_files(&args.logs, model, args.spread)?;
    let out = args.out.unwrap_or_else(|| args.logs[0].with_extension("calibrated.urdf"));
    let (text, notes) = urdf::patch(&document, &source, &c.calibration.model)?;
    for n in notes {
        eprintln!("note: {n}");
    }
    write_atomic(&out, text.as_bytes()).with_context(|| format!("writing {}", out.display()))?;
    match args.json {
        true => println!("{}", serde_json::to_string_pretty(&c.json(&out))?),
        false => println!("{c}calibrated URDF: {}", out.display()),
    }
    Ok(())
}
