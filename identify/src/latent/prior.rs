//! The prior: a family of robots as the mean and a low-rank factor of its parameters' covariance.

use nalgebra::{DMatrix, DVector};

use crate::IdentifyError;
use crate::solve::eigen;

/// Principal directions of the prior's (standardised) covariance below this fraction of the largest variance are
/// dropped: the generator's 30 directions have standardised variances above 6e-2 of the largest, its structural zeros
/// are at rounding level (1e-16).
pub const PRIOR_RANK_TOLERANCE: f64 = 1e-9;

/// A Gaussian prior over the full parameter vector, of low rank: `pi = mean + factor z`, `z ~ N(0, I)`.
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterPrior {
    mean: Vec<f64>,
    /// `p x r`, row-major: row `c` holds parameter `c`'s loading on each coordinate.
    factor: Vec<f64>,
    rank: usize,
}

impl ParameterPrior {
    /// The mean and principal directions of `samples` (parameter vectors of one layout, e.g. generated robots').
    /// Each parameter is standardised by its own spread before the eigen-decomposition, so that kilograms and
    /// kilogram square metres weigh alike; constant parameters (zero spread) stay at their mean.
    pub fn fit(samples: &[Vec<f64>]) -> Result<Self, IdentifyError> {
        let p = samples.first().map_or(0, Vec::len);
        if samples.len() < 2 || samples.iter().any(|s| s.len() != p) {
            return Err(IdentifyError::PriorSamples(samples.len()));
        }
        let n = samples.len() as f64;
        let mean: Vec<f64> = (0..p).map(|c| samples.iter().map(|s| s[c]).sum::<f64>() / n).collect();
        let mut cov = DMatrix::<f64>::zeros(p, p);
        for s in samples {
            let d = DVector::from_iterator(p, s.iter().zip(&mean).map(|(x, m)| x - m));
            cov.syger(1.0, &d, &d, 1.0);
        }
        cov.fill_upper_triangle_with_lower_triangle();
        cov /= n;
        let sd: Vec<f64> = (0..p).map(|c| cov[(c, c)].max(0.0).sqrt()).collect();
        let scale = sd.iter().fold(0.0f64, |a, &b| a.max(b));
        let sd: Vec<f64> = sd.iter().map(|&s| if s > 1e-12 * scale { s } else { 0.0 }).collect();
        let corr =
            DMatrix::from_fn(p, p, |i, j| if sd[i] > 0.0 && sd[j] > 0.0 { cov[(i, j)] / (sd[i] * sd[j]) } else { 0.0 });
        let (u, lam) = eigen(&corr)?;
        let largest = lam.iter().fold(0.0f64, |a, &b| a.max(b));
        let keep: Vec<usize> = (0..p).filter(|&k| lam[k] > PRIOR_RANK_TOLERANCE * largest).collect();
        let rank = keep.len();
        let mut factor = vec![0.0; p * rank];
        for c in 0..p {
            for (k, &e) in keep.iter().enumerate() {
                factor[c * rank + k] = sd[c] * u[(c, e)] * lam[e].sqrt();
            }
        }
        Ok(ParameterPrior { mean, factor, rank })
    }

    /// Coordinates of the prior (dimensions of the family).
    pub fn rank(&self) -> usize {
        self.rank
    }

    pub fn mean(&self) -> &[f64] {
        &self.mean
    }

    /// `L`, row-major (`parameters x rank`).
    pub fn factor(&self) -> &[f64] {
        &self.factor
    }

    /// A prior from its mean and row-major factor (as [`Self::mean`] and [`Self::factor`] give them), e.g. read back
    /// from a checkpoint; `None` if the sizes disagree or a value is not finite.
    pub fn from_parts(mean: Vec<f64>, factor: Vec<f64>) -> Option<Self> {
        let p = mean.len();
        let rank = factor.len().checked_div(p)?;
        (rank * p == factor.len() && mean.iter().chain(&factor).all(|v| v.is_finite())).then_some(ParameterPrior {
            mean,
            factor,
            rank,
        })
    }

    /// The parameter vector at coordinates `z`: `mean + L z`.
    pub fn parameters(&self, z: &[f64]) -> Vec<f64> {
        let r = self.rank;
        (0..self.mean.len())
            .map(|c| self.mean[c] + (0..r).map(|k| self.factor[c * r + k] * z[k]).sum::<f64>())
            .collect()
    }

    /// The coordinates whose parameters are closest to `pi` (least squares; exact for a member of the family).
    pub fn coordinates(&self, pi: &[f64]) -> Vec<f64> {
        let (p, r) = (self.mean.len(), self.rank);
        let l = DMatrix::from_row_slice(p, r, &self.factor);
        let d = DVector::from_iterator(p, pi.iter().zip(&self.mean).map(|(x, m)| x - m));
        let ltl = l.transpose() * &l;
        let rhs = l.transpose() * d;
        match ltl.cholesky() {
            Some(c) => c.solve(&rhs).iter().copied().collect(),
            None => vec![0.0; r],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_prior_fitted_to_a_plane_has_rank_two_and_recovers_its_points() {
        // Points pi = m + a u + b v in 4 dimensions, with wildly different units per coordinate.
        let (u, v) = ([1.0, 0.0, 1e-4, 3.0], [0.0, 2.0, -1e-4, 0.0]);
        let samples: Vec<Vec<f64>> = (0..200)
            .map(|k| {
                let (a, b) = ((k as f64 * 0.37).sin(), (k as f64 * 0.91).cos());
                (0..4).map(|c| [5.0, -1.0, 1e-3, 2.0][c] + a * u[c] + b * v[c]).collect()
            })
            .collect();
        let prior = ParameterPrior::fit(&samples).unwrap();
        assert_eq!(prior.rank(), 2);
        for s in &samples[..5] {
            let back = prior.parameters(&prior.coordinates(s));
            for (x, y) in back.iter().zip(s) {
                assert!((x - y).abs() <= 1e-12 * y.abs().max(1e-3), "{back:?} vs {s:?}");
            }
        }
    }
}
