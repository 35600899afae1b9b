//! What defines a training run besides its data and output directory ([`Recipe`]): the estimator and its
//! architecture, the window geometry, the optimisation and the physics estimator's examples; the defaults of each
//! estimator, and the command line's overrides ([`RecipeFlags`]).

use dynforge_dataset::prepare::ModelKind;
use dynforge_dataset::split::HoldOut;
use dynforge_dataset::window::WindowSpec;

use super::TrainConfig;
use crate::model::{PhysicsConfig, Preset, TransformerConfig};
#[cfg(feature = "clap")]
use dynforge_proto::flags::{positive, share, whole};

/// The architecture: the estimator, and the parts of its default size a run overrides.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelChoice {
    pub kind: ModelKind,
    /// The transformer's preset.
    pub preset: Preset,
    pub layers: Option<usize>,
    pub heads: Option<usize>,
    /// The transformer's embedding size, the physics map's hidden width.
    pub dim: Option<usize>,
    pub patch: Option<usize>,
    pub dropout: Option<f64>,
}

impl ModelChoice {
    pub fn new(kind: ModelKind, preset: Preset) -> Self {
        ModelChoice { kind, preset, layers: None, heads: None, dim: None, patch: None, dropout: None }
    }

    /// The transformer's configuration for `inputs` values per step of `seq_len`-step windows.
    pub fn transformer(&self, inputs: usize, seq_len: usize) -> TransformerConfig {
        let mut c = self.preset.config(inputs, seq_len);
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

    /// The physics map's configuration for `inputs` features.
    pub fn physics(&self, inputs: usize) -> PhysicsConfig {
        let mut c = PhysicsConfig::new(inputs);
        c.hidden = self.dim.unwrap_or(c.hidden);
        c.layers = self.layers.unwrap_or(c.layers);
        c.dropout = self.dropout.unwrap_or(c.dropout);
        c
    }
}

/// What defines a training run besides its data and output directory.
#[derive(Debug, Clone, PartialEq)]
pub struct Recipe {
    pub model: ModelChoice,
    pub window: WindowSpec,
    pub train: TrainConfig,
    /// What is held out for validation, and its share.
    pub split: HoldOut,
    pub validation: f64,
    /// Robots drawn from the generator per epoch (physics estimator).
    pub generated_per_epoch: usize,
    /// Physics estimator: train on the generated robots only, the dataset's windows serving as excitations and
    /// for validation.
    pub generated_only: bool,
    /// Physics estimator: half the generated robots carry torque noise, weighted as `estimate` weighs a noisy log.
    pub noisy: bool,
}

impl Recipe {
    /// The defaults of a run of `kind`. The transformer: the paper's architecture, AdamW at 5e-4, batch 64 in 4
    /// micro-batches (fastest on 2 cores). The physics map: a small network on many cheap examples, so larger batches
    /// and rate; 32,768 generated robots per epoch (~2 s of drawing per epoch per core).
    pub fn defaults(kind: ModelKind) -> Recipe {
        let train = match kind {
            ModelKind::Transformer => TrainConfig::default(),
            ModelKind::Physics => TrainConfig { batch: 256, lr: 1e-3, micro_batches: 2, ..TrainConfig::default() },
        };
        Recipe {
            model: ModelChoice::new(kind, Preset::Paper),
            window: WindowSpec::default(),
            train,
            split: HoldOut::Robots,
            validation: 0.2,
            generated_per_epoch: 32_768,
            generated_only: false,
            noisy: false,
        }
    }
}

/// A [`Recipe`] as a command line sets it: the estimator, its architecture and window geometry, and the
/// optimisation; unset values take the estimator's (or the calling command's) defaults. With the `clap` feature these
/// are the flags of `train`, `pipeline` and `sweep`.
#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct RecipeFlags {
    /// Estimator.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "physics"))]
    pub model: ModelKind,
    /// Transformer architecture preset [default: paper; pipeline: fast].
    #[cfg_attr(feature = "clap", arg(long, value_enum))]
    pub preset: Option<Preset>,
    #[cfg_attr(feature = "clap", arg(long, value_parser = whole::<usize>(1, 1 << 16)))]
    pub layers: Option<usize>,
    /// Transformer: attention heads.
    #[cfg_attr(feature = "clap", arg(long, value_parser = whole::<usize>(1, 1 << 16)))]
    pub heads: Option<usize>,
    /// Transformer: embedding size; physics: hidden width.
    #[cfg_attr(feature = "clap", arg(long, value_parser = whole::<usize>(1, 1 << 24)))]
    pub dim: Option<usize>,
    /// Transformer: time steps per token.
    #[cfg_attr(feature = "clap", arg(long, value_parser = whole::<usize>(1, 1 << 16)))]
    pub patch: Option<usize>,
    #[cfg_attr(feature = "clap", arg(long))]
    pub dropout: Option<f64>,
    /// Sequence length L (time steps per window).
    #[cfg_attr(feature = "clap", arg(long = "len", default_value_t = 64, value_parser = whole::<usize>(1, 1 << 20)))]
    pub len: usize,
    /// Stride between the time steps of a window, in 1 kHz samples (the paper's "sampling rate").
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 64, value_parser = whole::<usize>(1, 1 << 20)))]
    pub stride: usize,
    /// Secondary sampling rate: window offsets 0, SSR, 2 SSR, ... below the stride.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 16, value_parser = whole::<usize>(1, 1 << 20)))]
    pub ssr: usize,
    /// Maximum epochs [default: 30; pipeline: 12 (transformer)].
    #[cfg_attr(feature = "clap", arg(long, value_parser = whole::<usize>(1, 1 << 20)))]
    pub epochs: Option<usize>,
    /// Examples per step [default: transformer 64, physics 256].
    #[cfg_attr(feature = "clap", arg(long, value_parser = whole::<usize>(1, 1 << 24)))]
    pub batch: Option<usize>,
    /// Peak learning rate (AdamW; linear warmup over 5 % of the steps, then cosine decay) [default: transformer
    /// 5e-4, physics 1e-3].
    #[cfg_attr(feature = "clap", arg(long, value_parser = positive))]
    pub lr: Option<f64>,
    /// Epochs without a better validation loss before stopping early.
    #[cfg_attr(feature = "clap", arg(long))]
    pub patience: Option<usize>,
    /// Seed of the split, the initial weights, the batch order and dropout.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 0))]
    pub seed: u64,
    /// What validation holds out: whole robots (what a new robot is), whole recordings of robots trained on with
    /// their others, or windows drawn at random across all (robots and recordings seen in training).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value_t = HoldOut::Robots))]
    pub split: HoldOut,
    /// Share held out for validation (of the robots, recordings or windows).
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 0.2, value_parser = share))]
    pub validation: f64,
    /// Parts each batch is split into, each run on a thread of its own (part of the run's definition, not of the
    /// machine: the same value gives the same model anywhere) [default: transformer 4, physics 2].
    #[cfg_attr(feature = "clap", arg(long, value_parser = whole::<usize>(1, 1 << 10)))]
    pub micro_batches: Option<usize>,
    /// Physics: robots drawn from the generator per epoch (paired with real windows' excitation; never simulated).
    #[cfg_attr(feature = "clap", arg(long, value_parser = whole::<usize>(1, u32::MAX as u64)))]
    pub generated: Option<usize>,
    /// Physics: train on generated robots only; the dataset's windows give the excitations and the validation.
    #[cfg_attr(feature = "clap", arg(long))]
    pub generated_only: bool,
    /// Physics: half the generated robots carry torque noise (1e-4 to 1e-2 of the RMS), weighted as `estimate`
    /// weighs a noisy log, so the network has seen what a real robot's log looks like.
    #[cfg_attr(feature = "clap", arg(long))]
    pub noisy: bool,
}

impl RecipeFlags {
    pub fn model_is_transformer(&self) -> bool {
        self.model == ModelKind::Transformer
    }

    /// The recipe, with `preset` and `epochs` as the command's defaults where not given.
    pub fn recipe(&self, preset: Preset, epochs: Option<usize>) -> Recipe {
        let mut r = Recipe::defaults(self.model);
        r.model.preset = self.preset.unwrap_or(preset);
        (r.model.layers, r.model.heads, r.model.dim) = (self.layers, self.heads, self.dim);
        (r.model.patch, r.model.dropout) = (self.patch, self.dropout);
        r.window = WindowSpec { len: self.len, stride: self.stride, ssr: self.ssr };
        let t = &mut r.train;
        t.epochs = self.epochs.or(epochs).unwrap_or(t.epochs);
        t.batch = self.batch.unwrap_or(t.batch);
        t.lr = self.lr.unwrap_or(t.lr);
        t.patience = self.patience.unwrap_or(t.patience);
        t.micro_batches = self.micro_batches.unwrap_or(t.micro_batches);
        t.seed = self.seed;
        (r.split, r.validation) = (self.split, self.validation);
        r.generated_per_epoch = self.generated.unwrap_or(r.generated_per_epoch);
        r.generated_only = self.generated_only;
        r.noisy = self.noisy;
        r
    }
}
