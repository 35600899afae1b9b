//! What a stretch of samples says about the prior's coordinates: per-joint sums in those coordinates.

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI};
use dynforge_recording::JointTrajectory;
use dynforge_robot::{Data, Model};
use nalgebra::{DMatrix, DVector};

use super::{Evidence, ParameterPrior, packed_len};
use crate::IdentifyError;
use crate::samples::{PAIRED_NOISE_GAIN, REST_SPEED, for_each, row_support};

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

    /// The sums of `parts` (each of `dof` joints and `rank` coordinates): a window's of its blocks, a log's of its
    /// batches.
    pub fn sum(dof: usize, rank: usize, parts: &[LatentSums]) -> Self {
        let mut s = LatentSums::new(dof, rank);
        parts.iter().for_each(|p| s.merge(p));
        s
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
        for (j, w) in self.joints.iter().zip(self.weights(floor, variance)).filter(|(_, w)| *w > 0.0) {
            e.h.iter_mut().zip(&j.uu).for_each(|(x, y)| *x += w * y);
            e.b.iter_mut().zip(&j.ue).for_each(|(x, y)| *x += w * y);
        }
        e
    }

    /// Each joint's weight in [`Self::evidence_with_noise`]: one over its noise variance, the larger of `floor` times
    /// its torque's RMS, squared, and `variance[j]`; 0 for a joint that never moved or carried no torque.
    fn weights(&self, floor: f64, variance: &[f64]) -> Vec<f64> {
        self.joints
            .iter()
            .zip(variance)
            .map(|(j, v)| match j.n > 0 && j.tt > 0.0 {
                true => 1.0 / (floor * floor * j.tt / j.n as f64).max(*v),
                false => 0.0,
            })
            .collect()
    }

    /// Each joint's effort noise variance as these samples show it: the mean squared residual of its paired torques
    /// at the posterior mean, times [`PAIRED_NOISE_GAIN`], the posterior weighted by the noise found so far (a few
    /// rounds from the floor; the residual is what neither the noise floor nor the prior's parameters explain:
    /// sensor noise, unmodelled dynamics). The evidence of a log that is noisier than the floor would otherwise be
    /// believed far beyond what it carries, which ruins the estimate of a noisy log (`dynforge-bench-noise`; figures
    /// in `docs/measurements.md`).
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
    if traj.joints() != n || prior.mean().len() != NI * n + NF * n {
        return Err(IdentifyError::Dof(traj.joints().min(model.dof()), n));
    }
    let block = block.max(1);
    let r = prior.rank();
    let (mean, factor) = (prior.mean(), prior.factor());
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
                predicted += yc * mean[c];
                let row = &factor[c * r..(c + 1) * r];
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

/// How the evidence's scores scatter between consecutive batches of samples against what the noise it assumed would
/// make of them (batch means): `observed = sum_k s_k^T P^-1 s_k` over each batch's score `s_k` at the posterior
/// mean, and `expected = sum_k tr(P^-1 (H_k - H_k P^-1 H_k))`, white noise at the assumed weights after the fit, with
/// `P = I + H` the posterior precision (so directions the prior decides count little). Sums add over logs.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BatchScatter {
    pub observed: f64,
    pub expected: f64,
}

impl BatchScatter {
    pub fn add(&mut self, other: &BatchScatter) {
        self.observed += other.observed;
        self.expected += other.expected;
    }

    /// `observed / expected`: about 1 for white noise at the assumed level, under 1 for a residual under the floor
    /// (a simulated log's), and above what the residual's power alone gives where it is coherent over many samples
    /// (a model error smooth in time), whose evidence is then worth fewer independent samples than it counts. The
    /// posterior's variance times this is the sandwich (robust) variance along the directions the data decide.
    pub fn ratio(&self) -> f64 {
        if self.expected > 0.0 { self.observed / self.expected } else { 1.0 }
    }
}

/// The [`BatchScatter`] of `batches` (consecutive, each longer than the noise's correlation), weighted as
/// [`LatentSums::evidence_with_noise`] weighs their sum.
pub fn batch_scatter(batches: &[LatentSums], floor: f64, variance: &[f64]) -> Result<BatchScatter, IdentifyError> {
    let Some(first) = batches.first() else { return Ok(BatchScatter::default()) };
    let r = first.rank;
    let total = LatentSums::sum(first.joints.len(), r, batches);
    let e = total.evidence_with_noise(floor, variance);
    let weights = total.weights(floor, variance);
    // The posterior's mean and `P^-1` from one factorization, as `Evidence::posterior` computes them.
    let p = (DMatrix::identity(r, r) + Evidence::unpack(r, &e.h)).cholesky().ok_or(IdentifyError::Decomposition)?;
    let z = p.solve(&DVector::from_column_slice(&e.b));
    let p_inv = p.inverse();
    let mut scatter = BatchScatter::default();
    for batch in batches {
        let mut h = DMatrix::zeros(r, r);
        let mut s = DVector::zeros(r);
        for (j, w) in batch.joints.iter().zip(&weights).filter(|(_, w)| **w > 0.0) {
            let uu = Evidence::unpack(r, &j.uu);
            s += (DVector::from_column_slice(&j.ue) - &uu * &z) * *w;
            h += uu * *w;
        }
        scatter.observed += (&p_inv * &s).dot(&s);
        scatter.expected += (&p_inv * (&h - &h * &p_inv * &h)).trace();
    }
    Ok(scatter)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynforge_robot::rng::Rng;

    /// Batches of `per_batch` samples of one joint whose rows are `u_t = (1, sin(t / 200), cos(t / 350))` (smooth,
    /// as a regressor along a trajectory is) and whose torques are `u_t . z + noise_t`, the noise assumed white with
    /// variance 1 (floor 1, torque power `n`).
    fn batches(noise: &[f64], per_batch: usize) -> Vec<LatentSums> {
        let z = [0.5, -1.0, 2.0];
        let mut out = Vec::new();
        for chunk in noise.chunks(per_batch).enumerate().map(|(k, c)| (k * per_batch, c)) {
            let mut s = LatentSums::new(1, 3);
            let j = &mut s.joints[0];
            for (i, e) in chunk.1.iter().enumerate() {
                let t = (chunk.0 + i) as f64;
                let u = [1.0, (t / 200.0).sin(), (t / 350.0).cos()];
                let e = u.iter().zip(&z).map(|(a, b)| a * b).sum::<f64>() + e;
                let mut at = 0;
                for a in 0..3 {
                    for b in a..3 {
                        j.uu[at] += u[a] * u[b];
                        at += 1;
                    }
                    j.ue[a] += u[a] * e;
                }
                j.ee += e * e;
                j.tt += 1.0;
                j.n += 1;
            }
            out.push(s);
        }
        out
    }

    /// White noise at the assumed level scatters the batches' scores as the evidence assumes (the estimate's own
    /// sampling error over 3 directions x 200 batches is ~6 %); a tenth of it scatters them a hundredth as much; the
    /// same power correlated over ~100 samples (AR(1), phi 0.99, a smooth model error) scatters them by its long-run
    /// variance, `(1 + phi) / (1 - phi) = 199` times the white noise's, less what the fit absorbs.
    #[test]
    fn batch_scores_scatter_as_the_noise_is_white_or_coherent() {
        let n = 200 * 256;
        let mut rng = Rng::stream(7, &[1]);
        let white: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let k = batch_scatter(&batches(&white, 256), 1.0, &[0.0]).unwrap().ratio();
        assert!((k - 1.0).abs() < 0.25, "white noise at the assumed level: {k}");
        let tenth: Vec<f64> = white.iter().map(|e| 0.1 * e).collect();
        let k = batch_scatter(&batches(&tenth, 256), 1.0, &[0.0]).unwrap().ratio();
        assert!((k - 0.01).abs() < 0.0025, "a tenth of it: {k}");
        let phi: f64 = 0.99;
        let mut x = 0.0;
        let coherent: Vec<f64> = white
            .iter()
            .map(|e| {
                x = phi * x + (1.0 - phi * phi).sqrt() * e;
                x
            })
            .collect();
        let k = batch_scatter(&batches(&coherent, 256), 1.0, &[0.0]).unwrap().ratio();
        assert!(k > 50.0 && k < 400.0, "coherent noise of the same power: {k}");
    }
}
