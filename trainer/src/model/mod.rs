//! The estimators, selectable per run: the paper's pure [`transformer`] over downsampled windows, and the
//! [`physics`] map that reads what the torques identify. Both regress the 38 standardised labels and train in the
//! same loop; [`Network`] is whichever one a run uses.

mod attention;
pub mod noise;
pub mod physics;
pub mod transformer;

use burn::module::Module;
use burn::tensor::{Device, Tensor};
use dynforge_robot::rng::Rng;
use serde::{Deserialize, Serialize};

pub use physics::{PhysicsConfig, PhysicsMap};
pub use transformer::{JOINTS, Preset, Transformer, TransformerConfig};

#[derive(Debug, thiserror::Error, PartialEq)]
#[error("model configuration: {0}")]
pub struct ConfigError(pub(crate) String);

/// Which estimator, and its size.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum NetworkConfig {
    Transformer(TransformerConfig),
    Physics(PhysicsConfig),
}

impl NetworkConfig {
    pub fn check(&self) -> Result<(), ConfigError> {
        match self {
            NetworkConfig::Transformer(c) => c.check(),
            NetworkConfig::Physics(c) => c.check(),
        }
    }

    pub fn init(&self, device: &Device) -> Result<Network, ConfigError> {
        Ok(match self {
            NetworkConfig::Transformer(c) => Network::Transformer(c.init(device)?),
            NetworkConfig::Physics(c) => Network::Physics(c.init(device)?),
        })
    }

    /// Trainable parameters.
    pub fn parameters(&self) -> usize {
        match self {
            NetworkConfig::Transformer(c) => c.parameters(),
            NetworkConfig::Physics(c) => c.parameters(),
        }
    }

    /// The shape of one example's input: `[steps, values per step]` (a physics example is one step of features).
    pub fn input_shape(&self) -> [usize; 2] {
        match self {
            NetworkConfig::Transformer(c) => [c.seq_len, c.inputs],
            NetworkConfig::Physics(c) => [1, c.inputs],
        }
    }

    /// One line for logs.
    pub fn describe(&self) -> String {
        match self {
            NetworkConfig::Transformer(m) => format!(
                "transformer: {} layers, {} heads, {} dims, patch {} ({} tokens), {} parameters",
                m.layers,
                m.heads,
                m.d_model,
                m.patch,
                m.tokens(),
                m.parameters()
            ),
            NetworkConfig::Physics(m) => format!(
                "physics: {} features, {} x {} hidden, {} parameters",
                m.inputs,
                m.layers,
                m.hidden,
                m.parameters()
            ),
        }
    }
}

// The transformer is larger than the map; a run holds one network, so boxing would buy nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Module, Debug)]
pub enum Network {
    Transformer(Transformer),
    Physics(PhysicsMap),
}

impl Network {
    /// Standardised labels `[B, 38]` of standardised inputs `[B, steps, values]` (no dropout).
    pub fn forward(&self, x: Tensor<3>) -> Tensor<2> {
        match self {
            Network::Transformer(m) => m.forward(x),
            Network::Physics(m) => m.forward(flat(x)),
        }
    }

    /// The training pass: dropout masks drawn from `rng`.
    pub fn forward_train(&self, x: Tensor<3>, rng: &mut Rng) -> Tensor<2> {
        match self {
            Network::Transformer(m) => m.forward_train(x, rng),
            Network::Physics(m) => m.forward_train(flat(x), rng),
        }
    }
}

/// A size for counting parameters: sizes past 2^32 count as 2^32 (the count is then past any machine's memory
/// anyway), so that products of a few of them cannot overflow.
fn dimension(v: usize) -> u128 {
    (v as u128).min(1 << 32)
}

/// `[B, 1, F]` -> `[B, F]`.
fn flat(x: Tensor<3>) -> Tensor<2> {
    let [b, s, f] = x.dims();
    x.reshape([b, s * f])
}
