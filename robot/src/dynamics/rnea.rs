//! Recursive Newton-Euler algorithm: inverse dynamics in O(n).

use nalgebra::Vector3;

use crate::data::Data;
use crate::kinematics::joint_transform;
use crate::model::Model;
use crate::spatial::Motion;

/// Joint torques `tau = M(q) qdd + C(q, qd) qd + G(q)` (no friction), into and returned from `data.tau`.
pub fn rnea<'a>(model: &Model, data: &'a mut Data, q: &[f64], qd: &[f64], qdd: &[f64]) -> &'a [f64] {
    run(model, data, q, Some(qd), Some(qdd));
    &data.tau
}

/// Bias torques `C(q, qd) qd + G(q)`.
pub fn nonlinear_effects<'a>(model: &Model, data: &'a mut Data, q: &[f64], qd: &[f64]) -> &'a [f64] {
    run(model, data, q, Some(qd), None);
    &data.tau
}

/// Gravity torques `G(q)`.
pub fn gravity_torque<'a>(model: &Model, data: &'a mut Data, q: &[f64]) -> &'a [f64] {
    run(model, data, q, None, None);
    &data.tau
}

/// Forward pass (kinematics, twists, accelerations with gravity as a base acceleration, link forces) then the
/// backward pass accumulating forces into joint torques. Leaves `v`, `a`, `o_m_i` in `data` for other algorithms.
pub(crate) fn run(model: &Model, data: &mut Data, q: &[f64], qd: Option<&[f64]>, qdd: Option<&[f64]>) {
    forward(model, data, q, qd, qdd, true);
    for i in (0..model.dof()).rev() {
        data.tau[i] = model.subspace(i).dot(&data.f[i]);
        if i > 0 {
            let to_parent = data.li_m_i[i].act_force(&data.f[i]);
            data.f[i - 1] += to_parent;
        }
    }
}

/// The forward pass alone: placements, twists and accelerations (gravity as the base's acceleration) of every
/// body, and with `forces` each body's net force `I a + v x* I v`.
pub(crate) fn forward(
    model: &Model,
    data: &mut Data,
    q: &[f64],
    qd: Option<&[f64]>,
    qdd: Option<&[f64]>,
    forces: bool,
) {
    let n = model.dof();
    assert!(
        q.len() == n && qd.is_none_or(|v| v.len() == n) && qdd.is_none_or(|v| v.len() == n),
        "state has the wrong length"
    );
    let base_acc = Motion::new(Vector3::zeros(), -model.gravity());
    for i in 0..n {
        let x = joint_transform(model, i, q[i]);
        data.li_m_i[i] = x;
        data.o_m_i[i] = if i == 0 { x } else { data.o_m_i[i - 1].compose(&x) };
        let s = *model.subspace(i);
        let vj = s * qd.map_or(0.0, |v| v[i]);
        let aj = s * qdd.map_or(0.0, |v| v[i]);
        let (v_parent, a_parent) = if i == 0 { (Motion::ZERO, base_acc) } else { (data.v[i - 1], data.a[i - 1]) };
        let v = x.act_inv_motion(&v_parent) + vj;
        let a = x.act_inv_motion(&a_parent) + aj + v.cross_motion(&vj);
        data.v[i] = v;
        data.a[i] = a;
        if forces {
            let inertia = model.inertia(i);
            data.f[i] = inertia.apply(&a) + v.cross_force(&inertia.apply(&v));
        }
    }
}
