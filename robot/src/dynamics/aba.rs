//! Articulated-body algorithm (Featherstone): forward dynamics in O(n).

use nalgebra::{Vector3, Vector6};

use crate::data::Data;
use crate::kinematics::joint_transform;
use crate::model::Model;
use crate::spatial::{Force, Motion, transform_spatial_inertia};

/// Joint accelerations `qdd = M^-1 (tau - C qd - G)` for the rigid-body torques `tau` (subtract friction first),
/// into and returned from `data.ddq`.
pub fn aba<'a>(model: &Model, data: &'a mut Data, q: &[f64], qd: &[f64], tau: &[f64]) -> &'a [f64] {
    let n = model.dof();
    assert!(q.len() == n && qd.len() == n && tau.len() == n, "state has the wrong length");
    // Pass 1: kinematics, velocity-product accelerations and bias forces.
    for i in 0..n {
        let x = joint_transform(model, i, q[i]);
        data.li_m_i[i] = x;
        data.o_m_i[i] = if i == 0 { x } else { data.o_m_i[i - 1].compose(&x) };
        let vj = Motion::new(model.axis(i).into_inner() * qd[i], Vector3::zeros());
        let v = if i == 0 { vj } else { x.act_inv_motion(&data.v[i - 1]) + vj };
        data.v[i] = v;
        data.c[i] = v.cross_motion(&vj);
        let inertia = model.inertia(i);
        data.art_inertia[i] = inertia.matrix();
        data.art_bias[i] = v.cross_force(&inertia.apply(&v)).to_vector();
    }
    // Pass 2: articulated inertias and bias forces, tip to base.
    for i in (0..n).rev() {
        let axis = model.axis(i);
        let ia = data.art_inertia[i];
        // U = IA S for S = (axis, 0): a combination of the first three columns.
        let u_vec: Vector6<f64> = ia.fixed_columns::<3>(0) * axis.into_inner();
        let d = axis.dot(&u_vec.fixed_rows::<3>(0));
        let d_inv = 1.0 / d;
        let u = tau[i] - axis.dot(&data.art_bias[i].fixed_rows::<3>(0));
        data.u_vec[i] = u_vec;
        data.d_inv[i] = d_inv;
        data.u[i] = u;
        if i > 0 {
            let ia_a = ia - u_vec * u_vec.transpose() * d_inv;
            let pa = data.art_bias[i] + ia_a * data.c[i].to_vector() + u_vec * (u * d_inv);
            data.art_inertia[i - 1] += transform_spatial_inertia(&ia_a, &data.li_m_i[i]);
            let pa_parent = data.li_m_i[i].act_force(&Force::from_vector(&pa));
            data.art_bias[i - 1] += pa_parent.to_vector();
        }
    }
    // Pass 3: accelerations, base to tip; gravity enters as a base acceleration.
    let mut a_parent = Motion::new(Vector3::zeros(), -model.gravity());
    for i in 0..n {
        let a = data.li_m_i[i].act_inv_motion(&a_parent) + data.c[i];
        let qdd = (data.u[i] - data.u_vec[i].dot(&a.to_vector())) * data.d_inv[i];
        data.ddq[i] = qdd;
        a_parent = a + Motion::new(model.axis(i).into_inner() * qdd, Vector3::zeros());
    }
    &data.ddq
}
