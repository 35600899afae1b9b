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
        self.sandwich(1.0)
    }

    /// The posterior's mean with the covariance of its error when the data's score has `scatter` times the
    /// covariance the weights assumed (`BatchScatter::ratio`): `P^-1 (I + scatter H) P^-1`, `P = I + H`, over robots
    /// drawn from the prior. At 1 the posterior's own. Below 1 (a residual under the assumed floor) only the
    /// directions the data decide narrow; the shrinkage toward the prior stays in those they leave to it.
    pub fn sandwich(&self, scatter: f64) -> Result<Posterior, IdentifyError> {
        let r = self.rank;
        let hm = Self::unpack(r, &self.h);
        let chol = (DMatrix::identity(r, r) + &hm).cholesky().ok_or(IdentifyError::Decomposition)?;
        let mean = chol.solve(&DVector::from_column_slice(&self.b)).iter().copied().collect();
        let p_inv = chol.inverse();
        let cov = match scatter == 1.0 {
            true => p_inv,
            false => &p_inv * (DMatrix::identity(r, r) + hm * scatter) * &p_inv,
        };
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

impl Posterior {
    /// The covariance of the coordinates, from their variances and correlations.
    pub fn covariance(&self) -> DMatrix<f64> {
        let r = self.mean.len();
        let sd = |i: usize| self.variance[i].sqrt();
        DMatrix::from_fn(r, r, |i, j| match i.cmp(&j) {
            std::cmp::Ordering::Equal => self.variance[i],
            std::cmp::Ordering::Less => self.correlation[packed(r, i, j) - i - 1] * sd(i) * sd(j),
            std::cmp::Ordering::Greater => self.correlation[packed(r, j, i) - j - 1] * sd(i) * sd(j),
        })
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

    /// With `H` diagonal each coordinate's error is closed form: variance `(1 + k h_i) / (1 + h_i)^2`
    /// (shrinkage toward the prior plus the score's noise at `k` times the assumed). A direction the data barely see
    /// keeps nearly the prior's variance at any `k`; one they decide narrows as `k` does.
    #[test]
    fn the_sandwich_keeps_the_priors_share_and_scales_the_datas() {
        let r = 3;
        let (hd, z) = ([1e-2, 1.0, 1e4], [0.3, -1.2, 2.0]);
        let h = [hd[0], 0.0, 0.0, hd[1], 0.0, hd[2]];
        let e = Evidence::noiseless(r, &h, &z);
        assert_eq!(e.sandwich(1.0).unwrap(), e.posterior().unwrap());
        for k in [1e-3, 0.1, 1.0, 30.0] {
            let s = e.sandwich(k).unwrap();
            assert_eq!(s.mean, e.posterior().unwrap().mean);
            for (v, h) in s.variance.iter().zip(hd) {
                let expected = (1.0 + k * h) / (1.0 + h).powi(2);
                assert!((v - expected).abs() <= 1e-12 * expected, "k {k}, h {h}: {v} against {expected}");
            }
            assert!(s.correlation.iter().all(|c| c.abs() < 1e-12), "{:?}", s.correlation);
        }
    }

    /// The covariance read back from the variances and correlations is the posterior's `(I + H)^-1`.
    #[test]
    fn a_posteriors_covariance_is_the_inverse_of_its_precision() {
        let r = 3;
        let h = [4.0, 1.0, 0.5, 3.0, -0.2, 2.0];
        let post = Evidence::noiseless(r, &h, &[0.3, -1.2, 2.0]).posterior().unwrap();
        let want = (DMatrix::identity(r, r) + Evidence::unpack(r, &h)).try_inverse().unwrap();
        let got = post.covariance();
        assert!((&got - &want).abs().max() <= 1e-14, "{got} against {want}");
        assert_eq!(got, got.transpose());
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
