//! `dynforge train`, `evaluate`, `estimate` and `pipeline`: the trainer's commands.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use dynforge_proto::LABELS;
use dynforge_robot::urdf;
use dynforge_trainer::checkpoint::Checkpoint;
use dynforge_trainer::data::cache::{CachedWindows, load_or_build};
use dynforge_trainer::data::features::JacobianFeatures;
use dynforge_recording::dataset::{ShardFollower, dataset_robot, shard_dir};
use dynforge_trainer::data::normalize::{Standardizer, split_windows};
use dynforge_trainer::data::window::WindowSpec;
use dynforge_trainer::evaluation::{Report, evaluate_checkpoint};
use dynforge_trainer::inference::Predictor;
use dynforge_trainer::model::{ModelConfig, Preset};
use dynforge_trainer::training::{Corpus, EpochMetrics, TrainConfig, TrainObserver, TrainSummary, resumable, train};
use indicatif::{ProgressBar, ProgressStyle};

/// Set by SIGINT/SIGTERM: training checkpoints and stops at the next step.
static STOP: AtomicBool = AtomicBool::new(false);

/// Whether Ctrl-C or SIGTERM asked the current command to stop.
pub(crate) fn interrupted() -> bool {
    STOP.load(Ordering::Relaxed)
}

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn catch_interrupts() {
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
}

#[derive(Clone, Copy, ValueEnum)]
pub enum PresetArg {
    /// The paper's best: 4 layers, 32 heads, 128 dims, one token per time step.
    Paper,
    /// 4 layers, 4 heads, 128 dims, 4 time steps per token: several times cheaper on CPU.
    Fast,
}

#[derive(Args, Clone)]
pub struct ModelArgs {
    /// Architecture preset; the options below override its parts [default: paper; pipeline: fast].
    #[arg(long, value_enum)]
    pub(crate) preset: Option<PresetArg>,
    #[arg(long)]
    pub(crate) layers: Option<usize>,
    #[arg(long)]
    pub(crate) heads: Option<usize>,
    /// Embedding size.
    #[arg(long)]
    pub(crate) dim: Option<usize>,
    /// Time steps per token.
    #[arg(long)]
    pub(crate) patch: Option<usize>,
    #[arg(long)]
    pub(crate) dropout: Option<f64>,
}

impl ModelArgs {
    pub(crate) fn config(&self, inputs: usize, seq_len: usize, default: Preset) -> ModelConfig {
        let preset = match self.preset {
            Some(PresetArg::Paper) => Preset::Paper,
            Some(PresetArg::Fast) => Preset::Fast,
            None => default,
        };
        let mut c = preset.config(inputs, seq_len);
        if let Some(d) = self.dim {
            c.d_model = d;
            c.d_ff = 4 * d;
        }
        c.layers = self.layers.unwrap_or(c.layers);
        c.heads = self.heads.unwrap_or(c.heads);
        c.patch = self.patch.unwrap_or(c.patch);
        c.dropout = self.dropout.unwrap_or(c.dropout);
        c
    }
}

#[derive(Args, Clone)]
pub struct WindowArgs {
    /// Sequence length L (time steps per window).
    #[arg(long = "len", default_value_t = 64)]
    pub(crate) len: usize,
    /// Stride between the time steps of a window, in 1 kHz samples (the paper's "sampling rate").
    #[arg(long, default_value_t = 64)]
    pub(crate) stride: usize,
    /// Secondary sampling rate: window offsets 0, SSR, 2 SSR, ... below the stride.
    #[arg(long, default_value_t = 16)]
    pub(crate) ssr: usize,
}

impl WindowArgs {
    fn spec(&self) -> Result<WindowSpec> {
        if self.len == 0 || self.stride == 0 || self.ssr == 0 {
            bail!("--len, --stride and --ssr must be positive");
        }
        Ok(WindowSpec { len: self.len, stride: self.stride, ssr: self.ssr })
    }
}

#[derive(Args, Clone)]
pub struct OptimArgs {
    /// Maximum epochs [default: 30; pipeline: 12].
    #[arg(long)]
    pub(crate) epochs: Option<usize>,
    #[arg(long, default_value_t = 64)]
    pub(crate) batch: usize,
    /// Peak learning rate (AdamW; linear warmup over the first 5 % of steps, then cosine decay).
    #[arg(long, default_value_t = 5e-4)]
    pub(crate) lr: f64,
    /// Epochs without a better validation loss before stopping early.
    #[arg(long, default_value_t = 6)]
    pub(crate) patience: usize,
    /// Seed of the robot-level split, the initial weights, the batch order and dropout.
    #[arg(long, default_value_t = 0)]
    pub(crate) seed: u64,
    /// Share of the robots held out for validation.
    #[arg(long, default_value_t = 0.2)]
    pub(crate) validation: f64,
    /// Parts each batch is split into, each run on a thread of its own (part of the run's definition, not of the
    /// machine: the same value gives the same model anywhere).
    #[arg(long, default_value_t = TrainConfig::default().micro_batches)]
    pub(crate) micro_batches: usize,
}

/// What defines a training run besides its data and output directory: architecture, windows and optimisation.
#[derive(Args, Clone)]
pub struct Recipe {
    #[command(flatten)]
    pub(crate) model: ModelArgs,
    #[command(flatten)]
    pub(crate) window: WindowArgs,
    #[command(flatten)]
    pub(crate) optim: OptimArgs,
}

#[derive(Args)]
pub struct TrainArgs {
    /// A `dynforge generate` output directory.
    data: PathBuf,
    /// Checkpoint directory to write (model, statistics, metrics, resume state).
    #[arg(long)]
    out: PathBuf,
    /// Continue the interrupted or finished run in --out (same data and settings) instead of starting anew.
    #[arg(long)]
    resume: bool,
    /// Train while the dataset is being generated: wait for shards, and add the shards that appear before each
    /// epoch (the preprocessing statistics stay those of the first shards).
    #[arg(long)]
    follow: bool,
    #[command(flatten)]
    recipe: Recipe,
}

#[derive(Args)]
pub struct EvaluateArgs {
    /// Checkpoint directory (from `dynforge train`).
    checkpoint: PathBuf,
    /// Dataset to evaluate on (default: the one the checkpoint was trained on); its validation robots are used.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Validation recordings to run the torque check on (0: skip it).
    #[arg(long, default_value_t = DEFAULT_CHECKS.torque_recordings)]
    torque_recordings: usize,
    /// Validation robots to identify by physics (least squares on the regressor, and the hybrid that refines the
    /// network's estimate with it) from half of their recordings, scored on the other half (0: skip it).
    #[arg(long, default_value_t = DEFAULT_CHECKS.identify_robots)]
    identify_robots: usize,
}

#[derive(Args)]
pub struct EstimateArgs {
    /// Checkpoint directory (from `dynforge train`).
    #[arg(long)]
    checkpoint: PathBuf,
    /// A shard or a ROS 2 bag (MCAP) holding /joint_states.
    log: PathBuf,
    /// The robot's URDF, when the log has no /robot_description (joints are matched by name).
    #[arg(long)]
    urdf: Option<PathBuf>,
    /// Where to write the URDF with the estimated parameters (default: LOG with extension .estimated.urdf).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the estimate as JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Keep the network's estimate as it is. By default it is refined by physics: the labels that best explain the
    /// log's torques (least squares on the regressor), with the network's estimate as prior for what the torques
    /// cannot tell apart.
    #[arg(long)]
    no_refine: bool,
}

#[derive(Args)]
pub struct PipelineArgs {
    /// Directory for the dataset (DIR/data) and the checkpoint (DIR/model).
    #[arg(long, default_value = "dynforge-pipeline")]
    out: PathBuf,
    /// Robots to generate (16 trajectories each).
    #[arg(long, default_value_t = 48)]
    robots: usize,
    /// Worker processes of the generation.
    #[arg(long, default_value_t = 2)]
    workers: usize,
    /// Dataset seed.
    #[arg(long, default_value_t = 1)]
    dataset_seed: u64,
    #[command(flatten)]
    recipe: Recipe,
}

pub(crate) fn bar(len: u64, template: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(len);
    b.set_style(ProgressStyle::with_template(template).expect("valid template"));
    b
}

/// The windows of a dataset, from its cache or built with a progress bar.
fn load_windows(data: &Path, spec: &WindowSpec) -> Result<(CachedWindows, JacobianFeatures, Vec<String>)> {
    let robot = dataset_robot(data).with_context(|| format!("reading the dataset {}", data.display()))?;
    let features = JacobianFeatures::new(&robot);
    let b = bar(0, "preprocessing {bar:40} {pos}/{len} shards, ETA {eta}");
    let started = Instant::now();
    let (w, skipped) = load_or_build(data, spec, &features, |k, n| {
        b.set_length(n as u64);
        b.set_position(k as u64);
    })?;
    b.finish_and_clear();
    for s in &skipped {
        eprintln!("warning: skipped {s}");
    }
    eprintln!(
        "{} windows of {} x {} values ({}; {:.1} s){}",
        w.count(),
        spec.len,
        w.width,
        if w.hit { "from the cache" } else { "built and cached" },
        started.elapsed().as_secs_f64(),
        if skipped.is_empty() { String::new() } else { format!(", {} shards skipped", skipped.len()) }
    );
    let joints = robot.joints().iter().map(|j| j.name.clone()).collect();
    Ok((w, features, joints))
}

struct Bars {
    bar: ProgressBar,
    started: Instant,
    batch: usize,
    steps: usize,
    plain: bool,
}

impl TrainObserver for Bars {
    fn step(&mut self, epoch: usize, batch: usize, batches: usize, loss: f64) {
        if batch == 1 || self.bar.length() != Some(batches as u64) {
            self.bar.set_length(batches as u64);
            self.started = Instant::now();
            self.steps = 0;
        }
        self.steps += 1;
        self.bar.set_position(batch as u64);
        let rate = (self.steps * self.batch) as f64 / self.started.elapsed().as_secs_f64().max(1e-9);
        self.bar.set_message(format!("epoch {epoch}: loss {loss:.4}, {rate:.0} windows/s"));
    }

    fn epoch(&mut self, m: &EpochMetrics, best: bool) {
        let line = format!(
            "epoch {:>3}: train loss {:.4}, validation loss {:.4}, R2 {:.4}, RMSE {:.4}, {:.0} windows/s, {:.1} s ({:.1} CPU s){}",
            m.epoch,
            m.train_loss,
            m.validation_loss,
            m.validation_r2,
            m.validation_rmse,
            m.windows_per_second,
            m.seconds,
            m.cpu_seconds,
            if best { " (best)" } else { "" }
        );
        if self.plain {
            eprintln!("{line}");
        } else {
            self.bar.println(line);
        }
    }
}

pub(crate) struct TrainJob<'a> {
    /// Preset and epochs when not given.
    pub(crate) defaults: (Preset, usize),
    pub(crate) data: &'a Path,
    pub(crate) out: &'a Path,
    pub(crate) resume: bool,
    pub(crate) follow: bool,
    pub(crate) recipe: &'a Recipe,
}

/// Waits until the dataset has a readable shard and returns its robot (for --follow, started with the generation).
fn wait_for_robot(data: &Path) -> Result<dynforge_robot::Model> {
    let mut told = false;
    loop {
        match dataset_robot(data) {
            Ok(m) => return Ok(m),
            Err(e) if STOP.load(Ordering::Relaxed) => return Err(e).context("interrupted while waiting for shards"),
            Err(_) => {
                if !told {
                    eprintln!("waiting for the first shard in {} ...", data.display());
                    told = true;
                }
                std::thread::sleep(std::time::Duration::from_secs(2));
            }
        }
    }
}

pub(crate) fn run_training(job: &TrainJob) -> Result<(TrainSummary, CachedWindows)> {
    let o = &job.recipe.optim;
    if !(o.validation > 0.0 && o.validation < 1.0) {
        bail!("--validation {} must be between 0 and 1", o.validation);
    }
    if o.micro_batches == 0 || o.micro_batches > o.batch {
        bail!("--micro-batches {} must be between 1 and --batch {}", o.micro_batches, o.batch);
    }
    let resume = job.resume && resumable(job.out);
    if job.resume && !resume {
        eprintln!("note: {} holds no run to resume; starting a new one", job.out.display());
    }
    if !resume && Checkpoint::read(job.out).is_ok() {
        bail!(
            "{} already holds a checkpoint: pass --resume to continue it, or choose another --out",
            job.out.display()
        );
    }
    let previous = if resume { Some(Checkpoint::read(job.out)?) } else { None };
    let spec = match &previous {
        Some(c) => c.window_spec(),
        None => job.recipe.window.spec()?,
    };
    let (split_seed, fraction) =
        previous.as_ref().map_or((o.seed, o.validation), |c| (c.split_seed, c.validation_fraction));
    catch_interrupts();
    let (windows, features, joints) = if job.follow {
        let robot = wait_for_robot(job.data)?;
        let joints = robot.joints().iter().map(|j| j.name.clone()).collect();
        let empty =
            CachedWindows { spec, width: 0, data: Vec::new(), labels: Vec::new(), robots: Vec::new(), hit: false };
        (empty, JacobianFeatures::new(&robot), joints)
    } else {
        load_windows(job.data, &spec)?
    };
    // After the first shard exists, so that `shards/` of a generate directory is what is followed.
    let mut follower = ShardFollower::new(&shard_dir(job.data));
    let mut corpus =
        Corpus { windows, train: Vec::new(), validation: Vec::new(), standardizer: Standardizer::fit_empty() };
    if job.follow {
        // Both splits need windows before the statistics can be fitted.
        loop {
            let new = follower.poll().with_context(|| format!("listing {}", job.data.display()))?;
            for s in corpus.add_shards(&new, &features, split_seed, fraction) {
                eprintln!("warning: skipped {s}");
            }
            if !corpus.train.is_empty() && !corpus.validation.is_empty() {
                break;
            }
            if STOP.load(Ordering::Relaxed) {
                bail!("interrupted while waiting for shards of both splits");
            }
            std::thread::sleep(std::time::Duration::from_secs(2));
        }
    } else {
        (corpus.train, corpus.validation) = split_windows(&corpus.windows, split_seed, fraction);
    }
    let checkpoint = match previous {
        Some(c) => c,
        None => {
            let standardizer = Standardizer::fit(&corpus.windows, &corpus.train);
            let model = job.recipe.model.config(standardizer.columns.len(), spec.len, job.defaults.0);
            model.check()?;
            let mut c = Checkpoint::new(model, &spec, joints, &features, &standardizer);
            c.dataset = std::fs::canonicalize(job.data).unwrap_or(job.data.to_path_buf()).display().to_string();
            c.split_seed = split_seed;
            c.validation_fraction = fraction;
            c
        }
    };
    corpus.standardizer = checkpoint.standardizer();
    let m = &checkpoint.model;
    eprintln!(
        "model: {} layers, {} heads, {} dims, patch {} ({} tokens), {} parameters; {} training / {} validation windows",
        m.layers,
        m.heads,
        m.d_model,
        m.patch,
        m.tokens(),
        m.parameters(),
        corpus.train.len(),
        corpus.validation.len()
    );
    let cfg = TrainConfig {
        epochs: o.epochs.unwrap_or(job.defaults.1),
        batch: o.batch,
        lr: o.lr,
        patience: o.patience,
        seed: o.seed,
        micro_batches: o.micro_batches,
        ..TrainConfig::default()
    };
    let mut bars = Bars {
        bar: bar(0, "{bar:40} {pos}/{len} batches | {msg}"),
        started: Instant::now(),
        batch: o.batch,
        steps: 0,
        plain: !std::io::stderr().is_terminal(),
    };
    let mut grow = |c: &mut Corpus| match follower.poll() {
        Ok(new) if !new.is_empty() => {
            let before = c.windows.count();
            let skipped = c.add_shards(&new, &features, split_seed, fraction);
            for s in &skipped {
                eprintln!("warning: skipped {s}");
            }
            eprintln!(
                "follow: {} new shards, {} new windows ({} skipped)",
                new.len(),
                c.windows.count() - before,
                skipped.len()
            );
        }
        Ok(_) => {}
        Err(e) => eprintln!("warning: listing {}: {e}", job.data.display()),
    };
    let grow: Option<&mut dyn FnMut(&mut Corpus)> = if job.follow { Some(&mut grow) } else { None };
    let summary = train(&mut corpus, grow, checkpoint, &cfg, job.out, resume, &mut bars, &STOP)?;
    bars.bar.finish_and_clear();
    if summary.interrupted {
        bail!("interrupted: the run is saved in {}; continue it with --resume", job.out.display());
    }
    eprintln!(
        "{} after {} epochs; best epoch {} -> {}",
        if summary.stopped_early { "stopped early" } else { "finished" },
        summary.history.len(),
        summary.best_epoch,
        job.out.display()
    );
    Ok((summary, corpus.windows))
}

pub fn train_command(args: TrainArgs) -> Result<()> {
    run_training(&TrainJob {
        defaults: (Preset::Paper, 30),
        data: &args.data,
        out: &args.out,
        resume: args.resume,
        follow: args.follow,
        recipe: &args.recipe,
    })?;
    Ok(())
}

/// How many validation recordings and robots the torque and identification checks take.
struct Checks {
    torque_recordings: usize,
    identify_robots: usize,
}

const DEFAULT_CHECKS: Checks = Checks { torque_recordings: 64, identify_robots: 32 };

fn run_evaluation(checkpoint: &Path, data: &Path, windows: Option<CachedWindows>, checks: &Checks) -> Result<Report> {
    let windows = match windows {
        Some(w) => w,
        None => load_windows(data, &Checkpoint::read(checkpoint)?.window_spec())?.0,
    };
    let b = bar(0, "{msg} {bar:40} {pos}/{len}");
    let report = evaluate_checkpoint(
        checkpoint,
        &windows,
        data,
        checks.torque_recordings,
        checks.identify_robots,
        |what, k, n| {
            b.set_message(what.to_string());
            b.set_length(n as u64);
            b.set_position(k as u64);
        },
    )?;
    b.finish_and_clear();
    let md = report.markdown();
    // report.json also feeds `estimate` (the refinement's prior spread): never leave it half written.
    dynforge_proto::run_dir::write_atomic(&checkpoint.join("report.md"), md.as_bytes())
        .with_context(|| format!("writing {}/report.md", checkpoint.display()))?;
    let json = serde_json::to_string_pretty(&report)?;
    dynforge_proto::run_dir::write_atomic(&checkpoint.join("report.json"), json.as_bytes())
        .with_context(|| format!("writing {}/report.json", checkpoint.display()))?;
    println!("{md}");
    eprintln!("written: {0}/report.md, {0}/report.json", checkpoint.display());
    Ok(report)
}

pub fn evaluate_command(args: EvaluateArgs) -> Result<()> {
    let data = match args.data {
        Some(d) => d,
        None => PathBuf::from(Checkpoint::read(&args.checkpoint)?.dataset),
    };
    let checks = Checks { torque_recordings: args.torque_recordings, identify_robots: args.identify_robots };
    run_evaluation(&args.checkpoint, &data, None, &checks)?;
    Ok(())
}

pub fn estimate_command(args: EstimateArgs) -> Result<()> {
    let predictor = Predictor::load(&args.checkpoint)?;
    let base = match &args.urdf {
        Some(p) => Some(urdf::load(p)?),
        None => None,
    };
    let (prepared, e) = predictor.estimate(&args.checkpoint, &args.log, base.as_ref())?;
    // A log the torques of which cannot refine the estimate (no joint moves) keeps the network's, with a warning.
    let refinement = match args.no_refine {
        true => None,
        false => predictor
            .refine(&args.checkpoint, &prepared, &e)
            .inspect_err(|err| eprintln!("warning: the estimate is the network's alone, not refined by physics: {err}"))
            .ok(),
    };
    let values = refinement.as_ref().map_or(e.labels, |r| r.labels);
    let (model, notes) = dynforge_robot::parameters::with_labels(&prepared.model, &values)
        .with_context(|| format!("applying the estimate to the robot of {}", args.log.display()))?;
    let out = args.out.unwrap_or_else(|| args.log.with_extension("estimated.urdf"));
    dynforge_proto::run_dir::write_atomic(&out, urdf::to_string(&model, &urdf::BaseLink::default()).as_bytes())
        .with_context(|| format!("writing {}", out.display()))?;
    if args.json {
        let map: serde_json::Map<String, serde_json::Value> = LABELS
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let v = serde_json::json!({
                    "value": values[k], "network": e.labels[k], "spread": e.spread[k], "unit": l.kind.unit()
                });
                (l.name.to_string(), v)
            })
            .collect();
        let refined = refinement.as_ref().map(|r| {
            serde_json::json!({
                "identifiable": r.identifiable,
                "prior_from_validation": r.prior_from_validation,
                "torque_nrmse_network": r.nrmse_network,
                "torque_nrmse_refined": r.nrmse_refined,
            })
        });
        let summary = serde_json::json!({
            "windows": e.windows, "parameters": map, "refinement": refined, "projections": notes, "urdf": out
        });
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!("{}: {} windows", args.log.display(), e.windows);
        println!("{:<12} {:>12} {:>12} {:>12}  unit", "parameter", "estimate", "network", "spread");
        for (k, l) in LABELS.iter().enumerate() {
            let u = l.kind.unit();
            println!("{:<12} {:>12.6} {:>12.6} {:>12.6}  {u}", l.name, values[k], e.labels[k], e.spread[k]);
        }
        match &refinement {
            Some(r) => println!(
                "refined by physics ({} identifiable parameter combinations; prior spread from {}): torque NRMSE on \
                 this log {:.4} (network alone {:.4})",
                r.identifiable,
                if r.prior_from_validation { "the checkpoint's report.json" } else { "the training labels" },
                r.nrmse_refined,
                r.nrmse_network
            ),
            None if args.no_refine => println!("network estimate only (--no-refine)"),
            None => println!("network estimate only (not refined: see the warning above)"),
        }
        for n in &notes {
            println!("projected: {n}");
        }
        println!("URDF with the estimated parameters: {}", out.display());
    }
    Ok(())
}

pub fn pipeline_command(args: PipelineArgs) -> Result<()> {
    let data = args.out.join("data");
    let model_dir = args.out.join("model");
    eprintln!("== 1/3 generate {} robots x 16 trajectories into {}", args.robots, data.display());
    let exe = std::env::current_exe().context("locating the dynforge executable")?;
    let status = std::process::Command::new(exe)
        .args(["generate", "--out"])
        .arg(&data)
        .args(["--robots", &args.robots.to_string(), "--workers", &args.workers.to_string()])
        .args(["--seed", &args.dataset_seed.to_string()])
        .status()
        .context("starting the generation")?;
    if !status.success() {
        bail!("generation failed ({status}); rerun the same command to resume it");
    }
    eprintln!("== 2/3 train into {}", model_dir.display());
    let resume = resumable(&model_dir);
    let (_, windows) = run_training(&TrainJob {
        defaults: (Preset::Fast, 12),
        data: &data,
        out: &model_dir,
        resume,
        follow: false,
        recipe: &args.recipe,
    })?;
    eprintln!("== 3/3 evaluate on the validation robots");
    run_evaluation(&model_dir, &data, Some(windows), &DEFAULT_CHECKS)?;
    Ok(())
}
