//! `dynforge generate | status | verify | worker`: datasets made by a coordinator and worker processes.

use crate::flags::Engine;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use crate::display::GenerationDisplay;
use crate::flags::{MAX_ROBOTS, weld, whole};
use anyhow::{Context, Result, bail};
use clap::Args;
use dynforge_coordinator::run::{self, GenerateConfig};
use dynforge_coordinator::verify;
use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::manifest::Partition;
use dynforge_proto::sim::{EngineKind, SimConfig};
use dynforge_proto::spread::Spread;

#[derive(Args)]
pub struct GenerateArgs {
    /// Output directory (created if missing). Running the same command on it again resumes.
    #[arg(long, short)]
    out: PathBuf,
    /// Robots in the dataset (the paper: 8192).
    #[arg(long, default_value_t = 8192, value_parser = whole::<u64>(1, MAX_ROBOTS))]
    robots: u64,
    /// Trajectories per robot (the paper: 16; a family: one per excitation).
    #[arg(long, value_parser = whole::<u32>(1, u32::MAX as u64))]
    trajectories: Option<u32>,
    /// Worker processes (default: one per CPU core; at most 4 per core are started).
    #[arg(long, value_parser = whole::<usize>(1, 1 << 16))]
    workers: Option<usize>,
    /// Dataset seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Simulation engine.
    #[arg(long, value_enum, default_value_t = Engine::Native)]
    engine: Engine,
    /// Run only partition i of n (robots r with r % n == i), to split one dataset over several hosts.
    #[arg(long, default_value = "0/1")]
    partition: Partition,
    /// Generator configuration (TOML) for the robot distribution.
    #[arg(long, value_name = "TOML")]
    config: Option<PathBuf>,
    /// Seconds a job may run before its worker counts as hung and is replaced.
    #[arg(long, default_value_t = 120.0)]
    job_timeout: f64,
    /// Your robot's family instead of the generator's robots: variants of this URDF (its kinematics and limits;
    /// inertial parameters and friction drawn around its values), each run on every excitation of --excitation.
    #[arg(long, requires = "excitation", conflicts_with = "config")]
    urdf: Option<PathBuf>,
    /// The `dynforge excite --out` directory of the URDF's excitations.
    #[arg(long, requires = "urdf", value_name = "DIR")]
    excitation: Option<PathBuf>,
    /// A family's relative spread of masses and inertias (log-normal), centres of mass and friction: one number, or
    /// per kind (`0.3,com=0.1`; kinds mass, com, inertia, friction).
    #[arg(long, default_value_t = Spread::uniform(dynforge_proto::family::DEFAULT_SPREAD), requires = "urdf")]
    spread: Spread,
    /// A family's joint welded at a position, as the excitations were designed (`excite --fix`).
    #[arg(long, value_name = "JOINT[=POSITION]", value_parser = weld, requires = "urdf")]
    fix: Vec<(String, f64)>,
}

#[derive(Args)]
pub struct StatusArgs {
    /// The generation's output directory.
    dir: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
pub struct VerifyArgs {
    /// The generation's output directory.
    dir: PathBuf,
    /// Record missing and corrupt shards as failed jobs (moving corrupt files to DIR/quarantine/), so that rerunning
    /// the `generate` command makes them again.
    #[arg(long)]
    repair: bool,
}

#[derive(Args)]
pub struct MergeArgs {
    /// The new directory to write: the run as one host would have written it (shards hard-linked where possible).
    #[arg(long)]
    out: PathBuf,
    /// The partition directories (`generate --partition i/n`), each complete: all n of them, or those j/n with
    /// j % m == i for a divisor m of n, which make partition i/m (a nested subset: 0/8 and 4/8 are robots r % 4 == 0).
    #[arg(required = true)]
    parts: Vec<PathBuf>,
}

#[derive(Args)]
pub struct WorkerArgs {
    /// The run directory whose coordinator started this worker.
    #[arg(long)]
    dir: PathBuf,
    /// The worker's slot among the coordinator's N: its shared-memory channels and its log.
    #[arg(long)]
    slot: usize,
}

pub fn generate(args: GenerateArgs) -> Result<()> {
    let generator = GeneratorConfig::load(args.config.as_deref())?;
    let engine = EngineKind::from(args.engine);
    let job_timeout = match Duration::try_from_secs_f64(args.job_timeout) {
        Ok(d) if !d.is_zero() => d,
        _ => bail!("--job-timeout {}: expected a positive finite number of seconds", args.job_timeout),
    };
    let workers = args.workers.unwrap_or_else(default_workers);
    let family = match (&args.urdf, &args.excitation) {
        (Some(urdf), Some(dir)) => {
            Some(dynforge_worker::family::prepare(urdf, dir, args.fix.into_iter().collect(), args.spread, engine)?)
        }
        _ => None,
    };
    let trajectories = match &family {
        Some((f, _)) => args.trajectories.unwrap_or(f.excitation_hashes.len() as u32),
        None => args.trajectories.unwrap_or(16),
    };
    let cfg = GenerateConfig {
        dir: args.out.clone(),
        seed: args.seed,
        robots: args.robots,
        trajectories,
        workers,
        partition: args.partition,
        generator,
        sim: SimConfig { engine, ..SimConfig::default() },
        family,
        job_timeout,
        max_attempts: 3,
        worker_command: worker_command()?,
    };
    execute(&cfg, &mut std::io::stdout())
}

/// Runs the generation `cfg` with a live display, and reports what was made to `out` (failed jobs are an error
/// naming the directory; discarded ones are not).
pub fn execute(cfg: &GenerateConfig, out: &mut dyn std::io::Write) -> Result<()> {
    eprintln!(
        "generating {} robots x {} trajectories (seed {}, partition {}, engine {}) into {} with {} workers",
        cfg.robots,
        cfg.trajectories,
        cfg.seed,
        cfg.partition,
        cfg.sim.engine.name(),
        cfg.dir.display(),
        cfg.workers
    );
    let start = Instant::now();
    let mut display = GenerationDisplay::default();
    let progress = run::generate(cfg, &mut display)?;
    drop(display);
    let wall = start.elapsed().as_secs_f64();
    let c = progress.cpu_seconds;
    let cpu = format!("; coordinator CPU {c:.2} s ({:.1} % of one core)", 100.0 * c / wall);
    writeln!(
        out,
        "{} jobs: {} ({} resumed from an earlier run) in {wall:.1} s{cpu}",
        progress.total, progress, progress.resumed
    )?;
    Ok(progress.check_failures(&cfg.dir)?)
}

/// The command that starts a worker process: this executable's `worker`.
pub fn worker_command() -> Result<Vec<std::ffi::OsString>> {
    let exe = std::env::current_exe().context("locating the dynforge executable to start workers")?;
    Ok(vec![exe.into(), "worker".into()])
}

/// Worker processes when none are asked for: one per CPU core.
pub fn default_workers() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

pub fn status(args: StatusArgs) -> Result<()> {
    let s = dynforge_coordinator::status::status(&args.dir)?;
    match args.json {
        true => println!("{}", s.json()),
        false => println!("{s}"),
    }
    Ok(())
}

pub fn verify(args: VerifyArgs) -> Result<()> {
    let bar = crate::display::bar("{bar:40} {pos}/{len}");
    let report = verify::verify(&args.dir, |k, n| {
        bar.set_length(n as u64);
        bar.set_position(k as u64);
    })?;
    bar.finish_and_clear();
    print!("{}: {report}", args.dir.display());
    if args.repair && !(report.missing.is_empty() && report.corrupt.is_empty()) {
        let marked = verify::repair(&args.dir, &report)?;
        bail!("{marked} job(s) recorded as failed for their shards; rerun the `generate` command to make them again");
    }
    if report.is_ok() {
        println!("{}", report.intact());
    }
    report.verdict()?;
    Ok(())
}

pub fn merge(args: MergeArgs) -> Result<()> {
    let bar = crate::display::bar("{bar:40} {pos}/{len}");
    let merged = dynforge_coordinator::merge::merge(&args.parts, &args.out, |k, n| {
        bar.set_length(n as u64);
        bar.set_position(k as u64);
    })?;
    bar.finish_and_clear();
    println!("{}: {merged}", args.out.display());
    Ok(())
}

pub fn worker(args: WorkerArgs) -> Result<()> {
    let served = dynforge_worker::serve::serve(&args.dir, args.slot)?;
    eprintln!("worker {}: served {served} jobs", args.slot);
    Ok(())
}
