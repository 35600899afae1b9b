//! How well a motion identifies a robot: the information matrix `W = sum Y_s^T Y_s` of its torque regressor `Y`
//! (columns scaled to the robot's own parameter magnitudes, so a kilogram and a kilogram-square-metre weigh alike),
//! restricted to the combinations torques can determine at all (the base parameters, a subspace fixed by the
//! kinematics). D-optimality, the condition number and the covariance at a given torque noise are read from it.

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI, num_params};
use dynforge_robot::Model;
use dynforge_robot::parameters::dynamic_parameters;
use nalgebra::{DMatrix, DVector, SymmetricEigen};

/// Friction's scale as a share of the joint's effort limit (Coulomb) and of effort over speed limit (viscous).
const FRICTION_SCALE: f64 = 0.05;

/// Shortest length a link's moments are scaled by [m]: a point mass on the axis still has a size.
const MIN_LENGTH: f64 = 0.02;

/// The magnitude of each dynamic parameter of `model` ([`dynforge_proto::params`] layout): per link its mass `m`,
/// `m L` for the first moments and `m L^2` for the second, with `L` the larger of the COM's distance from the
/// joint and the radius of gyration; per joint a share of what its actuator can do for friction.
pub fn scales(model: &Model) -> Vec<f64> {
    let n = model.dof();
    let pi = dynamic_parameters(model);
    let mut s = vec![0.0; num_params(n)];
    for l in 0..n {
        let p = &pi[NI * l..NI * (l + 1)];
        let m = p[0].abs().max(1e-3);
        let com = (p[1].powi(2) + p[2].powi(2) + p[3].powi(2)).sqrt() / m;
        let gyration = ((p[4] + p[6] + p[9]).abs() / (2.0 * m)).sqrt();
        let length = com.max(gyration).max(MIN_LENGTH);
        s[NI * l] = m;
        s[NI * l + 1..NI * l + 4].fill(m * length);
        s[NI * l + 4..NI * (l + 1)].fill(m * length * length);
    }
    for (j, joint) in model.joints().iter().enumerate() {
        let at = NI * n + NF * j;
        s[at] = FRICTION_SCALE * joint.limits.effort;
        s[at + 1] = FRICTION_SCALE * joint.limits.effort / joint.limits.velocity.max(1e-3);
    }
    s
}

/// The identifiable subspace: orthonormal columns (scaled parameters) spanning the eigen-directions of a rich
/// motion's information above `RANK_TOLERANCE` of the largest. Structural: the same for almost every motion.
#[derive(Debug, Clone)]
pub struct Base {
    pub basis: DMatrix<f64>,
}

/// Eigenvalues below this fraction of the largest are the structural null space (rounding sits near 1e-16).
pub const RANK_TOLERANCE: f64 = 1e-10;

impl Base {
    pub fn of(w: &DMatrix<f64>) -> Self {
        let eig = SymmetricEigen::new(w.clone());
        let largest = eig.eigenvalues.amax();
        let keep: Vec<usize> = (0..w.nrows()).filter(|&k| eig.eigenvalues[k] > RANK_TOLERANCE * largest).collect();
        let basis = DMatrix::from_fn(w.nrows(), keep.len(), |r, c| eig.eigenvectors[(r, keep[c])]);
        Base { basis }
    }

    pub fn rank(&self) -> usize {
        self.basis.ncols()
    }

    /// `W` restricted to the base: `B^T W B`.
    pub fn restrict(&self, w: &DMatrix<f64>) -> DMatrix<f64> {
        self.basis.transpose() * w * &self.basis
    }
}

/// What an excitation's information says, on the base subspace.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Quality {
    /// Mean log eigenvalue (D-optimality per dimension; larger is better).
    pub log_det: f64,
    /// Largest over smallest eigenvalue's square root: the scaled regressor's condition number.
    pub condition: f64,
    /// Trace of the base covariance (scaled parameters) at the torque noise the information was weighted by.
    pub trace: f64,
}

impl Quality {
    pub fn of(base: &Base, w: &DMatrix<f64>) -> Self {
        let eig = SymmetricEigen::new(base.restrict(w)).eigenvalues;
        let (lo, hi) = (eig.min().max(f64::MIN_POSITIVE), eig.max());
        Quality {
            log_det: eig.iter().map(|&e| e.max(f64::MIN_POSITIVE).ln()).sum::<f64>() / eig.len().max(1) as f64,
            condition: (hi / lo).sqrt(),
            trace: eig.iter().map(|&e| 1.0 / e.max(f64::MIN_POSITIVE)).sum(),
        }
    }
}

/// Per parameter ([`dynforge_proto::params`] layout, in its units), the standard deviation of its identifiable part
/// estimated by least squares from torques with the white noise `W` was weighted by: the scale times the root of the
/// diagonal of `B (B^T W B)^-1 B^T`. Zero where the torques see nothing of it.
pub fn expected_std(base: &Base, w: &DMatrix<f64>, scales: &[f64]) -> Vec<f64> {
    let restricted = base.restrict(w);
    let inverse = restricted.clone().try_inverse().unwrap_or_else(|| DMatrix::zeros(base.rank(), base.rank()));
    let cov = &base.basis * inverse * base.basis.transpose();
    (0..scales.len()).map(|k| scales[k] * cov[(k, k)].max(0.0).sqrt()).collect()
}

/// Sums `W = sum (N^-1 Y S)^T (N^-1 Y S)` over samples' regressors `Y`: columns scaled by `S`, each joint's row
/// divided by its torque noise `N` (weighted least squares' information, as the classical design tools weigh it: a
/// noisy joint's torques tell less). Rows are gathered in blocks and each block added by one matrix product: per
/// sample the product is too small to run fast, and it took half of a design's time.
pub struct Information {
    scales: DVector<f64>,
    /// Per joint the inverse of its noise.
    weights: Vec<f64>,
    rows: DMatrix<f64>,
    filled: usize,
    w: DMatrix<f64>,
}

/// Samples gathered per block.
const BLOCK: usize = 64;

impl Information {
    /// A sum for these scales and per joint noise [N m or N].
    pub fn new(scales: &DVector<f64>, noise: &[f64]) -> Self {
        let p = scales.len();
        Information {
            scales: scales.clone(),
            weights: noise.iter().map(|s| 1.0 / s).collect(),
            rows: DMatrix::zeros(BLOCK * noise.len(), p),
            filled: 0,
            w: DMatrix::zeros(p, p),
        }
    }

    /// Adds one sample's regressor.
    pub fn add(&mut self, y: &DMatrix<f64>) {
        let r = y.nrows();
        for c in 0..y.ncols() {
            for k in 0..r {
                self.rows[(self.filled + k, c)] = y[(k, c)] * self.scales[c] * self.weights[k];
            }
        }
        self.filled += r;
        if self.filled == self.rows.nrows() {
            self.flush();
        }
    }

    fn flush(&mut self) {
        let rows = self.rows.rows(0, self.filled);
        self.w.gemm(1.0, &rows.transpose(), &rows, 1.0);
        self.filled = 0;
    }

    /// The sum.
    pub fn finish(mut self) -> DMatrix<f64> {
        self.flush();
        self.w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blocked sum is the per-sample sum of the weighted rows, across a block's end (rounding apart: relative
    /// 1e-13 is a few hundred ulps for sums of 150 products of numbers of order one).
    #[test]
    fn the_blocked_sum_is_the_sum_of_each_samples_weighted_rows() {
        let scales = DVector::from_fn(5, |i, _| 0.5 + i as f64);
        let noise = [0.5, 4.0];
        let mut blocked = Information::new(&scales, &noise);
        let mut plain = DMatrix::<f64>::zeros(5, 5);
        for k in 0..150 {
            let y = DMatrix::from_fn(2, 5, |r, c| ((k * 7 + r * 3 + c * 11) % 17) as f64 / 17.0 - 0.4);
            let ys = DMatrix::from_fn(2, 5, |r, c| y[(r, c)] * scales[c] / noise[r]);
            plain += ys.transpose() * &ys;
            blocked.add(&y);
        }
        let blocked = blocked.finish();
        assert!((blocked - &plain).amax() < 1e-13 * plain.amax(), "{plain}");
    }
}
