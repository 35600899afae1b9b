//! `dynforge identify`: calibrates a robot's URDF to its logs by physics alone (no trained network).

use std::path::{Path, PathBuf};

use crate::flags::positive;
use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use dynforge_identify::calibrate::{Calibrated, Options, RunToRun, calibrate_to_urdf, check_output};
use dynforge_identify::signals::{Conditioning, EffortConvention, VelocitySource};
use dynforge_proto::spread::Spread;
use dynforge_recording::Reading;
use dynforge_recording::table::ColumnMap;

#[derive(Args)]
pub struct IdentifyArgs {
    /// Logs of one robot: ROS 2 bags with /joint_states (MCAP or sqlite3 .db3 files, or rosbag2 directories), shards,
    /// or tables (.csv, .tsv, .txt, .dat) read by --columns.
    #[arg(required = true)]
    logs: Vec<PathBuf>,
    /// The robot's URDF, the starting point and prior (default: the first log's /robot_description).
    #[arg(long)]
    urdf: Option<PathBuf>,
    /// How far the URDF's values are trusted, relative: each mass and each inertia tensor's scale within ~this
    /// share (independently; the tensor's shape within half of it), centres of mass within this share of their
    /// distance from the link's origin (at least 1 cm), friction within this share of its value, or of a typical
    /// friction where the URDF states less (Coulomb: 10 % of the joint's effort limit; viscous: 20 % of it over the
    /// speed limit). One number, or per kind (`0.5,com=0.1`; kinds mass, com, inertia, friction).
    #[arg(long, default_value_t = Spread::uniform(0.5))]
    spread: Spread,
    #[command(flatten)]
    signals: Signals,
    /// Weld this joint at its mean logged position (a joint the logs do not move, e.g. a gripper's); repeatable.
    #[arg(long, value_name = "JOINT")]
    fix: Vec<String>,
    /// Write the calibration even when the search stopped before converging (its values are where it stopped).
    #[arg(long)]
    accept_unconverged: bool,
    /// How far a joint's friction moves from one run of the arm to the next (temperature, lubricant), as a share of
    /// its value (its offset: of its Coulomb friction); each log counts as a run. Gives friction and offsets a spread
    /// over runs beside the one run's (0: none). `measured`: from the scatter between the logs, each identified alone
    /// (several logs; one takes 0.05, the real UR10e's measured scatter).
    #[arg(long, value_name = "SHARE|measured", default_value = "measured", value_parser = run_to_run)]
    run_to_run: RunToRun,
    #[command(flatten)]
    output: Output,
}

/// `measured`, or a share: a finite number from 0 to 1.
fn run_to_run(s: &str) -> Result<RunToRun, String> {
    match (s.trim(), s.trim().parse::<f64>()) {
        ("measured", _) => Ok(RunToRun::Measured),
        (_, Ok(v)) if (0.0..=1.0).contains(&v) => Ok(RunToRun::Share(v)),
        _ => Err("expected `measured` or a number from 0 to 1".into()),
    }
}

/// Where a calibration goes (shared by `identify` and `calibrate`).
#[derive(Args)]
pub struct Output {
    /// Logs held out of the calibration: the torque error of the URDF as given and of the calibrated one on them is
    /// reported. Takes every log that follows it (`--holdout a.mcap b.mcap`), up to the next flag.
    #[arg(long, value_name = "LOG", num_args = 1..)]
    pub holdout: Vec<PathBuf>,
    /// Where to write the calibrated URDF (default: the first log with extension .calibrated.urdf).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write the calibrated robot as a MuJoCo model (MJCF): its bodies, friction (frictionloss, damping) and
    /// each joint's rotor inertia (armature), which a URDF cannot hold; the joints' torque offsets as its numeric
    /// `offset`.
    #[arg(long, value_name = "FILE.xml")]
    mjcf: Option<PathBuf>,
    /// Print the result as JSON instead of tables.
    #[arg(long)]
    pub json: bool,
}

impl Output {
    /// The calibrated URDF's path: `--out`, else the first log's with extension .calibrated.urdf.
    pub fn path(&self, logs: &[PathBuf]) -> PathBuf {
        self.out.clone().unwrap_or_else(|| logs[0].with_extension("calibrated.urdf"))
    }

    /// An error if the MuJoCo model asked for would land on an input or on the URDF written (`out`).
    pub fn check_mjcf(&self, logs: &[PathBuf], document: Option<(&str, &str)>, out: &Path) -> Result<()> {
        let Some(mjcf) = &self.mjcf else { return Ok(()) };
        check_output(logs, document, &self.holdout, mjcf)?;
        dynforge_recording::check_not_an_input(mjcf, &[out.to_path_buf()])
            .context("--mjcf and the calibrated URDF (--out) name the same file")?;
        Ok(())
    }

    /// The files a calibration writes: the URDF `out`, and the MuJoCo model if asked.
    pub fn written(&self, out: &Path) -> Vec<PathBuf> {
        std::iter::once(out.to_path_buf()).chain(self.mjcf.clone()).collect()
    }

    /// Writes the MuJoCo model, if asked.
    pub fn write_mjcf(&self, calibrated: &mut Calibrated) -> Result<()> {
        if let Some(mjcf) = &self.mjcf {
            calibrated.write_mjcf(mjcf)?;
        }
        Ok(())
    }
}

/// How the logs' signals are read (shared by `identify` and `calibrate`).
#[derive(Args)]
pub struct Signals {
    /// What the logged effort is: the torque held until the next sample (zero-order hold, a commanded torque), or
    /// the torque sampled at its stamp (a measured one). Auto: the one that fits the logs better.
    #[arg(long, value_enum, default_value_t = Effort::Auto)]
    effort: Effort,
    /// Where the velocity comes from. Auto: the log's, unless it has none or it is the difference of its encoder
    /// positions; then differences of the positions low-passed at --cutoff.
    #[arg(long, value_enum, default_value_t = Velocity::Auto)]
    velocity: Velocity,
    /// Low-pass cut-off [Hz] for velocities from positions (default: chosen from the positions' noise).
    #[arg(long, value_parser = positive)]
    cutoff: Option<f64>,
    /// The column map of logs that are tables: a TOML file naming the time column (and its unit) and each URDF
    /// joint's position, velocity and effort or current columns (docs/logs.md).
    #[arg(long, value_name = "MAP.toml")]
    columns: Option<PathBuf>,
    /// Joint torque (N m, or N for a prismatic joint) per unit of the logged effort, one per joint in the URDF's
    /// order (less welded joints): for drivers that log motor currents (A), e.g. Universal Robots'.
    #[arg(long, value_name = "G1,G2,...", value_delimiter = ',', value_parser = gain)]
    gains: Option<Vec<f64>>,
}

/// A drive gain: finite and not zero (a negative one flips a joint's sign convention).
fn gain(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v != 0.0 => Ok(v),
        _ => Err("expected a finite, non-zero number".into()),
    }
}

impl Signals {
    /// How the logs are read: the column map (read here, so a bad one is refused before anything runs), the
    /// gains, and the joints `fixed`.
    pub fn reading(&self, fixed: &[String]) -> Result<Reading> {
        let columns = self.columns.as_deref().map(ColumnMap::read).transpose()?;
        if let (Some(map), Some(path)) = (&columns, &self.columns) {
            map.check_gains(self.gains.is_some()).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        }
        Ok(Reading { columns, gains: self.gains.clone(), fixed: fixed.to_vec() })
    }

    pub fn conditioning(&self) -> Conditioning {
        Conditioning {
            velocity: match self.velocity {
                Velocity::Auto => None,
                Velocity::Logged => Some(VelocitySource::Logged),
                Velocity::Positions => Some(VelocitySource::Positions),
            },
            effort: match self.effort {
                Effort::Auto => None,
                Effort::Held => Some(EffortConvention::Held),
                Effort::Sampled => Some(EffortConvention::Sampled),
            },
            cutoff: self.cutoff,
        }
    }
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
    let out = args.output.path(&args.logs);
    let given = read_urdf(args.urdf.as_deref())?;
    let document = given.as_ref().map(|(text, source)| (text.as_str(), source.as_str()));
    let options = Options {
        spread: args.spread,
        conditioning: args.signals.conditioning(),
        reading: args.signals.reading(&args.fix)?,
        weld_idle: true,
        accept_unconverged: args.accept_unconverged,
        run_to_run: args.run_to_run,
    };
    args.output.check_mjcf(&args.logs, document, &out)?;
    let mut calibrated = calibrate_to_urdf(&args.logs, document, &options, &args.output.holdout, &out)?;
    args.output.write_mjcf(&mut calibrated)?;
    match args.output.json {
        true => println!("{}", serde_json::to_string_pretty(&calibrated.json()?)?),
        false => print!("{calibrated}"),
    }
    Ok(())
}

/// The URDF at `path` (its text and its name in messages), if given.
pub fn read_urdf(path: Option<&std::path::Path>) -> Result<Option<(String, String)>> {
    path.map(read_urdf_file).transpose()
}

/// The URDF at `path`: its text and its name in messages.
pub fn read_urdf_file(path: &std::path::Path) -> Result<(String, String)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    Ok((text, path.display().to_string()))
}
