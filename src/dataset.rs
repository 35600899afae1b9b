//! `dynforge dataset`: what a dataset holds and how many windows each preprocessing geometry makes of it (`stats`);
//! its training cache built ahead of training, and its shards pruned once cached (`prepare`).

use crate::flags::Estimator;
use std::path::PathBuf;
use std::sync::atomic::Ordering;

use crate::display::{Bars, STOP, catch_interrupts};
use anyhow::Result;
use clap::{Args, Subcommand};
use dynforge_coordinator::prune::prune;
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::prepare::{ModelKind, prepare};
use dynforge_dataset::window::WindowSpec;
use dynforge_dataset::windows::{AROUND_THE_BEST, stats};
use dynforge_trainer::training::session::SessionObserver;

#[derive(Subcommand)]
pub enum DatasetCommand {
    /// Robots, trajectories, hours of motion, windows per configuration and label ranges of a dataset.
    Stats(StatsArgs),
    /// Build the cache `train` reads (physics or windows) without training; with --prune, then delete the shards,
    /// whose data the cache holds (bounded disk: generate, prepare --prune and merge a run partition by partition).
    Prepare(PrepareArgs),
}

#[derive(Args)]
pub struct PrepareArgs {
    /// A finished `dynforge generate` directory (or partition).
    dir: PathBuf,
    /// The estimator whose cache to build.
    #[arg(long, value_enum, default_value = "physics")]
    model: Estimator,
    /// Window geometry, as `train` takes it (`--len`, `--stride`, `--ssr`, and `--hop` where the windows overlap).
    #[arg(long = "window", value_name = "LEN:STRIDE:SSR[:HOP]", default_value = "64:64:16")]
    window: WindowSpec,
    /// Then delete the shards (recorded in DIR/pruned.txt): `train` with these settings, `merge` and `verify` still
    /// work; other settings, the torque and identification checks need shards.
    #[arg(long)]
    prune: bool,
}

#[derive(Args)]
pub struct StatsArgs {
    /// A `generate` output directory, or a folder of shards.
    dir: PathBuf,
    /// Window geometries to count, as LEN:STRIDE:SSR[:HOP] (default: the paper's grid around its best, 64:64:16).
    #[arg(long = "window", value_name = "LEN:STRIDE:SSR[:HOP]")]
    windows: Vec<WindowSpec>,
    /// Also list the input features of a time step (for the first readable shard's robot).
    #[arg(long)]
    features: bool,
}

#[derive(Args)]
pub struct InfoArgs {
    /// A log: a dataset shard, a ROS 2 bag (MCAP or sqlite3 .db3 file, or rosbag2 directory), or a table read by
    /// --columns.
    log: PathBuf,
    /// The column map of a table (see `dynforge identify --help`).
    #[arg(long, value_name = "MAP.toml")]
    columns: Option<PathBuf>,
    /// The robot's URDF, for what `identify` and `estimate` would read (default: the log's /robot_description).
    #[arg(long)]
    urdf: Option<PathBuf>,
}

pub fn info(args: InfoArgs) -> Result<()> {
    let columns = args.columns.as_deref().map(dynforge_recording::table::ColumnMap::read).transpose()?;
    // `info` shows a table's columns as the map reads them (a current without a gain as it is).
    let how = dynforge_recording::Reading { columns, ..Default::default() };
    let (files, bag) = dynforge_recording::read_bag(&args.log, &how)?;
    let info = dynforge_recording::info::Info::of_bag(&args.log, &files, &bag)?;
    print!("{info}");
    let described = matches!(info.robot, Some(Ok(_)));
    let given = crate::identify::read_urdf(args.urdf.as_deref())?;
    let document = given.as_ref().map(|(text, source)| (text.as_str(), source.as_str()));
    print!("{}", dynforge_identify::calibrate::Readiness::of(files, bag, described, document));
    Ok(())
}

fn prepare_cache(args: PrepareArgs) -> Result<()> {
    let spec = args.window;
    catch_interrupts();
    let model = ModelKind::from(args.model);
    if model == ModelKind::Physics {
        eprintln!("fitting the generator's parameter prior to {} robots", dynforge_dataset::evidence::PRIOR_ROBOTS);
    }
    let mut bars = Bars::new(1);
    let progress = |what: &str, k, n| {
        if what != "verify" {
            bars.preprocessing(what, k, n);
        }
        !STOP.load(Ordering::Relaxed)
    };
    let held = if args.prune {
        let pruned = prune(&args.dir, model, &spec, progress)?;
        format!("{}; {} shards pruned", pruned.cache, pruned.shards)
    } else {
        prepare(&args.dir, model, &spec, progress)?.what
    };
    drop(bars);
    println!("{}: {held}", args.dir.display());
    Ok(())
}

pub fn run(cmd: DatasetCommand) -> Result<()> {
    let args = match cmd {
        DatasetCommand::Stats(args) => args,
        DatasetCommand::Prepare(args) => return prepare_cache(args),
    };
    let specs = match args.windows.is_empty() {
        true => AROUND_THE_BEST.to_vec(),
        false => args.windows,
    };
    let s = stats(&args.dir, &specs)?;
    print!("{}: {}", args.dir.display(), s.report(&specs));
    if args.features
        && let Some(model) = &s.model
    {
        print!("{}", JacobianFeatures::new(model).describe(model));
    }
    for skipped in &s.skipped {
        eprintln!("skipped: {skipped}");
    }
    Ok(())
}
