//! `dynforge excite`: excitation trajectories designed for a robot's URDF, to record before `identify`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use dynforge_excite::{Options, design_with, write::write_design};
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
    #[arg(long, default_value_t = 10.0)]
    duration: f64,
    /// Number of trajectories (designed together: each excites what the others leave weak).
    #[arg(long, default_value_t = 4)]
    count: usize,
    /// Harmonics per joint (the highest frequency is harmonics / duration).
    #[arg(long, default_value_t = 5)]
    harmonics: usize,
    /// Acceleration limit [rad/s^2 or m/s^2]: one for every joint, or one per joint separated by commas.
    #[arg(long, value_delimiter = ',', default_value = "5")]
    acceleration: Vec<f64>,
    /// Pose to start and end at, one value per joint separated by commas (default: the middle of each range).
    #[arg(long, value_delimiter = ',')]
    start: Option<Vec<f64>>,
    /// Share of the URDF's velocity limits the motion may use.
    #[arg(long, default_value_t = 0.8)]
    velocity_share: f64,
    /// Share of the URDF's effort limits the motion may need (computed with the URDF's own parameters).
    #[arg(long, default_value_t = 0.8)]
    effort_share: f64,
    /// Candidates judged per trajectory (the design's time grows with it).
    #[arg(long, default_value_t = 1500)]
    evaluations: usize,
    /// Rate of the written CSV [Hz].
    #[arg(long, default_value_t = 500.0)]
    rate: f64,
    /// Torque noise [N m] the report's expected standard deviations assume.
    #[arg(long, default_value_t = 0.1)]
    noise: f64,
    /// Weld this joint (a gripper's, say) at a position: NAME or NAME=POSITION (default 0); repeatable.
    #[arg(long, value_name = "JOINT[=POSITION]")]
    fix: Vec<String>,
    /// Seed of the search (the same seed, the same trajectories).
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

pub fn run(args: ExciteArgs) -> Result<()> {
    let text = std::fs::read_to_string(&args.urdf).with_context(|| format!("reading {}", args.urdf.display()))?;
    let mut welds = urdf::Welds::new();
    for f in &args.fix {
        let (name, at) = match f.split_once('=') {
            Some((name, at)) => {
                (name, at.parse::<f64>().with_context(|| format!("--fix {f}: the position is not a number"))?)
            }
            None => (f.as_str(), 0.0),
        };
        welds.insert(name.to_string(), at);
    }
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
        seed: args.seed,
        ..Options::default()
    };
    let bar = crate::progress::bar("{msg} [{bar:40}] {pos}/{len} candidates ({eta} left)");
    bar.set_message(format!("designing {} excitations of {}", options.count, model.name()));
    let design = design_with(&model, &options, |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .with_context(|| format!("designing excitations for {}", args.urdf.display()))?;
    bar.finish_and_clear();
    let files = write_design(&args.out, &model, &design, &options, args.rate, args.noise)?;
    let (d, r) = (&design.together, &design.random_together);
    println!(
        "{} trajectories of {} s for {} ({} of {} parameter combinations identifiable)",
        options.count,
        options.duration,
        model.name(),
        design.base.rank(),
        design.scales.len()
    );
    println!(
        "condition number {:.3e} (random multi-sines within the same limits: {:.3e}); base covariance {:.1}x smaller",
        d.condition,
        r.condition,
        r.trace / d.trace
    );
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}
