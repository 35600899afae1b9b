//! Normal equations of conditioned samples (`crate::signals`): the regressor rows of every moving sample, with the
//! torque of each effort convention on the right-hand side, so one pass over a log serves both until the data say
//! which convention they follow.

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI};
use dynforge_robot::{Data, Model, regressor};
use nalgebra::DMatrix;

use crate::IdentifyError;
use crate::normal::{NormalEquations, accumulate_row};
use crate::samples::{REST_SPEED, STOPPED_SPEED, row_support};
use crate::signals::{Conditioned, EffortConvention};

/// Normal equations of one set of rows, one per effort convention (same regressor, other torques).
#[derive(Debug, Clone)]
pub struct RowSums {
    by_convention: [NormalEquations; 2],
}

/// Calls `f(i, y)` with the regressor `y` of every usable sample `i` of `c`: interior samples where no joint stops,
/// starts or reverses (the span `[t[i-1], t[i+1]]` would mix friction regimes: `crate::samples::for_each`'s rule,
/// and the jump of Coulomb friction at a reversal), with the viscous column paired with the span's mean velocity
/// and the Coulomb column `c.coulomb`.
pub(crate) fn for_each_row(model: &Model, c: &Conditioned, mut f: impl FnMut(usize, &DMatrix<f64>)) {
    let (n, len) = (c.joints, c.len());
    let mut data = Data::new(model);
    let regime = |i: usize, j: usize| {
        let v = c.qd[i * n + j];
        if v.abs() <= STOPPED_SPEED {
            0
        } else if v > 0.0 {
            1
        } else {
            -1
        }
    };
    for i in 1..len.saturating_sub(1) {
        if (0..n).any(|j| (regime(i - 1, j) != regime(i, j)) || (regime(i, j) != regime(i + 1, j))) {
            continue;
        }
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

    /// Adds the moving rows of `c` (joint rows slower than [`REST_SPEED`] left out).
    pub fn add(&mut self, model: &Model, c: &Conditioned) -> Result<(), IdentifyError> {
        let n = model.dof();
        if c.joints != n {
            return Err(IdentifyError::Dof(c.joints, n));
        }
        let support = row_support(n);
        let moving = moving_rows(c);
        let [held, sampled] = &mut self.by_convention;
        for_each_row(model, c, |i, y| {
            for j in 0..n {
                if !moving[i * n + j] {
                    continue;
                }
                accumulate_row(&mut held.a[j], y, j, &support[j]);
                held.add_torque(j, y, &support[j], c.tau[0][i * n + j]);
                sampled.add_torque(j, y, &support[j], c.tau[1][i * n + j]);
            }
        });
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
        let mut ne = self.by_convention[convention as usize].clone();
        ne.a.clone_from(&self.by_convention[0].a);
        ne
    }
}

/// Joint `j`'s torque residuals of parameters `pi` on the usable rows of `c` (moving rows; a row at rest is `None`),
/// in sample order: what their autocorrelation is measured on.
pub fn residuals(model: &Model, c: &Conditioned, pi: &[f64], convention: EffortConvention) -> Vec<Vec<Option<f64>>> {
    let n = model.dof();
    let moving = moving_rows(c);
    let mut out = vec![Vec::new(); n];
    for_each_row(model, c, |i, y| {
        for j in 0..n {
            let predicted: f64 = (0..pi.len()).map(|k| y[(j, k)] * pi[k]).sum();
            out[j].push(moving[i * n + j].then(|| c.tau[convention as usize][i * n + j] - predicted));
        }
    });
    out
}
