//! Normal equations of conditioned samples (`crate::signals`): the regressor rows of every moving sample, with the
//! torque of each effort convention on the right-hand side, so one pass over a log serves both until the data say
//! which convention they follow.

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI};
use dynforge_robot::{Data, Model, regressor, rnea};
use nalgebra::DMatrix;

use crate::IdentifyError;
use crate::normal::{BlockedRows, NormalEquations};
use crate::samples::{REST_SPEED, STOPPED_SPEED};
use crate::signals::{Conditioned, EffortConvention};

/// Normal equations of one set of rows, one per effort convention (same regressor, other torques).
#[derive(Debug, Clone)]
pub struct RowSums {
    by_convention: [NormalEquations; 2],
}

/// The interior samples of `c` in `range` whose rows are usable: no joint stops, starts or reverses around them (the
/// span `[t[i-1], t[i+1]]` would mix friction regimes: `crate::samples::for_each`'s rule, and the jump of Coulomb
/// friction at a reversal).
fn usable(c: &Conditioned, range: std::ops::Range<usize>) -> impl Iterator<Item = usize> + '_ {
    let n = c.joints;
    let regime = move |i: usize, j: usize| {
        let v = c.qd[i * n + j];
        if v.abs() <= STOPPED_SPEED {
            0
        } else if v > 0.0 {
            1
        } else {
            -1
        }
    };
    let interior = range.start.max(1)..range.end.min(c.len().saturating_sub(1));
    interior.filter(move |&i| (0..n).all(|j| regime(i - 1, j) == regime(i, j) && regime(i, j) == regime(i + 1, j)))
}

/// Calls `f(i, y)` with the regressor `y` of every usable sample `i` of `c` in `range`, with the viscous column
/// paired with the span's mean velocity and the Coulomb column `c.coulomb`.
pub(crate) fn for_each_row(
    model: &Model,
    c: &Conditioned,
    range: std::ops::Range<usize>,
    mut f: impl FnMut(usize, &DMatrix<f64>),
) {
    let n = c.joints;
    let mut data = Data::new(model);
    for i in usable(c, range) {
        let row = i * n..(i + 1) * n;
        regressor(model, &mut data, &c.q[row.clone()], &c.qd[row.clone()], &c.qdd[row]);
        for j in 0..n {
            data.regressor[(j, NI * n + NF * j)] = c.coulomb[i * n + j];
            data.regressor[(j, NI * n + NF * j + 1)] = c.v[i * n + j];
        }
        f(i, &data.regressor);
    }
}

/// Per sample and joint (row-major), whether the joint's row is used: it moves faster than [`REST_SPEED`] at every
/// sample within `c.rest_margin` of it.
pub(crate) fn moving_rows(c: &Conditioned) -> Vec<bool> {
    let (n, len, w) = (c.joints, c.len(), c.rest_margin);
    let mut out = vec![true; n * len];
    for j in 0..n {
        let mut last_rest: Option<usize> = None;
        for i in 0..len {
            if c.qd[i * n + j].abs() < REST_SPEED {
                last_rest = Some(i);
                for k in i.saturating_sub(w)..=i {
                    out[k * n + j] = false;
                }
            } else if last_rest.is_some_and(|r| i - r <= w) {
                out[i * n + j] = false;
            }
        }
    }
    out
}

impl RowSums {
    pub fn new(dof: usize) -> Self {
        RowSums { by_convention: [NormalEquations::new(dof), NormalEquations::new(dof)] }
    }

    /// Adds the moving rows of `c` in `range` (joint rows slower than [`REST_SPEED`] left out).
    pub fn add(&mut self, model: &Model, c: &Conditioned, range: std::ops::Range<usize>) -> Result<(), IdentifyError> {
        let n = model.dof();
        if c.joints != n {
            return Err(IdentifyError::Dof(c.joints, n));
        }
        let moving = moving_rows(c);
        let mut rows = BlockedRows::new(n, 2);
        for_each_row(model, c, range, |i, y| {
            for j in (0..n).filter(|&j| moving[i * n + j]) {
                rows.push(j, y, &[c.tau[0][i * n + j], c.tau[1][i * n + j]]);
            }
        });
        for (ne, part) in self.by_convention.iter_mut().zip(&rows.finish()) {
            ne.merge(part);
        }
        Ok(())
    }

    /// Adds another set of sums (of the same robot).
    pub fn merge(&mut self, other: &RowSums) {
        for (a, b) in self.by_convention.iter_mut().zip(&other.by_convention) {
            a.merge(b);
        }
    }

    /// The normal equations under `convention`.
    pub fn equations(&self, convention: EffortConvention) -> NormalEquations {
        self.by_convention[convention as usize].clone()
    }
}

/// Each joint's torque residuals of the robot `calibrated` (its inertials by inverse dynamics, its friction on the
/// conditioned Coulomb and viscous columns) on the usable rows of `c` in `range` (a row at rest is `None`), in sample
/// order: what their autocorrelation is measured on.
pub fn residuals(
    calibrated: &Model,
    c: &Conditioned,
    range: std::ops::Range<usize>,
    convention: EffortConvention,
) -> Vec<Vec<Option<f64>>> {
    let n = calibrated.dof();
    let moving = moving_rows(c);
    let mut data = Data::new(calibrated);
    let mut out = vec![Vec::new(); n];
    for i in usable(c, range) {
        let row = i * n..(i + 1) * n;
        let tau = rnea(calibrated, &mut data, &c.q[row.clone()], &c.qd[row.clone()], &c.qdd[row]);
        for (j, joint) in calibrated.joints().iter().enumerate() {
            let k = i * n + j;
            let friction = joint.friction.coulomb * c.coulomb[k] + joint.friction.viscous * c.v[k];
            out[j].push(moving[k].then(|| c.tau[convention as usize][k] - tau[j] - friction));
        }
    }
    out
}
