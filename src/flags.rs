//! The command line's shared flags: the value rules of numeric flags, as parsers a flag names (`value_parser =
//! whole(1, MAX)`: a value out of range is refused before anything runs, with what the flag takes, instead of becoming
//! a panic, an abort or a run that means nothing such as `--lr nan`), the choices the libraries define, as the flags
//! that name them, and the training recipe's flags shared by `train`, `pipeline` and `sweep`.

use clap::ValueEnum;
use dynforge_dataset::prepare::ModelKind;
use dynforge_dataset::split::HoldOut;
use dynforge_dataset::window::WindowSpec;
use dynforge_proto::sim::EngineKind;
use dynforge_trainer::device::{Accelerator, DeviceError};
use dynforge_trainer::model::Preset;
use dynforge_trainer::training::recipe::Recipe;

/// Robots a dataset may have: 12,000 times the paper's 8192. Far more is a typing mistake, and a run of that size
/// would write petabytes.
pub const MAX_ROBOTS: u64 = 100_000_000;

/// A flag's value refused, saying what the flag takes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct FlagError(String);

impl From<&str> for FlagError {
    fn from(what: &str) -> Self {
        FlagError(what.to_string())
    }
}

/// A parser of whole numbers from `lo` to `hi`.
pub fn whole<T>(lo: u64, hi: u64) -> impl Fn(&str) -> Result<T, FlagError> + Clone + Send + Sync + 'static
where
    T: TryFrom<u64>,
{
    move |s: &str| {
        let refuse = || FlagError(format!("expected a whole number from {lo} to {hi}"));
        let v: u64 = s.trim().parse().map_err(|_| refuse())?;
        if !(lo..=hi).contains(&v) {
            return Err(refuse());
        }
        T::try_from(v).map_err(|_| refuse())
    }
}

/// A finite number above 0.
pub fn positive(s: &str) -> Result<f64, FlagError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err("expected a positive finite number".into()),
    }
}

/// A finite number of at least 0.
pub fn non_negative(s: &str) -> Result<f64, FlagError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v >= 0.0 && v.is_finite() => Ok(v),
        _ => Err("expected a finite number of at least 0".into()),
    }
}

/// A share strictly between 0 and 1 (a validation split: both sides must have something).
pub fn share(s: &str) -> Result<f64, FlagError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v < 1.0 => Ok(v),
        _ => Err("expected a number between 0 and 1 (exclusive)".into()),
    }
}

/// A joint to weld, `NAME` or `NAME=POSITION` (the position defaults to 0).
pub fn weld(s: &str) -> Result<(String, f64), FlagError> {
    match s.split_once('=') {
        None => Ok((s.to_string(), 0.0)),
        Some((name, at)) => match at.trim().parse::<f64>() {
            Ok(v) if v.is_finite() => Ok((name.to_string(), v)),
            _ => Err(FlagError(format!("expected NAME or NAME=POSITION, and '{at}' is not a finite number"))),
        },
    }
}

/// Which engine runs a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Engine {
    /// Featherstone ABA + RK4 with exact stick/slip Coulomb friction (`dynforge_worker`'s own).
    Native,
    /// rapier3d-f64's reduced-coordinate multibody (semi-implicit Euler substeps).
    Rapier,
}

impl From<Engine> for EngineKind {
    fn from(e: Engine) -> Self {
        match e {
            Engine::Native => EngineKind::Native,
            Engine::Rapier => EngineKind::Rapier,
        }
    }
}

/// Which estimator a run trains.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Estimator {
    /// Physics as input: what each window's torques identify (posterior of the generator's parameter prior),
    /// mapped to the labels by a network trained on generated robots.
    Physics,
    /// The paper's transformer over downsampled windows of q, qd, tau and Jacobian features.
    Transformer,
}

impl From<Estimator> for ModelKind {
    fn from(e: Estimator) -> Self {
        match e {
            Estimator::Physics => ModelKind::Physics,
            Estimator::Transformer => ModelKind::Transformer,
        }
    }
}

/// The transformer's named architectures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Architecture {
    /// 4 layers, 32 heads of width 4, 128 dims, a token per time step (the paper's best).
    Paper,
    /// 4 layers, 4 heads of width 32, 128 dims, 4 time steps per token: several times cheaper on CPU.
    Fast,
}

impl From<Architecture> for Preset {
    fn from(a: Architecture) -> Self {
        match a {
            Architecture::Paper => Preset::Paper,
            Architecture::Fast => Preset::Fast,
        }
    }
}

/// What a split holds out for validation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Split {
    /// Whole robots.
    Robots,
    /// Whole recordings, of robots whose other recordings are trained on.
    Trajectories,
    /// Time segments of recordings drawn across all robots and recordings: a window and its offset siblings (the same
    /// stretch of motion shifted by a few milliseconds) are on one side.
    Windows,
}

impl From<Split> for HoldOut {
    fn from(s: Split) -> Self {
        match s {
            Split::Robots => HoldOut::Robots,
            Split::Trajectories => HoldOut::Trajectories,
            Split::Windows => HoldOut::Windows,
        }
    }
}

/// A [`Recipe`] as a command line sets it: the estimator, its architecture and window geometry, and the
/// optimisation; unset values take the estimator's (or the calling command's) defaults. The flags of `train`,
/// `pipeline` and `sweep`.
#[derive(Debug, Clone, clap::Args)]
pub struct RecipeFlags {
    /// Estimator.
    #[arg(long, value_enum, default_value = "physics")]
    pub model: Estimator,
    /// Transformer architecture preset [default: paper; pipeline: fast].
    #[arg(long, value_enum)]
    pub preset: Option<Architecture>,
    /// Transformer: encoder layers; physics: hidden layers [default: 4; physics 3].
    #[arg(long, value_parser = whole::<usize>(1, 1 << 16))]
    pub layers: Option<usize>,
    /// Transformer: attention heads.
    #[arg(long, value_parser = whole::<usize>(1, 1 << 16))]
    pub heads: Option<usize>,
    /// Transformer: embedding size; physics: hidden width.
    #[arg(long, value_parser = whole::<usize>(1, 1 << 24))]
    pub dim: Option<usize>,
    /// Transformer: time steps per token.
    #[arg(long, value_parser = whole::<usize>(1, 1 << 16))]
    pub patch: Option<usize>,
    /// Dropout rate during training, in [0, 1) [default: transformer 0.1, physics 0].
    #[arg(long)]
    pub dropout: Option<f64>,
    /// Sequence length L (time steps per window).
    #[arg(long = "len", default_value_t = 64, value_parser = whole::<usize>(1, 1 << 20))]
    pub len: usize,
    /// Stride between the time steps of a window, in 1 kHz samples (the paper's "sampling rate").
    #[arg(long, default_value_t = 64, value_parser = whole::<usize>(1, 1 << 20))]
    pub stride: usize,
    /// Secondary sampling rate: window offsets 0, SSR, 2 SSR, ... below the stride.
    #[arg(long, default_value_t = 16, value_parser = whole::<usize>(1, 1 << 20))]
    pub ssr: usize,
    /// Time steps from one window's start to the next, a divisor of --len: less than --len overlaps them and reads
    /// the motion the last back-to-back window of a recording leaves (half the window: 1.6x the windows of 7.4 s
    /// recordings); `evaluate` still scores back-to-back windows [default: --len, back to back].
    #[arg(long, value_parser = whole::<usize>(1, 1 << 20))]
    pub hop: Option<usize>,
    /// Maximum epochs [default: 30; pipeline: 12 (transformer)].
    #[arg(long, value_parser = whole::<usize>(1, 1 << 20))]
    pub epochs: Option<usize>,
    /// Examples per step [default: transformer 64, physics 256].
    #[arg(long, value_parser = whole::<usize>(1, 1 << 24))]
    pub batch: Option<usize>,
    /// Peak learning rate (AdamW; linear warmup over 5 % of the steps, then cosine decay) [default: transformer
    /// 5e-4, physics 1e-3].
    #[arg(long, value_parser = positive)]
    pub lr: Option<f64>,
    /// Epochs without a better validation loss before stopping early.
    #[arg(long)]
    pub patience: Option<usize>,
    /// Seed of the split, the initial weights, the batch order and dropout.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// What validation holds out: whole robots (what a new robot is), whole recordings of robots trained on with
    /// their others, or time segments of recordings (robots and recordings seen in training).
    #[arg(long, value_enum, default_value_t = Split::Robots)]
    pub split: Split,
    /// Share held out for validation (of the robots, recordings or windows).
    #[arg(long, default_value_t = 0.2, value_parser = share)]
    pub validation: f64,
    /// Parts each batch is split into, each run on a thread of its own (part of the run's definition, not of the
    /// machine: the same value gives the same model anywhere) [default: transformer 4, physics 2].
    #[arg(long, value_parser = whole::<usize>(1, 1 << 10))]
    pub micro_batches: Option<usize>,
    /// Physics: robots drawn from the generator per epoch (paired with real windows' excitation; never simulated).
    #[arg(long, value_parser = whole::<usize>(1, u32::MAX as u64))]
    pub generated: Option<usize>,
    /// Physics: train on generated robots only; the dataset's windows give the excitations and the validation.
    #[arg(long)]
    pub generated_only: bool,
    /// Physics: half the generated robots carry torque noise (1e-4 to 1e-2 of the RMS), weighted as `estimate`
    /// weighs a noisy log, so the network has seen what a real robot's log looks like.
    #[arg(long)]
    pub noisy: bool,
    /// Where the steps run: cpu, or cuda / cuda:N (a GPU: needs a build with `--features cuda`). A run may resume
    /// on another device.
    #[arg(long, default_value = "cpu")]
    pub device: Accelerator,
}

impl RecipeFlags {
    pub fn model_is_transformer(&self) -> bool {
        self.model == Estimator::Transformer
    }

    /// The recipe, with `preset` and `epochs` as the command's defaults where not given; a device this build cannot
    /// run on is refused here, before a command reads or writes anything.
    pub fn recipe(&self, preset: Preset, epochs: Option<usize>) -> Result<Recipe, DeviceError> {
        self.device.device()?;
        let mut r = Recipe::defaults(self.model.into());
        r.model.preset = self.preset.map_or(preset, Preset::from);
        (r.model.layers, r.model.heads, r.model.dim) = (self.layers, self.heads, self.dim);
        (r.model.patch, r.model.dropout) = (self.patch, self.dropout);
        r.window = WindowSpec::new(self.len, self.stride, self.ssr).with_hop(self.hop.unwrap_or(self.len));
        let t = &mut r.train;
        t.epochs = self.epochs.or(epochs).unwrap_or(t.epochs);
        t.batch = self.batch.unwrap_or(t.batch);
        t.lr = self.lr.unwrap_or(t.lr);
        t.patience = self.patience.unwrap_or(t.patience);
        t.micro_batches = self.micro_batches.unwrap_or(t.micro_batches);
        t.seed = self.seed;
        t.device = self.device;
        (r.split, r.validation) = (self.split.into(), self.validation);
        r.generated_per_epoch = self.generated.unwrap_or(r.generated_per_epoch);
        r.generated_only = self.generated_only;
        r.noisy = self.noisy;
        Ok(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn out_of_range_values_are_refused_saying_what_is_taken() {
        let robots = whole::<u64>(1, MAX_ROBOTS);
        assert_eq!(robots("8192"), Ok(8192));
        for bad in ["-1", "0", "1e9", "10000000000", "18446744073709551616", "x", ""] {
            assert_eq!(robots(bad), Err("expected a whole number from 1 to 100000000".into()), "{bad}");
        }
        assert_eq!(whole::<u8>(0, 1000)("300"), Err("expected a whole number from 0 to 1000".into()));
        assert_eq!(positive("5e-4"), Ok(5e-4));
        for bad in ["nan", "inf", "-1", "0", "x"] {
            assert!(positive(bad).is_err(), "{bad}");
        }
        assert_eq!(non_negative("0"), Ok(0.0));
        assert!(non_negative("-1e-3").is_err() && non_negative("inf").is_err());
        assert_eq!(share("0.2"), Ok(0.2));
        for bad in ["0", "1", "nan", "-0.1", "x"] {
            assert!(share(bad).is_err(), "{bad}");
        }
        assert_eq!(weld("finger"), Ok(("finger".into(), 0.0)));
        assert_eq!(weld("finger=0.02"), Ok(("finger".into(), 0.02)));
        assert!(weld("finger=nan").is_err() && weld("finger=").is_err());
    }
}
