//! The `dynforge` command line: parses arguments and dispatches to the library crates.

mod calibrate;
mod dataset;
mod display;
mod estimate;
mod evaluate;
mod excite;
mod flags;
mod generate;
mod identify;
mod pipeline;
mod robot;
mod simulate;
mod sweep;
mod train;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

// burn's attention allocates tensors above glibc's mmap threshold every step; mimalloc reuses them (measured ~45 %
// faster training, ../docs/development.md).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

unsafe extern "C" {
    /// mimalloc's option setter (exported by the library the `mimalloc` crate links).
    fn mi_option_set(option: std::ffi::c_int, value: std::ffi::c_long);
}

/// `mi_option_purge_delay` in the option enum of mimalloc v3, the version `libmimalloc-sys` builds (the crate has no
/// constant for it).
const MI_OPTION_PURGE_DELAY: std::ffi::c_int = 15;

/// dynforge: learn the dynamic parameters of robot manipulators (mass, inertia, centre of mass, joint friction)
/// from joint trajectories.
#[derive(Parser)]
#[command(name = "dynforge", version, about, long_about = None, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate a random robot of the dataset distribution as URDF, or inspect a URDF file.
    Robot(robot::RobotArgs),
    /// Simulate one job (robot x trajectory) by hand and write its shard.
    Simulate(simulate::SimulateArgs),
    /// Generate (or resume) a dataset: a coordinator plus N worker processes.
    Generate(generate::GenerateArgs),
    /// Show the progress of a generation (live from its coordinator, or from its ledger).
    Status(generate::StatusArgs),
    /// Check every shard of a dataset against its ledger and manifest.
    Verify(generate::VerifyArgs),
    /// Merge the partition directories of one run (`generate --partition i/n`) into the single-host directory (or
    /// into a coarser partition of it).
    Merge(generate::MergeArgs),
    /// What a log holds (shard or ROS 2 bag, a file or a rosbag2 directory): joint states, rate, robot, labels, and
    /// which commands can take it (identify, estimate) or why not.
    Info(dataset::InfoArgs),
    /// Inspect a dataset of shards.
    #[command(subcommand)]
    Dataset(dataset::DatasetCommand),
    /// Train an estimator on a dataset: physics-informed (default) or the paper's transformer (checkpoint every
    /// epoch; Ctrl-C saves, --resume continues).
    Train(train::TrainArgs),
    /// Score a checkpoint on its validation robots: the paper's tables, per-robot scores, the torque check and
    /// the identification check (network, physics and hybrid side by side).
    Evaluate(evaluate::EvaluateArgs),
    /// Estimate the parameters of a robot of the family a model was trained on from its log (shard or ROS 2 bag),
    /// refined by its torques, and write its URDF; a robot of another family is refused (`identify` serves it).
    Estimate(estimate::EstimateArgs),
    /// Calibrate any serial arm's URDF to its logs (ROS 2 bags) by physics: every link's mass, centre of mass and
    /// inertia (physically valid) and every joint's friction, each with its standard deviation; no training needed.
    Identify(identify::IdentifyArgs),
    /// Design excitation trajectories for a robot's URDF: Fourier series within its limits, starting and ending at
    /// rest, free of self-collision with its collision geometry, optimized so that the logs recorded while running
    /// them identify its parameters best.
    Excite(excite::ExciteArgs),
    /// Calibrate your arm's URDF to bags of it running the designed excitations, with spreads measured on its
    /// family: identify the bag, make (or reuse from the cache) the robot's variants on the same motion, identify
    /// each at the bag's noise, and give every parameter the standard deviation that holds there.
    Calibrate(calibrate::CalibrateArgs),
    /// Generate a small dataset, train, evaluate and print the tables: the whole system in one command.
    Pipeline(pipeline::PipelineArgs),
    /// Run the paper's dataset and architecture grids at a chosen scale and write both tables.
    Sweep(sweep::SweepArgs),
    /// A worker process (started by `generate`).
    #[command(hide = true)]
    Worker(generate::WorkerArgs),
}

fn main() -> std::process::ExitCode {
    // Like any Unix filter, end quietly when the reader of our output goes away (`dynforge ... | head`).
    // SAFETY: restoring the default disposition of SIGPIPE before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Memory freed is kept for a second before it goes back to the system, not 10 ms: reading an hour-long log
    // decompresses megabyte chunks one after another, and each would otherwise be faulted in and zeroed anew (a
    // quarter of `identify`'s time went to the kernel clearing pages).
    // MIMALLOC_PURGE_DELAY, when set, is mimalloc's own setting and is left to it.
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: setting an option of the allocator, which it reads when it next purges.
        unsafe { mi_option_set(MI_OPTION_PURGE_DELAY, 1000) };
    }
    let cli = match Cli::from_arg_matches(&negative_values(Cli::command()).get_matches()) {
        Ok(cli) => cli,
        Err(e) => e.exit(),
    };
    let result = match cli.command {
        Command::Robot(args) => robot::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Generate(args) => generate::generate(args),
        Command::Status(args) => generate::status(args),
        Command::Verify(args) => generate::verify(args),
        Command::Worker(args) => generate::worker(args),
        Command::Merge(args) => generate::merge(args),
        Command::Info(args) => dataset::info(args),
        Command::Dataset(cmd) => dataset::run(cmd),
        Command::Train(args) => train::run(args),
        Command::Evaluate(args) => evaluate::run(args),
        Command::Estimate(args) => estimate::run(args),
        Command::Identify(args) => identify::run(args),
        Command::Excite(args) => excite::run(args),
        Command::Calibrate(args) => calibrate::run(args),
        Command::Pipeline(args) => pipeline::run(args),
        Command::Sweep(args) => sweep::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", chain(&e));
            match interrupted(&e) {
                // The shell's convention for a command a signal ended: 128 + the signal's number.
                true => std::process::ExitCode::from(128 + libc::SIGINT as u8),
                false => std::process::ExitCode::FAILURE,
            }
        }
    }
}

/// Whether the command failed because Ctrl-C or SIGTERM stopped it (the commands that catch them end with an error
/// that says where they stopped): scripts then tell a stopped run from a failed one by the exit status.
fn interrupted(e: &anyhow::Error) -> bool {
    use std::sync::atomic::Ordering;
    crate::display::STOP.load(Ordering::Relaxed)
        || e.chain().any(|c| {
            matches!(
                c.downcast_ref::<dynforge_coordinator::run::GenerateError>(),
                Some(dynforge_coordinator::run::GenerateError::Interrupted { .. })
            )
        })
}

/// `cmd` with every option that takes a value taking `-1` as one: then the option's parser says what is wrong with
/// it (`--robots -1`: "expected a whole number from 1 to ..."), where clap would take it for an unknown flag.
fn negative_values(cmd: clap::Command) -> clap::Command {
    cmd.mut_args(|a| match a.get_action().takes_values() {
        true => a.allow_negative_numbers(true),
        false => a,
    })
    .mut_subcommands(negative_values)
}

/// The error and its causes, each said once: library errors often quote their cause (`FILE: Is a directory (os error
/// 21)`), so a cause already in the text is not repeated.
fn chain(e: &anyhow::Error) -> String {
    let mut out = e.to_string();
    for cause in e.chain().skip(1).map(|c| c.to_string()) {
        if !out.contains(&cause) {
            out = format!("{out}: {cause}");
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--help` is the reference a user reads first: every option of every command, nested ones included, says what
    /// it is (clap prints an option without a doc comment with an empty line).
    #[test]
    fn every_option_of_every_command_has_help() {
        fn walk(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
            for arg in cmd.get_arguments() {
                let id = arg.get_id().as_str();
                if id == "help" || id == "version" || arg.get_help().is_some() || arg.get_long_help().is_some() {
                    continue;
                }
                missing.push(format!("{path} {}", arg.get_long().map_or(id.to_string(), |l| format!("--{l}"))));
            }
            for sub in cmd.get_subcommands() {
                walk(sub, &format!("{path} {}", sub.get_name()), missing);
            }
        }
        let mut missing = Vec::new();
        walk(&Cli::command(), "dynforge", &mut missing);
        assert!(missing.is_empty(), "options without help: {missing:?}");
    }
}
