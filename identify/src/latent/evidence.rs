//! The noise-weighted evidence about the prior's coordinates, and the Gaussian posterior it gives.

use nalgebra::{DMatrix, DVector};

use super::packed;
use crate::IdentifyError;

/// Noise-weighted evidence about a prior's coordinates `z`: the data's log-likelihood is `-(z^T H z - 2 b^T z) / 2`
/// up to a constant; `h` is `H`'s packed upper triangle.
#[derive(Debug, Clone, PartialEq)]
pub struct Evidence {
    pub rank: usize,
    pub h: Vec<f64>,
    pub b: Vec<f64>,
}

/// The Gaussian posterior of the prior's coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Posterior {
    pub mean: Vec<f64>,
    /// Diagonal of the posterior covariance (each at most 1, the prior's).
    pub variance: Vec<f64>,
    /// Correlations of the coordinates, the strict upper triangle row by row (`r (r - 1) / 2` values): which
    /// combinations of coordinates the data leave uncertain, beyond each one's variance.
    pub correlation: Vec<f64>,
}

impl Evidence {
    /// The evidence that data of this excitation (`h`, packed) would carry about a robot at coordinates `z`, were
    /// its torques exact: `b = H z`. How a generated robot that was never simulated is paired with a real window's
    /// excitation.
    pub fn noiseless(rank: usize, h: &[f64], z: &[f64]) -> Evidence {
        let hm = Self::unpack(rank, h);
        let b = (&hm * DVector::from_column_slice(z)).iter().copied().collect();
        Evidence { rank, h: h.to_vec(), b }
    }

    /// The evidence of the same data with white torque noise of `k` times the noise floor added to every sample, as
    /// an estimate that measured that noise weighs it: `b + k H^(1/2) xi` (exact for white noise: `b`'s noise term
    /// is `N(0, k^2 H)` in floor units), then both divided by the noise's variance `1 + k^2`. `xi`: `rank` standard
    /// normal values. How the estimator learns what a noisy log's posterior looks like without simulating one.
    pub fn with_noise(&self, k: f64, xi: &[f64]) -> Evidence {
        let eig = nalgebra::SymmetricEigen::new(Self::unpack(self.rank, &self.h));
        let root = DVector::from_fn(self.rank, |i, _| eig.eigenvalues[i].max(0.0).sqrt() * xi[i]);
        let d = &eig.eigenvectors * root;
        let w = 1.0 / (1.0 + k * k);
        Evidence {
            rank: self.rank,
            h: self.h.iter().map(|x| x * w).collect(),
            b: self.b.iter().zip(d.iter()).map(|(b, d)| (b + k * d) * w).collect(),
        }
    }

    /// Adds independent evidence (e.g. another recording's) about the same coordinates.
    pub fn add(&mut self, other: &Evidence) {
        self.h.iter_mut().zip(&other.h).for_each(|(x, y)| *x += y);
        self.b.iter_mut().zip(&other.b).for_each(|(x, y)| *x += y);
    }

    /// `H` from its packed upper triangle `h`.
    pub(super) fn unpack(r: usize, h: &[f64]) -> DMatrix<f64> {
        DMatrix::from_fn(r, r, |i, j| h[packed(r, i.min(j), i.max(j))])
    }

    /// Posterior under the prior `z ~ N(0, I)`: covariance `(I + H)^-1`, mean `(I + H)^-1 b`.
    pub fn posterior(&self) -> Result<Posterior, IdentifyError> {
        let r = self.rank;
        let m = DMatrix::identity(r, r) + Self::unpack(r, &self.h);
        let chol = m.cholesky().ok_or(IdentifyError::Decomposition)?;
        let mean = chol.solve(&DVector::from_column_slice(&self.b)).iter().copied().collect();
        let cov = chol.inverse();
        let variance: Vec<f64> = cov.diagonal().iter().copied().collect();
        let mut correlation = Vec::with_capacity(r * r.saturating_sub(1) / 2);
        for i in 0..r {
            for j in i + 1..r {
                correlation.push(cov[(i, j)] / (variance[i] * variance[j]).sqrt());
            }
        }
        Ok(Posterior { mean, variance, correlation })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::latent::packed_len;

    #[test]
    fn the_posterior_of_exact_evidence_approaches_the_truth_as_the_evidence_grows() {
        let r = 3;
        // H = s * diag(1, 4, 9) with off-diagonal coupling.
        let base = [1.0, 0.5, 0.0, 4.0, 1.0, 9.0];
        let z = [0.3, -1.2, 2.0];
        for s in [1.0, 1e3, 1e6] {
            let h: Vec<f64> = base.iter().map(|x| x * s).collect();
            let post = Evidence::noiseless(r, &h, &z).posterior().unwrap();
            // Shrinkage (I + H)^-1 H z differs from z by O(1 / s).
            for ((m, v), zk) in post.mean.iter().zip(&post.variance).zip(z) {
                assert!((m - zk).abs() < 5.0 / s, "s {s}: {:?}", post.mean);
                assert!(*v > 0.0 && *v <= 1.0);
            }
        }
        // No evidence: the prior itself.
        let none = Evidence { rank: r, h: vec![0.0; packed_len(r)], b: vec![0.0; r] }.posterior().unwrap();
        assert_eq!(none, Posterior { mean: vec![0.0; r], variance: vec![1.0; r], correlation: vec![0.0; 3] });
    }

    /// `with_noise` adds `k H^(1/2) xi`: over the unit vectors `xi = e_i` the outer products of what it adds sum to
    /// `k^2 H` (the covariance of white noise's term), and everything is divided by `1 + k^2`.
    #[test]
    fn noise_added_to_evidence_has_the_covariance_of_white_torque_noise() {
        let r = 3;
        let h = [4.0, 1.0, 0.5, 3.0, -0.2, 2.0];
        let e = Evidence::noiseless(r, &h, &[0.3, -1.2, 2.0]);
        let k = 7.0;
        let w = 1.0 / (1.0 + k * k);
        let quiet = e.with_noise(k, &[0.0; 3]);
        for (a, b) in quiet.h.iter().chain(&quiet.b).zip(e.h.iter().chain(&e.b)) {
            assert!((a - b * w).abs() <= 1e-15 * b.abs(), "{quiet:?}");
        }
        let mut sum = DMatrix::<f64>::zeros(r, r);
        for i in 0..r {
            let mut xi = [0.0; 3];
            xi[i] = 1.0;
            let d = DVector::from_iterator(r, e.with_noise(k, &xi).b.iter().zip(&quiet.b).map(|(a, b)| (a - b) / w));
            sum += &d * d.transpose();
        }
        let expected = Evidence::unpack(r, &h) * (k * k);
        assert!((sum - &expected).abs().max() <= 1e-12 * expected.abs().max(), "{expected}");
    }
}
