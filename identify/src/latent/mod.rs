//! Identification against a prior over the full parameter vector: what a stretch of samples says about the prior's
//! coordinates, and the Gaussian posterior it gives.
//!
//! A family of robots (the generator's, for one) spans a low-dimensional affine subspace of the `12 n` parameters:
//! the generated 6R arms, 72 parameters, lie in 30 dimensions (per link the first moment along the link axis and two
//! second moments, the mass following from them; per joint two friction coefficients). [`ParameterPrior`] holds the
//! family's mean `mu` and a factor `L` of its covariance, so `pi = mu + L z` with `z ~ N(0, I)`. Torques are linear
//! in `pi`, hence in `z`: `tau - Y mu = (Y L) z`. A stretch of samples reduces to `r x r` sums ([`LatentSums`]),
//! the noise model turns them into [`Evidence`], and the posterior of `z` is exact linear-Gaussian algebra. Because
//! every direction has the prior's unit variance to fall back on, weakly excited directions (a 4 s window excites
//! few) shrink to the family's mean instead of extrapolating, and directions no torque sees keep the prior.
//!
//! One file per step: `prior.rs` ([`ParameterPrior`]), `sums.rs` ([`LatentSums`] and [`latent_blocks`], which
//! computes them), `evidence.rs` ([`Evidence`] and its [`Posterior`]). The packed upper triangles below are the
//! layout the sums and the evidence share.

mod evidence;
mod prior;
mod sums;

pub use evidence::{Evidence, Posterior};
pub use prior::ParameterPrior;
pub use sums::{BatchScatter, LatentSums, batch_scatter, latent_blocks};

/// Index of `(i, j)`, `i <= j`, in a packed upper triangle of an `r x r` matrix.
fn packed(r: usize, i: usize, j: usize) -> usize {
    i * r - i * (i + 1) / 2 + j
}

/// Entries of a packed `r x r` triangle.
pub fn packed_len(r: usize) -> usize {
    r * (r + 1) / 2
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packed_indices_enumerate_the_upper_triangle_in_row_order() {
        for r in [1, 2, 5, 30] {
            let mut at = 0;
            for i in 0..r {
                for j in i..r {
                    assert_eq!(packed(r, i, j), at, "r {r} ({i}, {j})");
                    at += 1;
                }
            }
            assert_eq!(at, packed_len(r));
        }
    }
}
