//! The physics estimator's network: from what the torques say about a robot (the posterior of the generator prior's
//! coordinates, and the labels of its mean: `crate::data::physics::features`) to the 38 labels. The labels of the
//! posterior mean are already an estimate; the network learns the correction the generator's (non-Gaussian,
//! nonlinear) distribution implies, above all for what the torques cannot see.
//!
//! ```text
//! features [B, F] --Linear(F, h)--GELU--> (Linear(h, h)--GELU) x (layers - 1) --Linear(h, 38)--> c [B, 38]
//! labels = plug-in + spread * 3 tanh(c / 3)          (spread, plug-in: the last 2 x 38 features)
//! ```
//!
//! Scaling the correction by each label's posterior spread keeps what the torques pin down as they say it, however
//! the network generalises, and leaves it free where they say nothing.

use burn::module::Module;
use burn::nn::{Initializer, Linear, LinearConfig};
use burn::tensor::Device;
use burn::tensor::Tensor;
use burn::tensor::activation::gelu;
use dynforge_proto::NUM_LABELS;
use dynforge_robot::rng::Rng;
use serde::{Deserialize, Serialize};

use super::ConfigError;
use super::noise::Noise;

/// How many posterior spreads the correction may move a label (the prior itself is ~1 spread wide when the data
/// say nothing, so a few spreads reach anywhere the generator goes).
const REACH: f32 = 3.0;

/// Size of the map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhysicsConfig {
    /// Input features; the last 2 x [`NUM_LABELS`] of them are the labels' posterior spreads and the plug-in labels
    /// the output corrects.
    pub inputs: usize,
    pub hidden: usize,
    pub layers: usize,
    pub dropout: f64,
}

impl PhysicsConfig {
    /// The default map for `inputs` features.
    pub fn new(inputs: usize) -> Self {
        PhysicsConfig { inputs, hidden: 256, layers: 3, dropout: 0.0 }
    }

    pub fn check(&self) -> Result<(), ConfigError> {
        if self.inputs < 2 * NUM_LABELS || self.hidden == 0 || self.layers == 0 {
            return Err(ConfigError(format!(
                "physics map: {} inputs (at least the labels' spreads and plug-in values), {} hidden units and {} layers",
                self.inputs, self.hidden, self.layers
            )));
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return Err(ConfigError(format!("dropout {} is not in [0, 1)", self.dropout)));
        }
        Ok(())
    }

    pub fn init(&self, device: &Device) -> Result<PhysicsMap, ConfigError> {
        self.check()?;
        let widths: Vec<usize> =
            std::iter::once(self.inputs).chain(std::iter::repeat_n(self.hidden, self.layers)).collect();
        Ok(PhysicsMap {
            hidden: widths.windows(2).map(|w| LinearConfig::new(w[0], w[1]).init(device)).collect(),
            // Zero output weights: an untrained map returns the plug-in labels, and training moves it away from them
            // only where the generated robots show that it pays.
            out: LinearConfig::new(self.hidden, NUM_LABELS).with_initializer(Initializer::Zeros).init(device),
            inputs: self.inputs,
            dropout: self.dropout,
        })
    }

    /// Trainable parameters; past what any machine holds, a number still (to refuse), not an overflow.
    pub fn parameters(&self) -> usize {
        let [inputs, hidden, layers] = [self.inputs, self.hidden, self.layers].map(super::dimension);
        let n = (inputs * hidden + hidden)
            + layers.saturating_sub(1) * (hidden * hidden + hidden)
            + (hidden * NUM_LABELS as u128 + NUM_LABELS as u128);
        usize::try_from(n).unwrap_or(usize::MAX)
    }
}

#[derive(Module, Debug)]
pub struct PhysicsMap {
    hidden: Vec<Linear>,
    out: Linear,
    inputs: usize,
    dropout: f64,
}

impl PhysicsMap {
    pub(crate) fn run(&self, x: Tensor<2>, noise: &mut Noise) -> Tensor<2> {
        let [batch, _] = x.dims();
        let spread = x.clone().narrow(1, self.inputs - 2 * NUM_LABELS, NUM_LABELS);
        let plug_in = x.clone().narrow(1, self.inputs - NUM_LABELS, NUM_LABELS);
        let mut h = x;
        for layer in &self.hidden {
            h = noise.apply(gelu(layer.forward(h)));
        }
        let out = self.out.forward(h);
        debug_assert_eq!(out.dims(), [batch, NUM_LABELS]);
        // At most REACH spreads from the plug-in value.
        out.div_scalar(REACH).tanh().mul_scalar(REACH) * spread + plug_in
    }

    pub fn dropout(&self) -> f64 {
        self.dropout
    }

    /// Standardised labels `[B, 38]` of features `[B, F]` (no dropout).
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        self.run(x, &mut Noise::off())
    }

    /// As [`PhysicsMap::forward`], with dropout masks drawn from `rng`.
    pub fn forward_train(&self, x: Tensor<2>, rng: &mut Rng) -> Tensor<2> {
        self.run(x, &mut Noise::dropout(self.dropout, rng))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    #[test]
    fn an_untrained_map_returns_the_plug_in_labels_and_the_parameter_count_matches() {
        let device = Device::default();
        let cfg = PhysicsConfig { inputs: 2 * NUM_LABELS + 4, hidden: 8, layers: 2, dropout: 0.0 };
        let model = cfg.init(&device).unwrap();
        assert_eq!(model.num_params(), cfg.parameters());
        // Untrained, the map returns the plug-in labels (the last inputs) exactly.
        let a: Vec<f32> = (0..cfg.inputs).map(|i| i as f32 * 0.01).collect();
        let x = Tensor::<2>::from_data(TensorData::new(a, [1, cfg.inputs]), &device);
        let y = model.forward(x.clone());
        assert_eq!(y.dims(), [1, NUM_LABELS]);
        let correction: Vec<f32> =
            (y - x.narrow(1, 4 + NUM_LABELS, NUM_LABELS)).into_data().try_to_vec::<f32>().unwrap();
        assert!(correction.iter().all(|v| *v == 0.0), "{correction:?}");
        assert!(PhysicsConfig { inputs: 10, ..cfg }.check().is_err());
    }
}
