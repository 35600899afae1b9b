//! `dynforge excite`: excitation trajectories designed for a robot's URDF, to record before `identify`.

use std::path::PathBuf;

use crate::flags::{non_negative, positive, weld, whole};
use anyhow::{Context, Result};
use clap::Args;
use dynforge_excite::write::{summary, write_design};
use dynforge_excite::{MAX_WRITTEN_SAMPLES, Options, SelfCollision, design_with, start_pose};
use dynforge_robot::urdf;

#[derive(Args)]
pub struct ExciteArgs {
    /// The robot's URDF (its limits bound the motion; its parameters give the efforts and the scales).
    #[arg(long)]
    urdf: PathBuf,
    /// Directory to write the trajectories (CSV and their Fourier series as JSON) and report.md into.
    #[arg(long)]
    out: PathBuf,
    /// Duration of each trajectory [s].
    #[arg(long, default_value_t = 10.0, value_parser = positive)]
    duration: f64,
    /// Number of trajectories (designed together: each excites what the others leave weak).
    #[arg(long, default_value_t = 4, value_parser = whole::<usize>(1, 64))]
    count: usize,
    /// Harmonics per joint (the highest frequency is harmonics / duration).
    #[arg(long, default_value_t = 5, value_parser = whole::<usize>(1, 100))]
    harmonics: usize,
    /// Acceleration limit [rad/s^2 or m/s^2]: one for every joint, or one per joint separated by commas.
    #[arg(long, value_delimiter = ',', default_value = "5")]
    acceleration: Vec<f64>,
    /// Pose to start and end at, one value per joint separated by commas (default: the middle of each range).
    #[arg(long, value_delimiter = ',')]
    start: Option<Vec<f64>>,
    /// Share of the URDF's velocity limits the motion may use.
    #[arg(long, default_value_t = 0.8, value_parser = positive)]
    velocity_share: f64,
    /// Share of the URDF's effort limits the motion may need (computed with the URDF's own parameters).
    #[arg(long, default_value_t = 0.8, value_parser = positive)]
    effort_share: f64,
    /// Candidates judged per trajectory (the design's time grows with it).
    #[arg(long, default_value_t = 1500, value_parser = whole::<usize>(1, 10_000_000))]
    evaluations: usize,
    /// Rate of the written CSV [Hz].
    #[arg(long, default_value_t = 500.0, value_parser = positive)]
    rate: f64,
    /// Torque noise [N m]: one for every joint, or one per joint separated by commas. The design weighs each joint's
    /// torques by the inverse of its noise (a noisy joint's torques tell less), and the report's expected standard
    /// deviations assume it.
    #[arg(long, value_delimiter = ',', default_value = "0.1")]
    noise: Vec<f64>,
    /// Weld this joint (a gripper's, say) at a position: NAME or NAME=POSITION (default 0); repeatable.
    #[arg(long, value_name = "JOINT[=POSITION]", value_parser = weld)]
    fix: Vec<(String, f64)>,
    /// Distance [m] below which two bodies of the arm count as touching (padding on top of the convex hulls).
    #[arg(long, default_value_t = 0.0, value_parser = non_negative)]
    clearance: f64,
    /// Do not check self-collision (for a URDF whose collision meshes cannot be read: only STL is; `package://` is
    /// looked for in ROS_PACKAGE_PATH, AMENT_PREFIX_PATH and above the URDF).
    #[arg(long)]
    no_collision: bool,
    /// Seed of the search (the same seed, the same trajectories).
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

pub fn run(args: ExciteArgs) -> Result<()> {
    let text = std::fs::read_to_string(&args.urdf).with_context(|| format!("reading {}", args.urdf.display()))?;
    let welds: urdf::Welds = args.fix.into_iter().collect();
    let model = urdf::parse_welded(&text, &args.urdf.display().to_string(), &welds)?;
    let options = Options {
        duration: args.duration,
        count: args.count,
        harmonics: args.harmonics,
        start: args.start,
        acceleration: args.acceleration,
        velocity_share: args.velocity_share,
        effort_share: args.effort_share,
        evaluations: args.evaluations,
        noise: args.noise,
        seed: args.seed,
        ..Options::default()
    };
    let written = args.duration * args.rate;
    if written > MAX_WRITTEN_SAMPLES {
        anyhow::bail!(
            "--duration {} s at --rate {} Hz writes {written:.1e} samples per trajectory, more than {MAX_WRITTEN_SAMPLES:e}: \
             give a lower --rate (a controller takes 100-1000 Hz) or a shorter --duration",
            args.duration,
            args.rate
        );
    }
    let bar = crate::display::bar("{msg} [{bar:40}] {pos}/{len} candidates ({eta} left)");
    bar.set_message(format!("designing {} excitations of {}", options.count, model.name()));
    let collision = match args.no_collision {
        true => None,
        false => {
            let geometry = urdf::collision_bodies(&text, &args.urdf.display().to_string(), &welds)?;
            let start = start_pose(&model, &options)?;
            Some(SelfCollision::new(&model, &geometry, &args.urdf, &start, args.clearance)?)
        }
    };
    let design = design_with(&model, &options, collision.as_ref(), |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .with_context(|| format!("designing excitations for {}", args.urdf.display()))?;
    bar.finish_and_clear();
    let files = write_design(&args.out, &model, &design, &options, args.rate)?;
    print!("{}", summary(&model, &design, &options));
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}
