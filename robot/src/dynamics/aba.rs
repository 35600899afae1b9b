//! Articulated-body algorithm (Featherstone): forward dynamics in O(n).
//!
//! This is the world-frame variant (as in Pinocchio 3): every spatial quantity is expressed at the base frame's
//! origin, so articulated inertias are summed into their parent without the per-joint 6x6 frame change that
//! dominates the local-frame form. It halves the flops on a 6-DOF arm; link lever arms of ~1 m keep the
//! world-origin expressions as well conditioned as local ones.

use nalgebra::Vector3;

use crate::data::Data;
use crate::kinematics::joint_transform;
use crate::model::Model;
use crate::spatial::{ArticulatedInertia, Motion};

/// Joint accelerations `qdd = M^-1 (tau - C qd - G)` for the rigid-body torques `tau` (subtract friction first),
/// into and returned from `data.ddq`.
pub fn aba<'a>(model: &Model, data: &'a mut Data, q: &[f64], qd: &[f64], tau: &[f64]) -> &'a [f64] {
    run(model, data, q, qd, tau, None);
    &data.ddq
}

/// ABA with the joints marked in `locked` held rigid (`qdd = 0`; their speed should be zero too): the free joints'
/// accelerations into `data.ddq`, and for each locked joint the torque it must sustain to stay locked, beyond the
/// applied `tau`, into `data.tau` (`tau_i - S_i . f_i`, zero for free joints). This is the dynamics of joints held
/// by static friction, in one O(n) pass: a locked joint passes its child's articulated inertia on whole.
pub fn aba_locked<'a>(
    model: &Model,
    data: &'a mut Data,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    locked: &[bool],
) -> &'a [f64] {
    assert_eq!(locked.len(), model.dof(), "lock mask has the wrong length");
    run(model, data, q, qd, tau, Some(locked));
    &data.ddq
}

fn run(model: &Model, data: &mut Data, q: &[f64], qd: &[f64], tau: &[f64], locked: Option<&[bool]>) {
    let n = model.dof();
    let is_locked = |i: usize| locked.is_some_and(|l| l[i]);
    assert!(q.len() == n && qd.len() == n && tau.len() == n, "state has the wrong length");
    // Pass 1: placements, joint motion subspaces S = (z, o x z) (prismatic: (0, z)), twists, velocity-product accelerations, world
    // inertias and bias forces.
    for i in 0..n {
        let x = joint_transform(model, i, q[i]);
        data.li_m_i[i] = x;
        let o_m_i = if i == 0 { x } else { data.o_m_i[i - 1].compose(&x) };
        data.o_m_i[i] = o_m_i;
        let z = o_m_i.rot * model.axis(i).into_inner();
        let s = if model.is_prismatic(i) {
            Motion::new(Vector3::zeros(), z)
        } else {
            Motion::new(z, o_m_i.trans.cross(&z))
        };
        let vj = s * qd[i];
        let v = if i == 0 { vj } else { data.v[i - 1] + vj };
        data.s[i] = s;
        data.v[i] = v;
        data.c[i] = v.cross_motion(&vj);
        let inertia = model.inertia(i).transformed(&o_m_i);
        data.art_inertia[i] = ArticulatedInertia::from_rigid(&inertia);
        data.art_bias[i] = v.cross_force(&inertia.apply(&v));
    }
    // Pass 2: articulated inertias and bias forces, tip to base: U = IA S, D = S^T U.
    for i in (0..n).rev() {
        let s = data.s[i];
        let mut ia = data.art_inertia[i];
        let u_vec = ia.apply(&s);
        let d_inv = 1.0 / s.dot(&u_vec);
        let u = tau[i] - s.dot(&data.art_bias[i]);
        data.u_vec[i] = u_vec;
        data.d_inv[i] = d_inv;
        data.u[i] = u;
        if i > 0 {
            let mut pa = data.art_bias[i];
            if !is_locked(i) {
                ia.rank1_sub(&u_vec, d_inv);
                pa.ang += u_vec.ang * (u * d_inv);
                pa.lin += u_vec.lin * (u * d_inv);
            }
            pa += ia.apply(&data.c[i]);
            data.art_inertia[i - 1] += ia;
            data.art_bias[i - 1] += pa;
        }
    }
    // Pass 3: accelerations, base to tip; gravity enters as a uniform base acceleration.
    let mut a_parent = Motion::new(Vector3::zeros(), -model.gravity());
    for i in 0..n {
        let a = a_parent + data.c[i];
        if is_locked(i) {
            // The wrench through the joint is IA a + pA; along the axis it must equal the joint's total torque.
            data.ddq[i] = 0.0;
            data.tau[i] = data.u[i] - a.dot(&data.u_vec[i]);
            a_parent = a;
        } else {
            let qdd = (data.u[i] - a.dot(&data.u_vec[i])) * data.d_inv[i];
            data.ddq[i] = qdd;
            data.tau[i] = 0.0;
            a_parent = a + data.s[i] * qdd;
        }
    }
}
