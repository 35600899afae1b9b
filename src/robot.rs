//! `dynforge robot`: generate or inspect robots.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use dynforge_proto::LABELS;
use dynforge_robot::generator::{GeneratorConfig, generate};
use dynforge_robot::{Model, parameters, urdf};

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
        print!("{}", describe(&model));
        return Ok(());
    }
    let config = match &args.config {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            GeneratorConfig::from_toml(&text).with_context(|| format!("in {}", p.display()))?
        }
        None => GeneratorConfig::default(),
    };
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

/// Human-readable summary of a model.
fn describe(model: &Model) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "robot '{}': {} revolute joints, base '{}'", model.name(), model.dof(), model.base());
    let _ = writeln!(
        s,
        "\njoints:\n  {:<4} {:<20} {:<18} {:>17} {:>9} {:>8} {:>9} {:>10}",
        "#", "name", "axis", "limits [rad]", "effort", "vel", "coulomb", "viscous"
    );
    for (i, j) in model.joints().iter().enumerate() {
        let axis = model.axis(i);
        let _ = writeln!(
            s,
            "  {:<4} {:<20} [{:>4.1} {:>4.1} {:>4.1}]  [{:>7.3}, {:>7.3}] {:>9.1} {:>8.2} {:>9.4} {:>10.4}",
            i,
            j.name,
            axis.x,
            axis.y,
            axis.z,
            j.limits.lower,
            j.limits.upper,
            j.limits.effort,
            j.limits.velocity,
            j.friction.coulomb,
            j.friction.viscous
        );
    }
    let _ = writeln!(s, "\nlinks (COM in the link frame; inertia about the COM, link axes):");
    let _ = writeln!(
        s,
        "  {:<4} {:<20} {:>9} {:>28} {:>33} {:>33}",
        "#", "name", "mass", "com [m]", "Ixx Iyy Izz [kg m^2]", "Ixy Ixz Iyz"
    );
    for i in 0..model.dof() {
        let inertia = model.inertia(i);
        let (c, ic) = (inertia.com(), inertia.i_com());
        let _ = writeln!(
            s,
            "  {:<4} {:<20} {:>9.4} [{:>8.4} {:>8.4} {:>8.4}] [{:>10.3e} {:>10.3e} {:>10.3e}] [{:>10.3e} {:>10.3e} {:>10.3e}]",
            i + 1,
            model.links()[i].name,
            inertia.mass,
            c.x,
            c.y,
            c.z,
            ic[(0, 0)],
            ic[(1, 1)],
            ic[(2, 2)],
            ic[(0, 1)],
            ic[(0, 2)],
            ic[(1, 2)]
        );
    }
    if let Ok(y) = parameters::labels(model) {
        let _ = writeln!(s, "\nlabels (the paper's 38 targets):");
        for (l, v) in LABELS.iter().zip(y) {
            let _ = writeln!(s, "  {:<12} {:>12.6} {}", l.name, v, l.kind.unit());
        }
    }
    s
}
