//! What defines a training run besides its data and output directory ([`Recipe`]): the estimator and its
//! architecture, the window geometry, the optimisation and the physics estimator's examples; the defaults of each
//! estimator.

use dynforge_dataset::prepare::ModelKind;
use dynforge_dataset::split::HoldOut;
use dynforge_dataset::window::WindowSpec;

use super::TrainConfig;
use crate::model::{PhysicsConfig, Preset, TransformerConfig};

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
