//! `dynforge train`: flags -> a training session.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use dynforge_trainer::data::window::WindowSpec;
use dynforge_trainer::model::Preset;
use dynforge_trainer::training::session::{ModelKind, Recipe, Session};

use crate::progress::{Bars, STOP, catch_interrupts};

/// What defines a training run besides its data and output directory; unset values take the estimator's defaults.
#[derive(Args, Clone)]
pub struct RecipeArgs {
    /// Estimator.
    #[arg(long, value_enum, default_value = "physics")]
    pub model: ModelKind,
    /// Transformer architecture preset [default: paper; pipeline: fast].
    #[arg(long, value_enum)]
    pub preset: Option<Preset>,
    #[arg(long)]
    pub layers: Option<usize>,
    /// Transformer: attention heads.
    #[arg(long)]
    pub heads: Option<usize>,
    /// Transformer: embedding size; physics: hidden width.
    #[arg(long)]
    pub dim: Option<usize>,
    /// Transformer: time steps per token.
    #[arg(long)]
    pub patch: Option<usize>,
    #[arg(long)]
    pub dropout: Option<f64>,
    /// Sequence length L (time steps per window).
    #[arg(long = "len", default_value_t = 64)]
    pub len: usize,
    /// Stride between the time steps of a window, in 1 kHz samples (the paper's "sampling rate").
    #[arg(long, default_value_t = 64)]
    pub stride: usize,
    /// Secondary sampling rate: window offsets 0, SSR, 2 SSR, ... below the stride.
    #[arg(long, default_value_t = 16)]
    pub ssr: usize,
    /// Maximum epochs [default: 30; pipeline: 12 (transformer)].
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Examples per step [default: transformer 64, physics 256].
    #[arg(long)]
    pub batch: Option<usize>,
    /// Peak learning rate (AdamW; linear warmup over 5 % of the steps, then cosine decay) [default: transformer
    /// 5e-4, physics 1e-3].
    #[arg(long)]
    pub lr: Option<f64>,
    /// Epochs without a better validation loss before stopping early.
    #[arg(long)]
    pub patience: Option<usize>,
    /// Seed of the robot-level split, the initial weights, the batch order and dropout.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Share of the robots held out for validation.
    #[arg(long, default_value_t = 0.2)]
    pub validation: f64,
    /// Parts each batch is split into, each run on a thread of its own (part of the run's definition, not of the
    /// machine: the same value gives the same model anywhere) [default: transformer 4, physics 2].
    #[arg(long)]
    pub micro_batches: Option<usize>,
    /// Physics: robots drawn from the generator per epoch (paired with real windows' excitation; never simulated).
    #[arg(long)]
    pub generated: Option<usize>,
    /// Physics: train on generated robots only; the dataset's windows give the excitations and the validation.
    #[arg(long)]
    pub generated_only: bool,
    /// Physics: half the generated robots carry torque noise (1e-4 to 1e-2 of the RMS), weighted as `estimate`
    /// weighs a noisy log, so the network has seen what a real robot's log looks like.
    #[arg(long)]
    pub noisy: bool,
}

impl RecipeArgs {
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
        r.validation = self.validation;
        r.generated_per_epoch = self.generated.unwrap_or(r.generated_per_epoch);
        r.generated_only = self.generated_only;
        r.noisy = self.noisy;
        r
    }
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
    /// Train while the dataset is being generated (transformer): wait for shards, and add the shards that appear
    /// before each epoch (the preprocessing statistics stay those of the first shards).
    #[arg(long)]
    follow: bool,
    #[command(flatten)]
    recipe: RecipeArgs,
}

pub fn run(args: TrainArgs) -> Result<()> {
    let recipe = args.recipe.recipe(Preset::Paper, None);
    catch_interrupts();
    let session = Session {
        data: &args.data,
        out: &args.out,
        resume: args.resume,
        follow: args.follow,
        recipe: &recipe,
        stop: &STOP,
    };
    session.run(&mut Bars::new(recipe.train.batch))?;
    Ok(())
}
