//! `dynforge calibrate`: the user's one command for their own arm. The bag is identified from the URDF (as
//! `identify` does), the robot's family is made on the excitations the bag ran (or found in the cache by the hash of
//! the URDF, the excitations and the settings), every variant is identified as the bag was, at the bag's noise, and
//! the spreads the bag's identification reports are given the factors the family measured: standard deviations that
//! hold on this robot, this motion and this noise.

use std::path::{Path, PathBuf};

use crate::flags::{MAX_ROBOTS, weld, whole};
use anyhow::{Context, Result};
use clap::Args;
use dynforge_coordinator::run::{GenerateConfig, GenerateError};
use dynforge_identify::calibrate::family::{Degradation, FamilySpreads, MIN_VARIANTS, MeasureObserver};
use dynforge_identify::calibrate::{
    Calibrated, Kind, Options, check_output, check_ran, identify_logs, write_calibrated,
};
use dynforge_identify::signals::Conditioning;
use dynforge_proto::content_hash_hex;
use dynforge_proto::family::DEFAULT_SPREAD;
use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::lock::LockError;
use dynforge_proto::manifest::Partition;
use dynforge_proto::sim::{EngineKind, SimConfig};
use dynforge_proto::spread::Spread;
use serde_json::json;

use crate::generate::{default_workers, execute, worker_command};
use crate::identify::{Output, Signals, read_urdf_file};

#[derive(Args)]
pub struct CalibrateArgs {
    /// Logs of the robot running the designed excitations: ROS 2 bags with /joint_states (MCAP or sqlite3 .db3
    /// files, or rosbag2 directories), or tables read by --columns.
    #[arg(required = true)]
    logs: Vec<PathBuf>,
    /// The robot's URDF: the values the calibration starts from and the centre of its family.
    #[arg(long)]
    urdf: PathBuf,
    /// The `dynforge excite --out` directory of the excitations the logs ran.
    #[arg(long, value_name = "DIR")]
    excitation: PathBuf,
    /// How far the URDF's values are trusted, relative: the family's spread and the identification's prior. One
    /// number, or per kind (`0.3,com=0.1`; kinds mass, com, inertia, friction).
    #[arg(long, default_value_t = Spread::uniform(DEFAULT_SPREAD))]
    spread: Spread,
    /// Variants of the robot in its family.
    #[arg(long, default_value_t = 64, value_parser = whole::<u64>(MIN_VARIANTS as u64, MAX_ROBOTS))]
    robots: u64,
    /// Worker processes making the family (default: one per CPU core).
    #[arg(long, value_parser = whole::<usize>(1, 1 << 16))]
    workers: Option<usize>,
    /// Where families and what they measured are kept (default: $DYNFORGE_CACHE, else $XDG_CACHE_HOME/dynforge,
    /// else ~/.cache/dynforge).
    #[arg(long, value_name = "DIR")]
    cache: Option<PathBuf>,
    #[command(flatten)]
    signals: Signals,
    /// A joint welded as the excitations were designed (`excite --fix`); the logs' is welded at its mean position.
    #[arg(long, value_name = "JOINT[=POSITION]", value_parser = weld)]
    fix: Vec<(String, f64)>,
    /// Write the calibration even when the search stopped before converging (its values are where it stopped).
    #[arg(long)]
    accept_unconverged: bool,
    #[command(flatten)]
    output: Output,
}

pub fn run(args: CalibrateArgs) -> Result<()> {
    let out = args.output.path(&args.logs);
    let (text, source) = read_urdf_file(&args.urdf)?;
    let document = Some((text.as_str(), source.as_str()));
    let fixed: Vec<String> = args.fix.iter().map(|(name, _)| name.clone()).collect();
    let options = Options {
        spread: args.spread,
        conditioning: args.signals.conditioning(),
        reading: args.signals.reading(&fixed)?,
        // The family is made for the robot as --fix names it: a joint welded here and not there is two robots.
        weld_idle: false,
        accept_unconverged: args.accept_unconverged,
        ..Options::default()
    };

    // The files first, then the bag: what cannot be used is refused before minutes of simulation. The URDF written
    // lands in none of the inputs, the excitations and the families' cache included.
    check_output(&args.logs, document, &args.output.holdout, &out)?;
    args.output.check_mjcf(&args.logs, document, &out)?;
    let cache = cache_dir(args.cache.as_deref())?;
    for written in args.output.written(&out) {
        dynforge_recording::check_not_an_input(&written, std::slice::from_ref(&args.excitation))?;
        // The cache may not exist yet: inside it is inside it all the same.
        if dynforge_proto::run_dir::resolve(&written).starts_with(dynforge_proto::run_dir::resolve(&cache)) {
            anyhow::bail!(
                "{}: this output would overwrite the input {} (the families' cache) or a file of it: choose another \
                 --out or --mjcf",
                written.display(),
                cache.display()
            );
        }
    }
    let (family, sources) = dynforge_worker::family::prepare(
        &args.urdf,
        &args.excitation,
        args.fix.iter().cloned().collect(),
        args.spread,
        EngineKind::Native,
    )?;
    eprintln!("identifying {} log(s) from {}", args.logs.len(), args.urdf.display());
    let (id, read) = identify_logs(&args.logs, document, &options)?;
    for ran in check_ran(&read, &sources.parsed()?)? {
        eprintln!("{ran}");
    }
    let degradation = Degradation::of(&read, id.effort);

    let key = json!({"family": family, "robots": args.robots, "version": env!("CARGO_PKG_VERSION")});
    let dir = cache.join("families").join(content_hash_hex(key.to_string().as_bytes()));
    let cfg = GenerateConfig {
        dir: dir.clone(),
        seed: 0,
        robots: args.robots,
        trajectories: sources.excitations.len() as u32,
        workers: args.workers.unwrap_or_else(default_workers),
        partition: Partition::WHOLE,
        generator: GeneratorConfig::default(),
        sim: SimConfig::default(),
        family: Some((family, sources)),
        job_timeout: std::time::Duration::from_secs(120),
        max_attempts: 3,
        worker_command: worker_command()?,
    };
    if let Err(e) = execute(&cfg, &mut std::io::stderr()) {
        // The family's directory is a run directory, and its lock names the command inside it ("generate"): said
        // as what it is here, a family another process is making.
        let busy = e.chain().find_map(|c| match c.downcast_ref::<GenerateError>() {
            Some(GenerateError::Lock(LockError::Busy { holder, .. })) => Some(holder.process.clone()),
            _ => None,
        });
        return Err(match busy {
            Some(process) => anyhow::anyhow!(
                "{}: the robot's family is being made by another process ({process}: a `calibrate` or `generate` of \
                 the same URDF, excitations and settings); wait for it and run again, and the family is reused",
                dir.display()
            ),
            None => e.context(format!("making the robot's family in {}", dir.display())),
        });
    }

    let variants = Options {
        conditioning: Conditioning {
            velocity: Some(id.velocity.source),
            cutoff: id.velocity.cutoff,
            // The variants' efforts are taken as the bag's were (`Degradation::effort`).
            effort: Some(id.effort),
        },
        ..options.clone()
    };
    let bar = crate::display::bar("identifying the family's variants at the log's noise {bar:30} {pos}/{len}");
    let spreads = FamilySpreads::measure(&dir, document, &degradation, &variants, &mut Measuring(bar))?;
    let mut calibrated = write_calibrated(id, &read, document, &options, &args.output.holdout, &out)?;
    spreads.apply(&mut calibrated.id)?;
    args.output.write_mjcf(&mut calibrated)?;
    match args.output.json {
        true => {
            let mut v = calibrated.json()?;
            v["family"] = json!({"dir": dir, "degradation": degradation, "spreads": spreads});
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        false => print!("{}", Report { calibrated: &calibrated, spreads: &spreads, dir: &dir }),
    }
    Ok(())
}

/// The cache directory: `flag`, else $DYNFORGE_CACHE, else $XDG_CACHE_HOME/dynforge, else ~/.cache/dynforge.
fn cache_dir(flag: Option<&Path>) -> Result<PathBuf> {
    if let Some(dir) = flag {
        return Ok(dir.to_path_buf());
    }
    let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    var("DYNFORGE_CACHE")
        .or_else(|| var("XDG_CACHE_HOME").map(|d| d.join("dynforge")))
        .or_else(|| var("HOME").map(|d| d.join(".cache/dynforge")))
        .context("no cache directory: give --cache DIR (neither DYNFORGE_CACHE, XDG_CACHE_HOME nor HOME is set)")
}

/// What the family's measurement shows: a bar over the variants, refusals above it.
struct Measuring(indicatif::ProgressBar);

impl MeasureObserver for Measuring {
    fn reused(&mut self, path: &Path) {
        self.0.finish_and_clear();
        eprintln!("spreads: measured before at this noise ({})", path.display());
    }

    fn variant(&mut self, k: usize, of: usize) {
        self.0.set_length(of as u64);
        self.0.set_position(k as u64);
    }

    fn refused(&mut self, robot: u64, why: &str) {
        self.0.suspend(|| eprintln!("variant {robot}: refused by the identification: {why}"));
    }

    fn done(&mut self) {
        self.0.finish_and_clear();
    }
}

/// The calibration with what the family measured.
struct Report<'a> {
    calibrated: &'a Calibrated,
    spreads: &'a FamilySpreads,
    dir: &'a Path,
}

impl std::fmt::Display for Report<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.calibrated)?;
        let s = self.spreads;
        writeln!(
            f,
            "spreads: measured on {} variants of the robot's family ({} refused), each identified as the log was, at \
             its noise (a spread the family finds too wide is kept: a simulation cannot show a real robot's departures \
             from the model)",
            s.variants, s.refused,
        )?;
        for kind in Kind::ALL {
            let (n, median, widened) = s.of_kind(kind);
            if n > 0 {
                writeln!(f, "  {:<9} median factor {median:.2}; {widened} of {n} widened", kind.name())?;
            }
        }
        writeln!(f, "family: {}", self.dir.display())
    }
}
