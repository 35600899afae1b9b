//! `dynforge simulate`: one job by hand.

use crate::flags::Engine;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::job::Job;
use dynforge_proto::sim::EngineKind;
use dynforge_proto::sim::SimConfig;
use dynforge_worker::job::Runner;
use dynforge_worker::output::Outcome;

#[derive(Args)]
pub struct SimulateArgs {
    /// Dataset seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Robot index within the dataset.
    #[arg(long, default_value_t = 0)]
    robot: u64,
    /// Trajectory index (0-15: the move from waypoint T to waypoint T+1 of the robot's tour).
    #[arg(long, default_value_t = 0)]
    trajectory: u32,
    /// Directory the shard is written to (created if missing).
    #[arg(long, short)]
    out: PathBuf,
    /// Simulation engine.
    #[arg(long, value_enum, default_value_t = Engine::Native)]
    engine: Engine,
}

pub fn run(args: SimulateArgs) -> Result<()> {
    let engine = EngineKind::from(args.engine);
    let sim = SimConfig { engine, ..SimConfig::default() };
    if sim.trajectory.waypoints <= args.trajectory as usize {
        anyhow::bail!(
            "--trajectory {} is out of range: robots have {} trajectories",
            args.trajectory,
            sim.trajectory.waypoints
        );
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let mut runner = Runner::new(GeneratorConfig::default(), sim);
    let job = Job { seed: args.seed, robot: args.robot, trajectory: args.trajectory };
    let start = Instant::now();
    let outcome = runner.run(&job, &args.out)?;
    let wall = start.elapsed().as_secs_f64();
    let what = format!("seed {} robot {} trajectory {} ({})", job.seed, job.robot, job.trajectory, engine.name());
    match outcome {
        Outcome::Written { path, samples, duration, saturated, .. } => println!(
            "{what}: {duration:.3} s of motion, {samples} samples at 1 kHz, torque saturated in {:.1} % of samples, \
             simulated in {wall:.2} s ({:.1}x real time)\nwrote {}",
            100.0 * saturated,
            duration / wall,
            path.display()
        ),
        Outcome::Discarded(d) => println!("{what}: discarded ({}): {d}; no shard written", d.code()),
    }
    Ok(())
}
