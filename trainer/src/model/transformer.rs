//! The paper's estimator: a transformer encoder over the window's time axis, then joint-specific attention that
//! decodes the parameters of each joint (and the link it moves) from its own token.
//!
//! ```text
//! window [B, L, F] --(patch p)--> [B, L/p, p F] --Linear--> [B, T, d] + sinusoids
//!   --> temporal encoder (layers x heads): attention across time                    [B, T, d]
//!   --> joint queries (one learned token per joint) cross-attend to the time tokens   [B, J, d]
//!   --> joint encoder (1 layer): attention across joints                               [B, J, d]
//!   --> shared head Linear(d, 7) per joint token: coulomb, viscous, mass, com, Ixx, Iyy, Izz of that joint and
//!       its child link --> the 38 labels picked out of the J x 7 grid                 [B, 38]
//! ```
//!
//! The paper's description ("input embedding, joint-specific transformers, output decoding") fixes the parts, not
//! their wiring; this wiring gives each joint a token of its own to attend with, so a joint's friction and its
//! link's inertia are read by the same query, and costs only J extra tokens. `patch` > 1 groups consecutive time
//! steps into one token (as PatchTST does): attention cost falls with the square of the token count.

use burn::module::{Module, Param};
use burn::nn::{
    Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig, PositionalEncoding, PositionalEncodingConfig,
};
use burn::tensor::{Device, Int, Tensor, TensorData};
use dynforge_proto::{LABELS, LabelKind, NUM_LABELS};
use dynforge_robot::rng::Rng;
use serde::{Deserialize, Serialize};

use super::ConfigError;
use super::attention::{Encoder, MultiHeadAttention};
use super::noise::Noise;

/// Outputs per joint token: the joint's friction and its child link's inertial labels.
const SLOTS: usize = 7;

/// Joints of the labelled arm (the paper's 6R).
pub const JOINTS: usize = 6;

/// Architecture. Defaults are the paper's best (4 layers, 32 heads, 128 dims, one time step per token).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransformerConfig {
    /// Input values per time step (after feature filtering).
    pub inputs: usize,
    /// Time steps per window.
    pub seq_len: usize,
    pub layers: usize,
    pub heads: usize,
    pub d_model: usize,
    /// Width of the feed-forward blocks.
    pub d_ff: usize,
    /// Time steps per token.
    pub patch: usize,
    pub dropout: f64,
}

/// Named architectures: the paper's, and the cheaper one measured to give more accuracy per CPU-hour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Preset {
    /// 4 layers, 32 heads of width 4, 128 dims, a token per time step (the paper's best).
    Paper,
    /// 4 layers, 4 heads of width 32, 128 dims, 4 time steps per token: several times cheaper on CPU.
    Fast,
}

impl Preset {
    pub fn config(self, inputs: usize, seq_len: usize) -> TransformerConfig {
        let (heads, patch) = match self {
            Preset::Paper => (32, 1),
            Preset::Fast => (4, 4),
        };
        TransformerConfig { inputs, seq_len, layers: 4, heads, d_model: 128, d_ff: 512, patch, dropout: 0.1 }
    }
}

impl TransformerConfig {
    pub fn check(&self) -> Result<(), ConfigError> {
        let fail = |s: String| Err(ConfigError(s));
        if self.inputs == 0 || self.seq_len == 0 || self.layers == 0 || self.heads == 0 || self.patch == 0 {
            return fail("inputs, sequence length, layers, heads and patch must be positive".into());
        }
        if !self.d_model.is_multiple_of(self.heads) {
            return fail(format!("embedding size {} is not a multiple of the {} heads", self.d_model, self.heads));
        }
        if !self.seq_len.is_multiple_of(self.patch) {
            return fail(format!("sequence length {} is not a multiple of the patch {}", self.seq_len, self.patch));
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return fail(format!("dropout {} is not in [0, 1)", self.dropout));
        }
        Ok(())
    }

    /// Tokens per window on the time axis.
    pub fn tokens(&self) -> usize {
        self.seq_len / self.patch
    }

    pub fn init(&self, device: &Device) -> Result<Transformer, ConfigError> {
        self.check()?;
        let d = self.d_model;
        let encoder = |layers| Encoder::new(layers, d, self.heads, self.d_ff, device);
        let queries = Initializer::Normal { mean: 0.0, std: 0.02 }.init([1, JOINTS, d], device);
        Ok(Transformer {
            embed: LinearConfig::new(self.inputs * self.patch, d).init(device),
            position: PositionalEncodingConfig::new(d).with_max_sequence_size(self.tokens()).init(device),
            temporal: encoder(self.layers),
            temporal_norm: LayerNormConfig::new(d).init(device),
            joint_queries: queries,
            joint_attention: MultiHeadAttention::new(d, self.heads, device),
            joint_norm: LayerNormConfig::new(d).init(device),
            joints: encoder(1),
            head: LinearConfig::new(d, SLOTS).init(device),
            patch: self.patch,
            dropout: self.dropout,
        })
    }

    /// Trainable parameters; past what any machine holds, a number still (to refuse), not an overflow.
    pub fn parameters(&self) -> usize {
        let sizes = [self.d_model, self.d_ff, self.inputs, self.patch, self.layers];
        let [d, ff, inputs, patch, layers] = sizes.map(super::dimension);
        let (joints, slots) = (JOINTS as u128, SLOTS as u128);
        let layer = 4 * (d * d + d) + (d * ff + ff) + (ff * d + d) + 4 * d;
        let n = (inputs * patch * d + d)
            + layers * layer
            + 2 * d
            + joints * d
            + 4 * (d * d + d)
            + 2 * d
            + layer
            + (d * slots + slots);
        usize::try_from(n).unwrap_or(usize::MAX)
    }
}

#[derive(Module, Debug)]
pub struct Transformer {
    embed: Linear,
    position: PositionalEncoding,
    temporal: Encoder,
    temporal_norm: LayerNorm,
    joint_queries: Param<Tensor<3>>,
    joint_attention: MultiHeadAttention,
    joint_norm: LayerNorm,
    joints: Encoder,
    head: Linear,
    patch: usize,
    dropout: f64,
}

/// Where label `k` sits in the `JOINTS x SLOTS` output grid.
fn grid_index(k: usize) -> usize {
    let l = &LABELS[k];
    let (token, slot) = match l.kind {
        LabelKind::Coulomb => (l.index, 0),
        LabelKind::Viscous => (l.index, 1),
        LabelKind::Mass => (l.index - 1, 2),
        LabelKind::Com => (l.index - 1, 3),
        LabelKind::Ixx => (l.index - 1, 4),
        LabelKind::Iyy => (l.index - 1, 5),
        LabelKind::Izz => (l.index - 1, 6),
    };
    token * SLOTS + slot
}

impl Transformer {
    /// Standardised labels `[B, 38]` of standardised windows `[B, L, F]` (no dropout).
    pub fn forward(&self, x: Tensor<3>) -> Tensor<2> {
        self.run(x, &mut Noise::off())
    }

    /// As [`Transformer::forward`], with dropout masks drawn from `rng`: the training pass.
    pub fn forward_train(&self, x: Tensor<3>, rng: &mut Rng) -> Tensor<2> {
        self.run(x, &mut Noise::dropout(self.dropout, rng))
    }

    fn run(&self, x: Tensor<3>, noise: &mut Noise) -> Tensor<2> {
        let [batch, len, width] = x.dims();
        let device = x.device();
        let tokens = x.reshape([batch, len / self.patch, self.patch * width]);
        let h = self.position.forward(self.embed.forward(tokens));
        let h = self.temporal_norm.forward(self.temporal.forward(h, noise));
        let q = self.joint_queries.val().repeat_dim(0, batch);
        let attended = self.joint_attention.forward(q.clone(), h, noise);
        let j = self.joints.forward(self.joint_norm.forward(q + attended), noise);
        let grid = self.head.forward(j).reshape([batch, JOINTS * SLOTS]);
        let index: Vec<i64> = (0..NUM_LABELS).map(|k| grid_index(k) as i64).collect();
        grid.select(1, Tensor::<1, Int>::from_data(TensorData::new(index, [NUM_LABELS]), &device))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_label_has_its_own_output() {
        let mut seen: Vec<usize> = (0..NUM_LABELS).map(grid_index).collect();
        assert!(seen.iter().all(|&i| i < JOINTS * SLOTS));
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), NUM_LABELS);
    }

    #[test]
    fn bad_configurations_are_refused_with_the_reason() {
        let ok = Preset::Paper.config(90, 64);
        assert_eq!(ok.check(), Ok(()));
        let e = TransformerConfig { heads: 5, ..ok.clone() }.check().unwrap_err();
        assert!(e.to_string().contains("not a multiple of the 5 heads"), "{e}");
        let e = TransformerConfig { patch: 5, ..ok }.check().unwrap_err();
        assert!(e.to_string().contains("patch 5"), "{e}");
    }

    #[test]
    fn output_has_one_value_per_label_and_the_parameter_count_matches() {
        let device = Device::default();
        let cfg = TransformerConfig { layers: 1, heads: 4, d_model: 16, d_ff: 32, ..Preset::Fast.config(5, 8) };
        let model = cfg.init(&device).unwrap();
        let y = model.forward(Tensor::<3>::zeros([3, 8, 5], &device));
        assert_eq!(y.dims(), [3, NUM_LABELS]);
        assert_eq!(model.num_params(), cfg.parameters());
    }
}
