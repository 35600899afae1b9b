//! The training loop: AdamW with linear warmup then cosine decay, gradient-norm clipping, early stopping on the
//! validation loss, a checkpoint every epoch and on request (Ctrl-C), and exact resume.
//!
//! Exactness: the batch order of epoch `e` comes from the stream `(seed, e)` and the backend's random state
//! (dropout) is reseeded from `(seed, step)` before every step, so a run resumed from its last checkpoint (weights
//! with their parameter ids, optimizer moments, step counter) takes the same steps as one that never stopped.

pub mod recipe;
pub mod schedule;
pub mod session;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use burn::module::Module;
use burn::optim::{
    AdamWConfig, GradientsAccumulator, GradientsParams, ModuleOptimizer, grad_clipping::GradientClippingConfig,
};
use burn::store::{BurnpackStore, ModuleSnapshot};
use burn::tensor::{Bytes, Device, Tensor, TensorData};
use dynforge_proto::NUM_LABELS;
use dynforge_robot::rng::Rng;
use serde::{Deserialize, Serialize};

use crate::checkpoint::{Checkpoint, CheckpointError, write_atomic};
use crate::device::Accelerator;
use crate::model::{Network, NetworkConfig};
use dynforge_dataset::examples::Examples;
use dynforge_dataset::metrics::EpochMetrics;
use dynforge_dataset::metrics::write_history;
use dynforge_dataset::metrics::{Scores, score};
use schedule::Schedule;

/// Optimisation settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    pub epochs: usize,
    pub batch: usize,
    /// Peak learning rate.
    pub lr: f64,
    /// Share of all steps spent warming up linearly from 0 to `lr`.
    pub warmup: f64,
    pub weight_decay: f64,
    /// Maximum L2 norm of the gradient.
    pub clip: f64,
    /// Epochs without a better validation loss before stopping.
    pub patience: usize,
    pub seed: u64,
    /// Parts each batch is split into, run on their own threads and their gradients summed: burn's CPU backend
    /// uses one core per pass, so this is how a step uses several. Part of the configuration, not taken from the
    /// machine, so a seed gives the same model everywhere.
    #[serde(default = "default_micro_batches")]
    pub micro_batches: usize,
    /// Where the steps run. Not part of the run's identity: a run may resume on another device.
    #[serde(skip)]
    pub device: Accelerator,
}

/// 4 parts of a 64-window batch measured fastest on 2 cores (bench/training.sh; figures in `docs/measurements.md`): smaller
/// parts keep the attention scores in cache.
fn default_micro_batches() -> usize {
    4
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            epochs: 30,
            batch: 64,
            lr: 5e-4,
            warmup: 0.05,
            weight_decay: 1e-2,
            clip: 1.0,
            patience: 6,
            seed: 0,
            micro_batches: default_micro_batches(),
            device: Accelerator::Cpu,
        }
    }
}

/// Progress of a run, saved with every checkpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct TrainState {
    config: TrainConfig,
    /// Next epoch to run, and the global step count before it.
    epoch: usize,
    step: usize,
    /// Step within `epoch` (non-zero after an interruption mid-epoch).
    batch_in_epoch: usize,
    train_loss_sum: f64,
    best_loss: f64,
    best_epoch: usize,
    history: Vec<EpochMetrics>,
    stopped_early: bool,
    /// What `epoch` cost before an interruption, so that the resumed epoch reports its whole cost. Absent from
    /// states saved before it was kept (they resume with nothing spent).
    #[serde(default)]
    spent: Spent,
}

/// Wall-clock and CPU seconds, and windows trained, of the part of an epoch run before an interruption.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
struct Spent {
    seconds: f64,
    cpu_seconds: f64,
    windows: usize,
}

impl Spent {
    /// This and the stretch that began at `started` (wall clock, process CPU seconds) and trained `windows`.
    fn plus(self, (started, cpu_started): (Instant, f64), windows: usize) -> Spent {
        Spent {
            seconds: self.seconds + started.elapsed().as_secs_f64(),
            cpu_seconds: self.cpu_seconds + (process_cpu_seconds() - cpu_started),
            windows: self.windows + windows,
        }
    }
}

impl TrainState {
    /// Whether more than `patience` epochs have passed without a better validation loss.
    fn stops_early(&self, patience: usize) -> bool {
        self.epoch.saturating_sub(self.best_epoch) > patience
    }
}

/// What a finished (or interrupted) run reports.
#[derive(Debug, Clone)]
pub struct TrainSummary {
    pub history: Vec<EpochMetrics>,
    pub best_epoch: usize,
    pub interrupted: bool,
    pub stopped_early: bool,
}

/// Observes training; the CLI draws progress bars from it.
pub trait TrainObserver {
    fn step(&mut self, _epoch: usize, _batch: usize, _batches: usize, _loss: f64) {}
    fn epoch(&mut self, _m: &EpochMetrics, _best: bool) {}
    /// Something the user should know (a resumed run and what changed in it, skipped shards, waiting).
    fn message(&mut self, _text: &str) {}
}

impl TrainObserver for () {}

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Model(#[from] crate::model::ConfigError),
    #[error("{0}")]
    Setup(String),
}

/// Standardised predictions of `model` for standardised inputs `x` (`count` examples of `shape`), in batches.
pub fn predict(model: &Network, x: &[f32], count: usize, shape: [usize; 2], device: &Device) -> Vec<[f32; NUM_LABELS]> {
    let per = shape[0] * shape[1];
    predict_with(model, count, shape, device, |r| x[r.start * per..r.end * per].to_vec())
}

/// [`predict`] of `count` examples whose inputs `inputs(range)` makes a batch at a time, so that they are never all
/// in memory at once.
pub fn predict_with(
    model: &Network,
    count: usize,
    shape: [usize; 2],
    device: &Device,
    inputs: impl Fn(std::ops::Range<usize>) -> Vec<f32> + Sync,
) -> Vec<[f32; NUM_LABELS]> {
    const CHUNK: usize = 256;
    let [len, width] = shape;
    let chunk = |start: usize| {
        let n = (count - start).min(CHUNK);
        let t = Tensor::<3>::from_data(TensorData::new(inputs(start..start + n), [n, len, width]), device);
        let y: Vec<f32> = model.forward(t).into_data().try_to_vec::<f32>().expect("f32 predictions");
        y.chunks_exact(NUM_LABELS).map(|c| <[f32; NUM_LABELS]>::try_from(c).expect("38")).collect::<Vec<_>>()
    };
    // Chunk boundaries do not depend on the core count, so neither do the predictions.
    let starts: Vec<usize> = (0..count).step_by(CHUNK).collect();
    dynforge_proto::parallel::map_in_order(&starts, |&start| chunk(start)).into_iter().flatten().collect()
}

/// Scores, SI predictions and mean squared error (standardised) of `model` on the validation examples.
pub fn evaluate(model: &Network, examples: &dyn Examples, device: &Device) -> (Scores, Vec<[f64; NUM_LABELS]>, f64) {
    let truth = examples.validation_labels();
    let s = examples.standardizer();
    let pred = predict_with(model, truth.len(), examples.shape(), device, |r| examples.validation_inputs(r));
    let predicted: Vec<[f64; NUM_LABELS]> = pred.iter().map(|p| s.labels(p)).collect();
    let scores = score(&predicted, &truth, &s.label_std);
    let mse = scores.rmse * scores.rmse;
    (scores, predicted, mse)
}

/// AdamW with the configured weight decay and gradient-norm clipping.
fn optimizer(cfg: &TrainConfig) -> ModuleOptimizer {
    AdamWConfig::new()
        .with_weight_decay(cfg.weight_decay as f32)
        .with_grad_clipping(Some(GradientClippingConfig::Norm(cfg.clip as f32)))
        .init()
}

/// The loss of one step and its gradients, over a batch of `n` windows split into `parts` contiguous
/// micro-batches that run on their own threads. `batch(range)` builds a micro-batch's inputs and targets; each
/// part's dropout masks come from the stream (`seed`, `step`, part), and its loss is weighted by its share of the
/// batch, so the sum is the mean-squared error of the whole batch. Gradients are summed in part order: the result
/// does not depend on thread timing.
fn step_gradients<F>(
    model: &Network,
    n: usize,
    parts: usize,
    (seed, step): (u64, u64),
    device: &Device,
    batch: F,
) -> (f64, GradientsParams)
where
    F: Fn(std::ops::Range<usize>) -> (Tensor<3>, Tensor<2>) + Sync,
{
    let parts = parts.clamp(1, n.max(1));
    let bounds: Vec<usize> = (0..=parts).map(|p| p * n / parts).collect();
    let run = |p: usize, replica: Network| {
        let (x, y) = batch(bounds[p]..bounds[p + 1]);
        let mut rng = Rng::stream(seed, &[0x6472_6f70, step, p as u64]);
        let share = (bounds[p + 1] - bounds[p]) as f64 / n as f64;
        let loss = (replica.forward_train(x, &mut rng) - y).square().mean().mul_scalar(share as f32);
        // Reading the loss back also forces the pass to complete.
        let value = loss.clone().into_scalar::<f32>() as f64;
        (value, GradientsParams::from_grads(loss.backward(), &replica))
    };
    let results: Vec<(f64, GradientsParams)> = std::thread::scope(|s| {
        // `fork` gives each replica fresh autodiff leaves (same parameter ids), so every part has a graph of its own.
        let handles: Vec<_> =
            (1..parts).map(|p| (p, model.clone().fork(device))).map(|(p, m)| s.spawn(move || run(p, m))).collect();
        let mut out = vec![run(0, model.clone().fork(device))];
        out.extend(handles.into_iter().map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))));
        out
    });
    let mut loss = 0.0;
    let mut sum = GradientsAccumulator::new();
    for (value, grads) in results {
        loss += value;
        sum.accumulate(model, grads);
    }
    (loss, sum.grads())
}

/// The permutation of the training windows in `epoch`.
fn epoch_order(seed: u64, epoch: usize, n: usize) -> Vec<usize> {
    let mut rng = Rng::stream(seed, &[0x6f_7264_6572, epoch as u64]);
    let mut order: Vec<usize> = (0..n).collect();
    for i in (1..n).rev() {
        order.swap(i, rng.below(i + 1));
    }
    order
}

fn train_dir(dir: &Path) -> PathBuf {
    dir.join("train")
}

fn io(path: &Path, e: impl ToString) -> TrainError {
    TrainError::Checkpoint(CheckpointError::File { file: path.display().to_string(), problem: e.to_string() })
}

fn save_state(dir: &Path, model: &Network, optim: &ModuleOptimizer, state: &TrainState) -> Result<(), TrainError> {
    let t = train_dir(dir);
    let mut store = BurnpackStore::from_bytes(None);
    model.save_into(&mut store).map_err(|e| io(&t.join("last.bpk"), e))?;
    let bytes = store.get_bytes().map_err(|e| io(&t.join("last.bpk"), e))?;
    write_atomic(&t.join("last.bpk"), &bytes)?;
    let opt = optim.into_bytes().map_err(|e| io(&t.join("optimizer.bin"), e))?;
    write_atomic(&t.join("optimizer.bin"), &opt)?;
    // The state goes last: it names the step the two files above belong to.
    let json = serde_json::to_vec_pretty(state).map_err(|e| io(&t.join("state.json"), e))?;
    write_atomic(&t.join("state.json"), &json)?;
    Ok(())
}

fn load_state(
    dir: &Path,
    model: &mut Network,
    optim: ModuleOptimizer,
) -> Result<(ModuleOptimizer, TrainState), TrainError> {
    let t = train_dir(dir);
    let read = |name: &str| std::fs::read(t.join(name)).map_err(|e| io(&t.join(name), e));
    let state: TrainState = serde_json::from_slice(&read("state.json")?).map_err(|e| io(&t.join("state.json"), e))?;
    let mut store = BurnpackStore::from_bytes(Some(Bytes::from_bytes_vec(read("last.bpk")?)));
    model.load_from(&mut store).map_err(|e| io(&t.join("last.bpk"), e))?;
    let optim =
        optim.from_bytes(Bytes::from_bytes_vec(read("optimizer.bin")?)).map_err(|e| io(&t.join("optimizer.bin"), e))?;
    Ok((optim, state))
}

/// This machine's physical memory [bytes], when the OS says.
fn physical_memory() -> Option<u128> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kb = info.lines().find_map(|l| l.strip_prefix("MemTotal:"))?.trim().strip_suffix("kB")?.trim().parse::<u128>();
    Some(kb.ok()? * 1024)
}

/// An error when holding `bytes` at once (for `what`) takes more memory than this machine has: refused with the
/// flag to change, before an allocation that would abort the process.
pub fn check_memory(bytes: u128, what: impl FnOnce() -> String) -> Result<(), TrainError> {
    let gb = |b: u128| b as f64 / 1e9;
    match physical_memory() {
        Some(have) if bytes > have => Err(TrainError::Setup(format!(
            "{} would need {:.1} GB of memory; this machine has {:.1} GB",
            what(),
            gb(bytes),
            gb(have)
        ))),
        _ => Ok(()),
    }
}

/// CPU time this process has used so far, all threads; 0 where the OS does not say.
fn process_cpu_seconds() -> f64 {
    // SAFETY: getrusage only writes the struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return 0.0;
    }
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    secs(usage.ru_utime) + secs(usage.ru_stime)
}

/// The settings of `now` that differ from `was` (those a resumed run may change), as `; changed: lr 0.001 -> 0.0005`.
fn changes(was: &TrainConfig, now: &TrainConfig) -> String {
    let pairs = [
        ("epochs", was.epochs as f64, now.epochs as f64),
        ("lr", was.lr, now.lr),
        ("warmup", was.warmup, now.warmup),
        ("weight decay", was.weight_decay, now.weight_decay),
        ("clip", was.clip, now.clip),
        ("patience", was.patience as f64, now.patience as f64),
    ];
    let changed: Vec<String> =
        pairs.iter().filter(|(_, a, b)| a != b).map(|(name, a, b)| format!("{name} {a} -> {b}")).collect();
    match changed.is_empty() {
        true => String::new(),
        false => format!("; changed: {} (the schedule follows the new values from here)", changed.join(", ")),
    }
}

/// Whether `dir` holds a run that `train(.., resume = true)` can continue.
pub fn resumable(dir: &Path) -> bool {
    train_dir(dir).join("state.json").is_file()
}

/// Where and how a run trains (besides its examples and model).
pub struct Run<'a> {
    /// The checkpoint directory: description, best weights, metrics and the resume state.
    pub dir: &'a Path,
    pub config: &'a TrainConfig,
    /// Continue the state saved in `dir` instead of starting afresh.
    pub resume: bool,
    /// Set (e.g. by a signal handler) to checkpoint and stop at the next step.
    pub stop: &'a AtomicBool,
}

/// Trains `checkpoint.model` on `examples` as `run` says, from scratch or resuming its saved state. Stops after the
/// last epoch, on early stopping, or when `run.stop` becomes true (checkpointing first). `grow`, if given, runs
/// before every epoch and may add examples (training while generating); the learning-rate schedule then follows
/// the current size. Exact resume needs examples that did not grow.
pub fn train<E: Examples>(
    examples: &mut E,
    mut grow: Option<&mut dyn FnMut(&mut E)>,
    checkpoint: Checkpoint,
    run: &Run,
    observer: &mut dyn TrainObserver,
) -> Result<TrainSummary, TrainError> {
    let cfg = run.config;
    if examples.planned_train_len() == 0 || examples.validation_len() == 0 {
        return Err(TrainError::Setup(format!(
            "{} training and {} validation examples: both splits need windows (more robots, or another validation fraction)",
            examples.planned_train_len(),
            examples.validation_len()
        )));
    }
    if cfg.batch == 0 || cfg.epochs == 0 {
        return Err(TrainError::Setup("batch size and epochs must be positive".into()));
    }
    // Not a divergence to report later: no step with this rate means anything.
    if !(cfg.lr > 0.0 && cfg.lr.is_finite()) {
        return Err(TrainError::Setup(format!("learning rate {} is not a positive finite number", cfg.lr)));
    }
    let parameters = checkpoint.model.parameters();
    // Weights, gradients and AdamW's two moments, and the replica each micro-batch runs on, all f32.
    let bytes = parameters as u128 * 4 * (4 + cfg.micro_batches as u128);
    check_memory(bytes, || {
        format!(
            "the model's {parameters} parameters (weights, gradients, optimizer moments, a copy per micro-batch; \
             fewer --layers or a smaller --dim)"
        )
    })?;
    let device = cfg.device.device().map_err(|e| TrainError::Setup(e.to_string()))?.autodiff();
    device.seed(cfg.seed);
    let mut model = checkpoint.model.init(&device)?;
    let (mut optim, state, checkpoint) = start(run, checkpoint, &mut model, observer)?;
    let mut l = Loop { run, device, state, checkpoint };
    let mut interrupted = false;
    while l.state.epoch < cfg.epochs && !l.state.stopped_early {
        // An epoch's cost includes preparing its examples (the physics estimator draws and featurises its generated
        // robots here), not only the gradient steps.
        let started = (Instant::now(), process_cpu_seconds());
        if let Some(g) = grow.as_mut() {
            g(examples);
        }
        examples.begin_epoch(l.state.epoch);
        let (trained, finished);
        (model, trained, finished) = l.steps(examples, model, &mut optim, observer)?;
        let spent = std::mem::take(&mut l.state.spent).plus(started, trained);
        if !finished {
            interrupted = true;
            l.state.spent = spent;
            save_state(run.dir, &model, &optim, &l.state)?;
            break;
        }
        l.end_epoch(examples, &model, spent, observer)?;
        save_state(run.dir, &model, &optim, &l.state)?;
    }
    Ok(TrainSummary {
        history: l.state.history,
        best_epoch: l.state.best_epoch,
        interrupted,
        stopped_early: l.state.stopped_early,
    })
}

/// The optimizer, progress and checkpoint a run starts from: fresh (its description written first, so a run
/// interrupted before its first epoch still resumes with its statistics), or the state saved in `run.dir` (loaded
/// into `model`), refused if the settings that decide the batches changed.
fn start(
    run: &Run,
    checkpoint: Checkpoint,
    model: &mut Network,
    observer: &mut dyn TrainObserver,
) -> Result<(ModuleOptimizer, TrainState, Checkpoint), TrainError> {
    let cfg = run.config;
    if !run.resume {
        std::fs::create_dir_all(run.dir).map_err(|e| io(run.dir, e))?;
        checkpoint.describe(run.dir)?;
        let state = TrainState {
            config: cfg.clone(),
            epoch: 0,
            step: 0,
            batch_in_epoch: 0,
            train_loss_sum: 0.0,
            // Finite (JSON has no infinity): any real loss is below it.
            best_loss: f64::MAX,
            best_epoch: 0,
            history: Vec::new(),
            stopped_early: false,
            spent: Spent::default(),
        };
        return Ok((optimizer(cfg), state, checkpoint));
    }
    let (optim, s) = load_state(run.dir, model, optimizer(cfg))?;
    let (was, now) = (&s.config, cfg);
    if (was.seed, was.batch, was.micro_batches) != (now.seed, now.batch, now.micro_batches) {
        return Err(TrainError::Setup(format!(
            "{}: the run was started with seed {}, batch {} and {} micro-batches; resume it with the same \
             (they decide the batches and the rounding of the gradients)",
            run.dir.display(),
            was.seed,
            was.batch,
            was.micro_batches
        )));
    }
    observer.message(&format!("resuming {} at epoch {}{}", run.dir.display(), s.epoch, changes(was, now)));
    // Early stopping is judged under the patience of now: more of it lets a stopped run go on.
    let stopped_early = s.stops_early(cfg.patience);
    let state = TrainState { config: cfg.clone(), stopped_early, ..s };
    Ok((optim, state, Checkpoint::read(run.dir)?))
}

/// A run in progress: its settings, device, progress and checkpoint description.
struct Loop<'a> {
    run: &'a Run<'a>,
    device: Device,
    state: TrainState,
    checkpoint: Checkpoint,
}

impl Loop<'_> {
    /// The learning-rate schedule over the run at the current number of training examples.
    fn schedule(&self, examples: &impl Examples) -> Schedule {
        let cfg = self.run.config;
        Schedule::new(cfg.lr, cfg.warmup, cfg.epochs * examples.train_len().div_ceil(cfg.batch))
    }

    /// The optimisation steps of the current epoch from where it stands: the model after them, the examples
    /// trained on, and whether the epoch finished (false when `run.stop` interrupted it).
    fn steps(
        &mut self,
        examples: &impl Examples,
        mut model: Network,
        optim: &mut ModuleOptimizer,
        observer: &mut dyn TrainObserver,
    ) -> Result<(Network, usize, bool), TrainError> {
        let schedule = self.schedule(examples);
        let (cfg, device, state) = (self.run.config, &self.device, &mut self.state);
        let batches = examples.train_len().div_ceil(cfg.batch);
        let order = epoch_order(cfg.seed, state.epoch, examples.train_len());
        let shape = examples.shape();
        let mut trained = 0usize;
        for b in state.batch_in_epoch..batches {
            if self.run.stop.load(Ordering::Relaxed) {
                return Ok((model, trained, false));
            }
            let ids = &order[b * cfg.batch..((b + 1) * cfg.batch).min(order.len())];
            let (value, grads) =
                step_gradients(&model, ids.len(), cfg.micro_batches, (cfg.seed, state.step as u64), device, |r| {
                    let (x, y) = examples.train_batch(&ids[r.clone()]);
                    (
                        Tensor::from_data(TensorData::new(x, [r.len(), shape[0], shape[1]]), device),
                        Tensor::from_data(TensorData::new(y, [r.len(), NUM_LABELS]), device),
                    )
                });
            if !value.is_finite() {
                return Err(TrainError::Setup(format!(
                    "training diverged at step {} (loss {value}); lower the learning rate",
                    state.step
                )));
            }
            model = optim.step(schedule.lr(state.step), model, grads);
            state.step += 1;
            state.batch_in_epoch = b + 1;
            state.train_loss_sum += value * ids.len() as f64;
            trained += ids.len();
            observer.step(state.epoch, b + 1, batches, value);
        }
        Ok((model, trained, true))
    }

    /// Validation after an epoch: its metrics, the checkpoint if it is the best so far, early stopping, the
    /// metrics files. `spent` is what the whole epoch cost, every stretch of it.
    fn end_epoch(
        &mut self,
        examples: &impl Examples,
        model: &Network,
        spent: Spent,
        observer: &mut dyn TrainObserver,
    ) -> Result<(), TrainError> {
        let valid = model.valid();
        let (scores, _, val_loss) = evaluate(&valid, examples, &self.device.clone().inner());
        let lr = self.schedule(examples).lr(self.state.step.saturating_sub(1));
        let state = &mut self.state;
        let m = EpochMetrics {
            epoch: state.epoch,
            step: state.step,
            lr,
            train_loss: state.train_loss_sum / examples.train_len() as f64,
            validation_loss: val_loss,
            validation_r2: scores.r2,
            validation_rmse: scores.rmse,
            windows_per_second: spent.windows as f64 / spent.seconds.max(1e-9),
            seconds: spent.seconds,
            cpu_seconds: spent.cpu_seconds,
        };
        let best = val_loss < state.best_loss;
        if best {
            state.best_loss = val_loss;
            state.best_epoch = state.epoch;
            self.checkpoint.epoch = state.epoch;
            self.checkpoint.validation_loss = Some(val_loss);
            self.checkpoint.save(self.run.dir, &valid)?;
        }
        state.history.push(m.clone());
        observer.epoch(&m, best);
        state.epoch += 1;
        state.batch_in_epoch = 0;
        state.train_loss_sum = 0.0;
        state.stopped_early = state.stops_early(self.run.config.patience);
        write_history(self.run.dir, &state.history).map_err(|e| io(&e.0, e.1))
    }
}

/// Training throughput of architecture `cfg` in windows per second: `steps` optimisation steps (after `warmup`
/// untimed ones) on random standardised windows and targets, with the loss, optimizer and clipping of `train`.
/// The benchmark against PyTorch (bench/training.sh) runs this and the same model in PyTorch side by side.
pub fn synthetic_throughput(
    cfg: &NetworkConfig,
    batch: usize,
    micro_batches: usize,
    steps: usize,
    warmup: usize,
    seed: u64,
) -> Result<f64, TrainError> {
    use burn::tensor::Distribution;
    let device = Device::default().autodiff();
    device.seed(seed);
    let mut model = cfg.init(&device)?;
    let defaults = TrainConfig::default();
    let mut optim = optimizer(&defaults);
    let [len, width] = cfg.input_shape();
    let x = Tensor::<3>::random([batch, len, width], Distribution::Normal(0.0, 1.0), &device);
    let y = Tensor::<2>::random([batch, NUM_LABELS], Distribution::Normal(0.0, 1.0), &device);
    let mut started = Instant::now();
    for step in 0..warmup + steps {
        if step == warmup {
            started = Instant::now();
        }
        let (_, grads) = step_gradients(&model, batch, micro_batches, (seed, step as u64), &device, |r| {
            (x.clone().narrow(0, r.start, r.len()), y.clone().narrow(0, r.start, r.len()))
        });
        model = optim.step(defaults.lr, model, grads);
    }
    Ok((steps * batch) as f64 / started.elapsed().as_secs_f64().max(1e-9))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::{ModuleVisitor, Param};

    /// Every parameter's gradient, flattened, in module order.
    fn flat(model: &Network, grads: &GradientsParams) -> Vec<f32> {
        struct Collect<'a>(&'a GradientsParams, Vec<f32>);
        impl ModuleVisitor for Collect<'_> {
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                let g = self.0.get::<D>(param.id).expect("every parameter has a gradient");
                self.1.extend(g.into_data().try_to_vec::<f32>().unwrap());
            }
        }
        let mut c = Collect(grads, Vec::new());
        model.visit(&mut c);
        c.1
    }

    /// A small model and a batch of 7 windows (odd, so micro-batches differ in size).
    fn setup(dropout: f64) -> (Network, Tensor<3>, Tensor<2>, Device) {
        let device = Device::default().autodiff();
        let cfg = NetworkConfig::Transformer(crate::model::TransformerConfig {
            inputs: 3,
            seq_len: 8,
            layers: 1,
            heads: 2,
            d_model: 16,
            d_ff: 32,
            patch: 2,
            dropout,
        });
        let model = cfg.init(&device).unwrap();
        let mut rng = Rng::stream(5, &[]);
        let mut draw = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.uniform(-1.0, 1.0) as f32).collect() };
        let x = Tensor::<3>::from_data(TensorData::new(draw(7 * 8 * 3), [7, 8, 3]), &device);
        let y = Tensor::<2>::from_data(TensorData::new(draw(7 * NUM_LABELS), [7, NUM_LABELS]), &device);
        (model, x, y, device)
    }

    fn step(model: &Network, x: &Tensor<3>, y: &Tensor<2>, parts: usize, device: &Device) -> (f64, Vec<f32>) {
        let (loss, grads) = step_gradients(model, 7, parts, (0, 0), device, |r| {
            (x.clone().narrow(0, r.start, r.len()), y.clone().narrow(0, r.start, r.len()))
        });
        (loss, flat(model, &grads))
    }

    #[test]
    fn micro_batches_sum_to_the_whole_batch_gradient() {
        let (model, x, y, device) = setup(0.0);
        let (l1, g1) = step(&model, &x, &y, 1, &device);
        let (l3, g3) = step(&model, &x, &y, 3, &device);
        // Without dropout the split only reorders f32 sums: each gradient entry sums a few thousand products, so
        // the two differ by rounding, ~1e3 * 6e-8 of the entries' magnitude; 1e-4 of the largest leaves margin.
        let scale = g1.iter().fold(0f32, |m, v| m.max(v.abs()));
        assert!(scale > 0.0);
        let worst = g1.iter().zip(&g3).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst <= 1e-4 * scale, "largest difference {worst} of {scale}");
        assert!((l1 - l3).abs() <= 1e-5 * l1, "loss {l1} vs {l3}");
    }

    #[test]
    fn a_step_with_dropout_on_threads_is_reproducible() {
        let (model, x, y, device) = setup(0.3);
        let a = step(&model, &x, &y, 3, &device);
        let b = step(&model, &x, &y, 3, &device);
        assert_eq!(a, b, "thread timing must not change the masks or the sum");
        // And dropout is on: the loss differs from the deterministic forward pass's.
        let plain = (model.forward(x) - y).square().mean().into_scalar::<f32>() as f64;
        assert!((a.0 - plain).abs() > 1e-3 * plain, "dropout loss {} vs plain {plain}", a.0);
    }

    #[test]
    fn a_state_saved_without_the_spent_stretch_resumes_with_nothing_spent() {
        let state = TrainState {
            config: TrainConfig::default(),
            epoch: 2,
            step: 9,
            batch_in_epoch: 3,
            train_loss_sum: 1.5,
            best_loss: 0.7,
            best_epoch: 1,
            history: Vec::new(),
            stopped_early: false,
            spent: Spent { seconds: 4.0, cpu_seconds: 7.5, windows: 12 },
        };
        let mut json = serde_json::to_value(&state).unwrap();
        let back: TrainState = serde_json::from_value(json.clone()).unwrap();
        assert_eq!(back, state);
        json.as_object_mut().unwrap().remove("spent");
        let old: TrainState = serde_json::from_value(json).unwrap();
        assert_eq!(old, TrainState { spent: Spent::default(), ..state });
    }
}
