//! Multi-head attention and the pre-norm encoder layer, with dropout from an explicit [`Noise`] stream.
//!
//! Same computation and parameter names as burn's `MultiHeadAttention` and `TransformerEncoder` (so checkpoints
//! written with burn's modules load); only dropout differs: see [`super::noise`].

use burn::module::Module;
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::tensor::activation::{gelu, softmax};
use burn::tensor::{Device, Tensor};

use super::noise::Noise;

/// burn's transformer initialisation (Kaiming uniform with gain 1/sqrt(3)), so these modules train as burn's do.
fn linear(inputs: usize, outputs: usize, device: &Device) -> Linear {
    let init = Initializer::KaimingUniform { gain: 1.0 / 3f64.sqrt(), fan_out_only: false };
    LinearConfig::new(inputs, outputs).with_initializer(init).init(device)
}

#[derive(Module, Debug)]
pub struct MultiHeadAttention {
    query: Linear,
    key: Linear,
    value: Linear,
    output: Linear,
    heads: usize,
}

impl MultiHeadAttention {
    pub fn new(d_model: usize, heads: usize, device: &Device) -> Self {
        MultiHeadAttention {
            query: linear(d_model, d_model, device),
            key: linear(d_model, d_model, device),
            value: linear(d_model, d_model, device),
            output: linear(d_model, d_model, device),
            heads,
        }
    }

    /// Each of the `query` tokens `[B, Tq, d]` attends to the `memory` tokens `[B, Tk, d]`; dropout acts on the
    /// attention weights. Returns `[B, Tq, d]`.
    pub fn forward(&self, query: Tensor<3>, memory: Tensor<3>, noise: &mut Noise) -> Tensor<3> {
        let [batch, tokens, d] = query.dims();
        let width = d / self.heads;
        let split = |x: Tensor<3>, l: &Linear| {
            let [b, t, _] = x.dims();
            l.forward(x).reshape([b, t, self.heads, width]).swap_dims(1, 2)
        };
        let q = split(query, &self.query);
        let k = split(memory.clone(), &self.key);
        let v = split(memory, &self.value);
        let scores = q.matmul(k.transpose()).div_scalar((width as f32).sqrt());
        let weights = noise.apply(softmax(scores, 3));
        let context = weights.matmul(v).swap_dims(1, 2).reshape([batch, tokens, d]);
        self.output.forward(context)
    }
}

#[derive(Module, Debug)]
pub struct FeedForward {
    linear_inner: Linear,
    linear_outer: Linear,
}

/// Pre-norm layer: `x + drop(attn(norm_2 x))`, then `x + drop(ff(norm_1 x))` (burn's field names).
#[derive(Module, Debug)]
pub struct EncoderLayer {
    mha: MultiHeadAttention,
    pwff: FeedForward,
    norm_1: LayerNorm,
    norm_2: LayerNorm,
}

#[derive(Module, Debug)]
pub struct Encoder {
    layers: Vec<EncoderLayer>,
}

impl Encoder {
    pub fn new(layers: usize, d_model: usize, heads: usize, d_ff: usize, device: &Device) -> Self {
        let layer = || EncoderLayer {
            mha: MultiHeadAttention::new(d_model, heads, device),
            pwff: FeedForward {
                linear_inner: linear(d_model, d_ff, device),
                linear_outer: linear(d_ff, d_model, device),
            },
            norm_1: LayerNormConfig::new(d_model).init(device),
            norm_2: LayerNormConfig::new(d_model).init(device),
        };
        Encoder { layers: (0..layers).map(|_| layer()).collect() }
    }

    /// Self-attention over the tokens `[B, T, d]`.
    pub fn forward(&self, mut x: Tensor<3>, noise: &mut Noise) -> Tensor<3> {
        for l in &self.layers {
            let h = l.norm_2.forward(x.clone());
            let h = l.mha.forward(h.clone(), h, noise);
            x = x + noise.apply(h);
            let h = l.pwff.linear_inner.forward(l.norm_1.forward(x.clone()));
            let h = l.pwff.linear_outer.forward(noise.apply(gelu(h)));
            x = x + noise.apply(h);
        }
        x
    }
}
