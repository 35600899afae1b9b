//! Normal equations of the regressor, per joint, accumulated over recordings.

use dynforge_proto::params::num_params;
use dynforge_robot::{Data, Model};
use nalgebra::{DMatrix, DVector};

use crate::IdentifyError;
use dynforge_recording::JointTrajectory;
use dynforge_robot::drive::{DRIVE_PER_JOINT, drive_index, identified_len};

use crate::samples::{REST_SPEED, for_each, row_support};

/// `sum y y^T`, `sum y tau`, `sum tau^2`, `sum tau` and the count over the moving samples of one joint, where `y`
/// is that joint's row of the regressor. Kept per joint so that a parameter set's torque error can be normalised by
/// each joint's own torque spread (the torque check), and summed for identification.
///
/// Sums of squares lose precision to cancellation only at `1e-16` of the torque's mean square: far below the
/// residuals of interest (the true parameters leave ~2e-4 of the torque's spread on simulated data).
#[derive(Debug, Clone)]
pub struct NormalEquations {
    pub(crate) dof: usize,
    /// Columns of the regressor: the robot's parameters, and the drives' when identified with them.
    pub(crate) p: usize,
    pub(crate) a: Vec<DMatrix<f64>>,
    pub(crate) b: Vec<DVector<f64>>,
    pub(crate) c: Vec<f64>,
    pub(crate) sum: Vec<f64>,
    pub(crate) n: Vec<usize>,
}

impl NormalEquations {
    /// Empty sums for a `dof`-joint robot's parameters (`dynforge_proto::params`).
    pub fn new(dof: usize) -> Self {
        Self::with_columns(dof, num_params(dof))
    }

    /// Empty sums for a `dof`-joint robot's parameters and its drives' ([`crate::drive`]).
    pub fn with_drives(dof: usize) -> Self {
        Self::with_columns(dof, identified_len(dof))
    }

    fn with_columns(dof: usize, p: usize) -> Self {
        NormalEquations {
            dof,
            p,
            a: vec![DMatrix::zeros(p, p); dof],
            b: vec![DVector::zeros(p); dof],
            c: vec![0.0; dof],
            sum: vec![0.0; dof],
            n: vec![0; dof],
        }
    }

    /// Adds the moving samples of `traj`, a trajectory of `model`'s joints on a uniform grid (only the model's
    /// kinematics are used).
    pub fn add(&mut self, model: &Model, traj: &JointTrajectory) -> Result<(), IdentifyError> {
        self.add_range(model, traj, 0..traj.len())
    }

    /// Adds the moving samples `range` of `traj` (e.g. a window's).
    pub fn add_range(
        &mut self,
        model: &Model,
        traj: &JointTrajectory,
        range: std::ops::Range<usize>,
    ) -> Result<(), IdentifyError> {
        let n = self.dof;
        if model.dof() != n || traj.joints() != n {
            return Err(IdentifyError::Dof(traj.joints().min(model.dof()), n));
        }
        let mut data = Data::new(model);
        let mut rows = BlockedRows::new(n, 1, false);
        for_each(model, &mut data, traj, range, |_, y, qd, tau| {
            for j in (0..n).filter(|&j| qd[j].abs() >= REST_SPEED) {
                rows.push(j, y, &tau[j..=j]);
            }
        });
        self.merge(&rows.finish()[0]);
        Ok(())
    }

    /// The normal equations of `traj` alone.
    pub fn of(model: &Model, traj: &JointTrajectory) -> Result<Self, IdentifyError> {
        let mut ne = NormalEquations::new(model.dof());
        ne.add(model, traj)?;
        Ok(ne)
    }

    /// Adds another set of sums (of the same robot).
    pub fn merge(&mut self, other: &NormalEquations) {
        for j in 0..self.dof.min(other.dof) {
            self.a[j] += &other.a[j];
            self.b[j] += &other.b[j];
            self.c[j] += other.c[j];
            self.sum[j] += other.sum[j];
            self.n[j] += other.n[j];
        }
    }

    pub fn dof(&self) -> usize {
        self.dof
    }

    /// Columns of the regressor summed: [`num_params`], or [`identified_len`] with the drives.
    pub fn columns(&self) -> usize {
        self.p
    }

    /// `pi` as a vector of every column: a robot's parameters alone (a URDF's) have no drive terms.
    pub(crate) fn padded(&self, pi: &[f64]) -> DVector<f64> {
        assert!(pi.len() <= self.p, "{} parameters for {} columns", pi.len(), self.p);
        DVector::from_fn(self.p, |k, _| pi.get(k).copied().unwrap_or(0.0))
    }

    /// Torque rows (moving joint samples) summed.
    pub fn rows(&self) -> usize {
        self.n.iter().sum()
    }

    /// `(Y^T Y, Y^T tau, tau^T tau)` over all joints.
    pub fn gram(&self) -> (DMatrix<f64>, DVector<f64>, f64) {
        let p = self.p;
        let mut a = DMatrix::zeros(p, p);
        let mut b = DVector::zeros(p);
        for j in 0..self.dof {
            a += &self.a[j];
            b += &self.b[j];
        }
        (a, b, self.c.iter().sum())
    }

    /// Joint `j`'s sums: `(Y_j^T Y_j, Y_j^T tau_j, tau_j^T tau_j, rows)`.
    pub fn joint(&self, j: usize) -> (&DMatrix<f64>, &DVector<f64>, f64, usize) {
        (&self.a[j], &self.b[j], self.c[j], self.n[j])
    }

    /// Residual sum of squares of `pi`'s torques on joint `j` (0 when it never moved).
    fn rss_joint(&self, j: usize, pi: &DVector<f64>) -> f64 {
        let quad = pi.dot(&(&self.a[j] * pi));
        (quad - 2.0 * self.b[j].dot(pi) + self.c[j]).max(0.0)
    }

    /// Residual sum of squares of the torques predicted by `pi` (layout of `dynforge_proto::params`, then the
    /// drives' if these sums have them).
    pub fn rss(&self, pi: &[f64]) -> f64 {
        let pi = self.padded(pi);
        (0..self.dof).map(|j| self.rss_joint(j, &pi)).sum()
    }

    /// Per joint: RMS torque error of `pi` over the standard deviation of the recorded torque (NaN for a joint
    /// that never moved).
    pub fn nrmse(&self, pi: &[f64]) -> Vec<f64> {
        let mut e = TorqueError::default();
        e.add(self, pi);
        e.per_joint()
    }

    /// Mean of [`Self::nrmse`] over the joints that moved.
    pub fn mean_nrmse(&self, pi: &[f64]) -> f64 {
        let mut e = TorqueError::default();
        e.add(self, pi);
        e.overall()
    }

    /// RMS torque error of `pi` over the RMS spread of the recorded torque, both over every joint's rows together:
    /// the joints that carry the large torques weigh most (where [`Self::mean_nrmse`] weighs a wrist's small
    /// torque as much as a shoulder's).
    pub fn pooled_nrmse(&self, pi: &[f64]) -> f64 {
        let mut e = TorqueError::default();
        e.add(self, pi);
        e.pooled()
    }
}

/// Rows of the regressor gathered per joint in blocks of [`BLOCK`], so that a block's Gram matrix is one matrix
/// product (a vectorised kernel) rather than a rank-one update per row; `k` right-hand sides (the effort
/// conventions) share the rows. Each joint's row is non-zero only on its `support` (links `j..` and its friction),
/// so the blocks are that narrow and are scattered into the full normal equations at the end. With `drives`, the rows
/// have the drives' columns too (joint `j`'s row only joint `j`'s).
pub(crate) struct BlockedRows {
    support: Vec<Vec<usize>>,
    rows: Vec<faer::Mat<f64>>,
    taus: Vec<faer::Mat<f64>>,
    filled: Vec<usize>,
    gram: Vec<faer::Mat<f64>>,
    cross: Vec<faer::Mat<f64>>,
    equations: Vec<NormalEquations>,
}

/// Rows per block: enough for the product to run at the kernel's speed, few enough to stay in cache.
const BLOCK: usize = 64;

impl BlockedRows {
    pub(crate) fn new(dof: usize, k: usize, drives: bool) -> Self {
        let mut support = row_support(dof);
        if drives {
            for (j, columns) in support.iter_mut().enumerate() {
                columns.extend(drive_index(dof, j)..drive_index(dof, j) + DRIVE_PER_JOINT);
            }
        }
        let s = |j: usize| support[j].len();
        BlockedRows {
            rows: (0..dof).map(|j| faer::Mat::zeros(BLOCK, s(j))).collect(),
            taus: (0..dof).map(|_| faer::Mat::zeros(BLOCK, k)).collect(),
            filled: vec![0; dof],
            gram: (0..dof).map(|j| faer::Mat::zeros(s(j), s(j))).collect(),
            cross: (0..dof).map(|j| faer::Mat::zeros(s(j), k)).collect(),
            equations: vec![
                match drives {
                    true => NormalEquations::with_drives(dof),
                    false => NormalEquations::new(dof),
                };
                k
            ],
            support,
        }
    }

    /// Adds row `j` of `y` with its torque under each right-hand side.
    pub(crate) fn push(&mut self, j: usize, y: &DMatrix<f64>, tau: &[f64]) {
        let r = self.filled[j];
        for (c, &col) in self.support[j].iter().enumerate() {
            self.rows[j][(r, c)] = y[(j, col)];
        }
        for (e, (ne, &t)) in self.equations.iter_mut().zip(tau).enumerate() {
            self.taus[j][(r, e)] = t;
            ne.c[j] += t * t;
            ne.sum[j] += t;
            ne.n[j] += 1;
        }
        self.filled[j] += 1;
        if self.filled[j] == BLOCK {
            self.flush(j);
        }
    }

    fn flush(&mut self, j: usize) {
        let m = self.filled[j];
        if m == 0 {
            return;
        }
        use faer::linalg::matmul::matmul;
        use faer::{Accum, Par};
        let rows = self.rows[j].as_ref().subrows(0, m);
        matmul(self.gram[j].as_mut(), Accum::Add, rows.transpose(), rows, 1.0, Par::Seq);
        matmul(
            self.cross[j].as_mut(),
            Accum::Add,
            rows.transpose(),
            self.taus[j].as_ref().subrows(0, m),
            1.0,
            Par::Seq,
        );
        self.filled[j] = 0;
    }

    /// The normal equations of the rows pushed, one per right-hand side.
    pub(crate) fn finish(mut self) -> Vec<NormalEquations> {
        for j in 0..self.support.len() {
            self.flush(j);
            let support = &self.support[j];
            for ne in &mut self.equations {
                for (r, &pr) in support.iter().enumerate() {
                    for (c, &pc) in support.iter().enumerate() {
                        ne.a[j][(pr, pc)] += self.gram[j][(r, c)];
                    }
                }
            }
            for (e, ne) in self.equations.iter_mut().enumerate() {
                for (r, &pr) in support.iter().enumerate() {
                    ne.b[j][pr] += self.cross[j][(r, e)];
                }
            }
        }
        self.equations
    }
}

/// Torque errors summed over recordings that each have their own parameter set (e.g. one estimate per log):
/// NRMSE per joint = RMS error over the standard deviation of the recorded torque, both over all recordings' moving
/// samples of that joint.
#[derive(Debug, Clone, Default)]
pub struct TorqueError {
    rss: Vec<f64>,
    c: Vec<f64>,
    sum: Vec<f64>,
    n: Vec<usize>,
}

impl TorqueError {
    /// Adds the errors of `pi` on the recording(s) summed in `ne`.
    pub fn add(&mut self, ne: &NormalEquations, pi: &[f64]) {
        if self.rss.len() != ne.dof {
            *self = TorqueError {
                rss: vec![0.0; ne.dof],
                c: vec![0.0; ne.dof],
                sum: vec![0.0; ne.dof],
                n: vec![0; ne.dof],
            };
        }
        let pi = ne.padded(pi);
        for j in 0..ne.dof {
            self.rss[j] += ne.rss_joint(j, &pi);
            self.c[j] += ne.c[j];
            self.sum[j] += ne.sum[j];
            self.n[j] += ne.n[j];
        }
    }

    /// NRMSE per joint (NaN for a joint that never moved).
    pub fn per_joint(&self) -> Vec<f64> {
        (0..self.rss.len())
            .map(|j| {
                let n = self.n[j] as f64;
                let var = self.c[j] / n - (self.sum[j] / n).powi(2);
                (self.rss[j] / n).sqrt() / var.max(0.0).sqrt()
            })
            .collect()
    }

    /// Squared error over the torque's spread, summed over the joints that moved: [`NormalEquations::pooled_nrmse`].
    pub fn pooled(&self) -> f64 {
        let (mut rss, mut spread) = (0.0, 0.0);
        for j in (0..self.rss.len()).filter(|&j| self.n[j] > 0) {
            rss += self.rss[j];
            spread += (self.c[j] - self.sum[j] * self.sum[j] / self.n[j] as f64).max(0.0);
        }
        (rss / spread).sqrt()
    }

    /// Mean NRMSE over the joints that moved.
    pub fn overall(&self) -> f64 {
        let v: Vec<f64> = self.per_joint().into_iter().filter(|x| x.is_finite()).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    }
}
