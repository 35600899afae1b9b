//! Dropout with its randomness passed in, not drawn from the backend.
//!
//! burn's `Dropout` draws its masks from one process-wide generator. When the micro-batches of a step run on
//! several threads, the order of those draws (and so the masks each thread gets) would follow thread timing; a
//! mask drawn from a stream keyed by (seed, step, micro-batch) is the same on every run and every machine.

use burn::tensor::{Tensor, TensorData};
use dynforge_robot::rng::Rng;

/// Where dropout masks come from during one forward pass; `Noise::off()` for evaluation.
pub struct Noise<'a> {
    rate: f64,
    rng: Option<&'a mut Rng>,
}

impl<'a> Noise<'a> {
    /// No dropout (evaluation, inference).
    pub fn off() -> Noise<'static> {
        Noise { rate: 0.0, rng: None }
    }

    /// Drop activations with probability `rate`, masks drawn from `rng`.
    pub fn dropout(rate: f64, rng: &'a mut Rng) -> Self {
        Noise { rate, rng: Some(rng) }
    }

    /// Inverted dropout: zero each value with probability `rate`, scale the rest by 1 / (1 - rate).
    pub fn apply<const D: usize>(&mut self, x: Tensor<D>) -> Tensor<D> {
        let Some(rng) = self.rng.as_deref_mut() else { return x };
        if self.rate <= 0.0 {
            return x;
        }
        let keep = 1.0 - self.rate;
        let scale = (1.0 / keep) as f32;
        let dims = x.dims();
        let n: usize = dims.iter().product();
        let mask: Vec<f32> = (0..n).map(|_| if rng.unit() < keep { scale } else { 0.0 }).collect();
        let mask = Tensor::<D>::from_data(TensorData::new(mask, dims), &x.device());
        x * mask
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Device;

    #[test]
    fn masks_follow_the_stream_and_keep_the_expectation() {
        let device = Device::default();
        let x = Tensor::<2>::ones([64, 256], &device);
        let draw = |seed| {
            let mut rng = Rng::stream(seed, &[]);
            Noise::dropout(0.25, &mut rng).apply(x.clone()).into_data().try_to_vec::<f32>().unwrap()
        };
        let (a, b, c) = (draw(1), draw(1), draw(2));
        assert_eq!(a, b, "same stream, same mask");
        assert_ne!(a, c, "another stream, another mask");
        // Each value is 0 or 1/0.75; the kept share is binomial(16384, 0.75): sd 0.0034, 5 sd = 0.017.
        let kept = a.iter().filter(|&&v| v != 0.0).count() as f64 / a.len() as f64;
        assert!((kept - 0.75).abs() < 0.017, "kept share {kept}");
        assert!(a.iter().all(|&v| v == 0.0 || (v - 1.0 / 0.75).abs() < 1e-6));
        assert_eq!(Noise::off().apply(x.clone()).into_data(), x.into_data());
    }
}
