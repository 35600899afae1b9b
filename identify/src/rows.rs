//! Normal equations of conditioned samples (`crate::signals`): the regressor rows of every moving sample, with the
//! torque of each effort convention on the right-hand side, so one pass over a log serves both until the data say
//! which convention they follow.

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI};
use dynforge_robot::{Data, Model, regressor, rnea};
use nalgebra::{DMatrix, DVector};

use crate::IdentifyError;
use crate::normal::{BlockedRows, NormalEquations};
use crate::samples::{REST_SPEED, STOPPED_SPEED};
use crate::signals::{Conditioned, EffortConvention};
use dynforge_robot::drive::{Drive, drive_index, identified_len};

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

/// Calls `f(i, y)` with the regressor `y` of every usable sample `i` of `c` in `range` (every `step`-th from its
/// start), with the viscous column paired with the span's mean velocity and the Coulomb column `c.coulomb`, and the
/// drives' columns (`crate::drive`: the joint's acceleration and one).
pub(crate) fn for_each_row(
    model: &Model,
    c: &Conditioned,
    range: std::ops::Range<usize>,
    step: usize,
    mut f: impl FnMut(usize, &DMatrix<f64>),
) {
    let n = c.joints;
    let mut data = Data::new(model);
    let mut y = DMatrix::zeros(n, identified_len(n));
    let start = range.start;
    for i in usable(c, range).filter(|i| (i - start).is_multiple_of(step)) {
        let row = i * n..(i + 1) * n;
        regressor(model, &mut data, &c.q[row.clone()], &c.qd[row.clone()], &c.qdd[row]);
        y.columns_mut(0, data.regressor.ncols()).copy_from(&data.regressor);
        for j in 0..n {
            y[(j, NI * n + NF * j)] = c.coulomb[i * n + j];
            y[(j, NI * n + NF * j + 1)] = c.v[i * n + j];
            y[(j, drive_index(n, j))] = c.qdd[i * n + j];
            y[(j, drive_index(n, j) + 1)] = 1.0;
        }
        f(i, &y);
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

/// The samples of `range` whose index in the segment (`origin` + index in the piece) is a multiple of `step`, as
/// the range to start from and the step (at least 1): fixed in the segment, so how a segment is cut into pieces
/// changes no row.
fn thinned(range: std::ops::Range<usize>, step: usize, origin: usize) -> (std::ops::Range<usize>, usize) {
    let step = step.max(1);
    (range.start + (step - (origin + range.start) % step) % step..range.end, step)
}

impl RowSums {
    pub fn new(dof: usize) -> Self {
        RowSums { by_convention: [NormalEquations::with_drives(dof), NormalEquations::with_drives(dof)] }
    }

    /// Adds the moving rows of `c` in `range` (joint rows slower than [`REST_SPEED`] left out) at the samples whose
    /// index in the segment (`origin` + index in `c`) is a multiple of `step` (`crate::signals::row_step`): fixed in
    /// the segment, so how a segment is cut into pieces changes nothing.
    pub fn add(
        &mut self,
        model: &Model,
        c: &Conditioned,
        range: std::ops::Range<usize>,
        (step, origin): (usize, usize),
    ) -> Result<(), IdentifyError> {
        let n = model.dof();
        if c.joints != n {
            return Err(IdentifyError::Dof(c.joints, n));
        }
        let moving = moving_rows(c);
        let mut rows = BlockedRows::new(n, 2, true);
        let (rows_range, step) = thinned(range, step, origin);
        for_each_row(model, c, rows_range, step, |i, y| {
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

/// The weighted scores `sum w_j r_ij y_ij` of the parameters `pi` over the rows of `c` in `range` (every `step`-th
/// sample from the segment's `origin`, as [`RowSums::add`] takes them), one per run of `block` samples, and the rows
/// summed: each column's overlap with the residual as the residual really is (coloured by the filter and the
/// controller), what a sandwich covariance is measured from.
pub(crate) fn scores(
    model: &Model,
    c: &Conditioned,
    range: std::ops::Range<usize>,
    (step, origin): (usize, usize),
    convention: EffortConvention,
    (pi, weights): (&DVector<f64>, &[f64]),
    block: usize,
) -> (Vec<DVector<f64>>, usize) {
    let n = model.dof();
    let moving = moving_rows(c);
    let (rows_range, step) = thinned(range, step, origin);
    let (mut out, mut g, mut current, mut rows) = (Vec::new(), DVector::zeros(pi.len()), None, 0);
    for_each_row(model, c, rows_range, step, |i, y| {
        let b = i / block.max(1);
        if current != Some(b) {
            if current.is_some() {
                out.push(std::mem::replace(&mut g, DVector::zeros(pi.len())));
            }
            current = Some(b);
        }
        for j in (0..n).filter(|&j| moving[i * n + j]) {
            let yj = y.row(j);
            let r = c.tau[convention as usize][i * n + j] - (yj * pi)[0];
            g += yj.transpose() * (weights[j] * r);
            rows += 1;
        }
    });
    if current.is_some() {
        out.push(g);
    }
    (out, rows)
}

/// Each joint's torque residuals of the robot `calibrated` with its drives `drives` (its inertials by inverse
/// dynamics, its friction on the conditioned Coulomb and viscous columns) on the usable rows of `c` in `range` (a row
/// at rest is `None`), in sample order, each beside the joint's velocity: what their autocorrelation, and how much of
/// them friction could be, are measured on.
pub fn residuals(
    (calibrated, drives): (&Model, &[Drive]),
    c: &Conditioned,
    range: std::ops::Range<usize>,
    convention: EffortConvention,
) -> Vec<Vec<Option<Residual>>> {
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
            let drive = drives[j].armature * c.qdd[k] + drives[j].offset;
            let torque = c.tau[convention as usize][k] - tau[j] - friction - drive;
            out[j].push(moving[k].then_some(Residual { torque, velocity: c.v[k] }));
        }
    }
    out
}

/// A joint's torque residual at a row, and the joint's velocity there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Residual {
    pub torque: f64,
    pub velocity: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signals::{VelocitySource, condition, row_step};
    use dynforge_recording::JointTrajectory;

    /// A two-joint arm turning one way at all times (no rows lost to reversals), logged at 1 kHz.
    fn arm_and_log(samples: usize) -> (Model, JointTrajectory) {
        let link = |name: &str| {
            format!(
                r#"<link name="{name}"><inertial><origin xyz="0.1 0 0"/><mass value="2"/>
                   <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.03"/></inertial></link>"#
            )
        };
        let joint = |name: &str, parent: &str, child: &str, axis: &str| {
            format!(
                r#"<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>
                   <origin xyz="0.2 0 0"/><axis xyz="{axis}"/>
                   <limit lower="-1000" upper="1000" effort="100" velocity="100"/></joint>"#
            )
        };
        let text = format!(
            r#"<robot name="two"><link name="base"/>{}{}{}{}</robot>"#,
            link("a"),
            link("b"),
            joint("j0", "base", "a", "0 0 1"),
            joint("j1", "a", "b", "0 1 0")
        );
        let model = dynforge_robot::urdf::parse(&text, "two.urdf").expect("a valid URDF");
        let mut log = JointTrajectory { names: vec!["j0".into(), "j1".into()], ..Default::default() };
        for i in 0..samples {
            let t = i as f64 * 1e-3;
            let q = [1.5 * t + 0.3 * (2.0 * t).sin(), 1.0 * t + 0.2 * (3.0 * t).cos()];
            log.t.push(t);
            log.q.extend(q);
            log.qd.extend([0.0, 0.0]);
            log.tau.extend([q[0].sin() + 2.0, q[1].cos() + 1.0]);
        }
        (model, log)
    }

    /// Rows are thinned at sample indices fixed in the segment: sums over pieces conditioned apart (with the
    /// filter's settling on either side, as `calibrate` cuts a long log) take exactly the rows of the whole, and the
    /// same sums to the filter's settling error.
    #[test]
    fn thinned_rows_do_not_depend_on_how_a_segment_is_cut() {
        let (model, log) = arm_and_log(6000);
        let (cutoff, dt) = (20.0, 1e-3);
        let step = row_step(VelocitySource::Positions, Some(cutoff), dt);
        assert_eq!(step, 12, "1 kHz at 20 Hz: 4 rows per period of the cut-off");
        let whole = {
            let c = condition(&log, VelocitySource::Positions, cutoff);
            let mut sums = RowSums::new(2);
            sums.add(&model, &c, 0..c.len(), (step, 0)).expect("two joints");
            sums.equations(EffortConvention::Sampled)
        };
        let pad = (4.0 / (cutoff * dt)).ceil() as usize;
        let mut cut = RowSums::new(2);
        for range in [0..1234usize, 1234..3001, 3001..6000] {
            let (lo, hi) = (range.start.saturating_sub(pad), (range.end + pad).min(log.len()));
            let c = condition(&log.slice(lo..hi), VelocitySource::Positions, cutoff);
            cut.add(&model, &c, range.start - lo..range.end - lo, (step, lo)).expect("two joints");
        }
        let cut = cut.equations(EffortConvention::Sampled);
        assert_eq!(cut.rows(), whole.rows());
        let rows = whole.rows() as f64 / 2.0;
        // Every step-th sample but those within the rest margin (2 / (fc dt) = 100 samples) of the log's ends,
        // where the differenced velocity is zero.
        let expected = (6000.0 - 2.0 * 101.0) / step as f64;
        assert!((rows - expected).abs() <= 1.0, "{rows} rows of each joint, {expected:.1} expected");
        for j in 0..2 {
            let (a, b) = (whole.joint(j), cut.joint(j));
            // The filter settles to ~1e-7 of the signal within the pad (four time constants of the cut-off).
            assert!((a.0 - b.0).norm() <= 1e-6 * a.0.norm(), "joint {j}: {} vs {}", a.0.norm(), b.0.norm());
            assert!((a.1 - b.1).norm() <= 1e-6 * a.1.norm());
        }
    }
}
