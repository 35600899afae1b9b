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

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI};
use dynforge_recording::JointTrajectory;
use dynforge_robot::{Data, Model};
use nalgebra::{DMatrix, DVector};

use crate::IdentifyError;
use crate::samples::{PAIRED_NOISE_GAIN, REST_SPEED, for_each, row_support};
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

/// Index of `(i, j)`, `i <= j`, in a packed upper triangle of an `r x r` matrix.
fn packed(r: usize, i: usize, j: usize) -> usize {
    i * r - i * (i + 1) / 2 + j
}

/// Entries of a packed `r x r` triangle.
pub fn packed_len(r: usize) -> usize {
    r * (r + 1) / 2
}

/// One joint's sums over moving samples: `U^T U`, `U^T e`, `e^T e` with `U = Y_j L` and `e = tau_j - Y_j mu`, and
/// `sum tau^2`, `sum tau`, the count.
#[derive(Debug, Clone, PartialEq)]
struct JointSums {
    uu: Vec<f64>,
    ue: Vec<f64>,
    ee: f64,
    tt: f64,
    t: f64,
    n: usize,
}

/// What a stretch of samples contributes, per joint, in the coordinates of a [`ParameterPrior`]. Sums add: the
/// sums of a window are those of its blocks, a robot's those of its recordings.
#[derive(Debug, Clone, PartialEq)]
pub struct LatentSums {
    rank: usize,
    joints: Vec<JointSums>,
}

impl LatentSums {
    pub fn new(dof: usize, rank: usize) -> Self {
        let zero = JointSums { uu: vec![0.0; packed_len(rank)], ue: vec![0.0; rank], ee: 0.0, tt: 0.0, t: 0.0, n: 0 };
        LatentSums { rank, joints: vec![zero; dof] }
    }

    pub fn merge(&mut self, other: &LatentSums) {
        for (a, b) in self.joints.iter_mut().zip(&other.joints) {
            a.uu.iter_mut().zip(&b.uu).for_each(|(x, y)| *x += y);
            a.ue.iter_mut().zip(&b.ue).for_each(|(x, y)| *x += y);
            a.ee += b.ee;
            a.tt += b.tt;
            a.t += b.t;
            a.n += b.n;
        }
    }

    /// Torque rows summed (moving joint samples).
    pub fn rows(&self) -> usize {
        self.joints.iter().map(|j| j.n).sum()
    }

    /// The evidence about the prior's coordinates, with each joint's torque noise taken as `floor` times the RMS of
    /// its own recorded torque here: joints whose torques differ by orders of magnitude (a 330 N m shoulder, a 1 N m
    /// wrist) each count by their own scale, as a sensor's relative accuracy would have them.
    pub fn evidence(&self, floor: f64) -> Evidence {
        self.evidence_with_noise(floor, &vec![0.0; self.joints.len()])
    }

    /// [`Self::evidence`] with each joint's noise variance at least `variance[j]` [torque^2]: what a log's own
    /// residual says when its sensors are noisier than the floor (see [`Self::measured_noise`]).
    pub fn evidence_with_noise(&self, floor: f64, variance: &[f64]) -> Evidence {
        let r = self.rank;
        let mut e = Evidence { rank: r, h: vec![0.0; packed_len(r)], b: vec![0.0; r] };
        for (j, v) in self.joints.iter().zip(variance).filter(|(j, _)| j.n > 0 && j.tt > 0.0) {
            let w = 1.0 / (floor * floor * j.tt / j.n as f64).max(*v);
            e.h.iter_mut().zip(&j.uu).for_each(|(x, y)| *x += w * y);
            e.b.iter_mut().zip(&j.ue).for_each(|(x, y)| *x += w * y);
        }
        e
    }

    /// Each joint's effort noise variance as these samples show it: the mean squared residual of its paired torques
    /// at the posterior mean, times [`PAIRED_NOISE_GAIN`], the posterior weighted by the noise found so far (a few
    /// rounds from the floor; the residual is what neither the noise floor nor the prior's parameters explain:
    /// sensor noise, unmodelled dynamics). The evidence of a log that is noisier than the floor would otherwise be
    /// believed far beyond what it carries: with torque noise at 1e-3 of the RMS, per-robot R2 0.98 -> 0.88
    /// (`dynforge-bench-noise`).
    pub fn measured_noise(&self, floor: f64) -> Result<Vec<f64>, IdentifyError> {
        let mut variance = vec![0.0; self.joints.len()];
        for _ in 0..NOISE_ROUNDS {
            let z = DVector::from_vec(self.evidence_with_noise(floor, &variance).posterior()?.mean);
            for (v, j) in variance.iter_mut().zip(&self.joints).filter(|(_, j)| j.n > 0) {
                // |e - U z|^2 from the sums.
                let rss = j.ee - 2.0 * DVector::from_column_slice(&j.ue).dot(&z)
                    + z.dot(&(Evidence::unpack(self.rank, &j.uu) * &z));
                *v = PAIRED_NOISE_GAIN * (rss / j.n as f64).max(0.0);
            }
        }
        Ok(variance)
    }

    /// Each joint's torque standard deviation over these samples (0 where none moved): what an NRMSE is relative to.
    pub fn torque_std(&self) -> Vec<f64> {
        let std = |j: &JointSums| {
            let n = j.n as f64;
            (j.tt / n - (j.t / n).powi(2)).max(0.0).sqrt()
        };
        self.joints.iter().map(|j| if j.n > 0 { std(j) } else { 0.0 }).collect()
    }
}

/// Rounds of [`LatentSums::measured_noise`]: the residual at the floor's posterior is already the noise once that
/// dominates; two more rounds let the weights between joints settle.
const NOISE_ROUNDS: usize = 3;

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

    fn unpack(r: usize, h: &[f64]) -> DMatrix<f64> {
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

/// One pass over `traj` (a trajectory of `model` on a uniform grid): the [`LatentSums`] of each run of `block`
/// samples, `0..block`, `block..2 block`, ... (the last one shorter). A window's sums are those of the blocks its span
/// covers, so one pass serves every window of a recording whose bounds are multiples of `block`.
pub fn latent_blocks(
    model: &Model,
    prior: &ParameterPrior,
    traj: &JointTrajectory,
    block: usize,
) -> Result<Vec<LatentSums>, IdentifyError> {
    let n = model.dof();
    if traj.joints() != n || prior.mean.len() != NI * n + NF * n {
        return Err(IdentifyError::Dof(traj.joints().min(model.dof()), n));
    }
    let block = block.max(1);
    let r = prior.rank;
    let mut blocks = vec![LatentSums::new(n, r); traj.len().div_ceil(block)];
    let mut data = Data::new(model);
    let support = row_support(n);
    let mut u = vec![0.0; r];
    for_each(model, &mut data, traj, 0..traj.len(), |i, y, qd, tau| {
        let sums = &mut blocks[i / block];
        for j in 0..n {
            if qd[j].abs() < REST_SPEED {
                continue;
            }
            u.iter_mut().for_each(|x| *x = 0.0);
            let mut predicted = 0.0;
            for &c in &support[j] {
                let yc = y[(j, c)];
                predicted += yc * prior.mean[c];
                let row = &prior.factor[c * r..(c + 1) * r];
                u.iter_mut().zip(row).for_each(|(x, l)| *x += yc * l);
            }
            let e = tau[j] - predicted;
            let s = &mut sums.joints[j];
            let mut at = 0;
            for (a, &ua) in u.iter().enumerate() {
                for &ub in &u[a..] {
                    s.uu[at] += ua * ub;
                    at += 1;
                }
                s.ue[a] += ua * e;
            }
            s.ee += e * e;
            s.tt += tau[j] * tau[j];
            s.t += tau[j];
            s.n += 1;
        }
    });
    Ok(blocks)
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
