//! The linear-in-parameters regressor: `rnea(q, qd, qdd) + friction(qd) = Y(q, qd, qdd) * pi`.

use nalgebra::{DMatrix, Matrix3, SMatrix, Vector3};

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI};

use crate::data::Data;
use crate::model::Model;
use crate::spatial::{Motion, skew};

use super::friction::sign;

/// `L(x)` with `I x = L(x) [Ixx, Ixy, Iyy, Ixz, Iyz, Izz]` for a symmetric `I`.
fn inertia_map(x: &Vector3<f64>) -> SMatrix<f64, 3, 6> {
    SMatrix::<f64, 3, 6>::from_row_slice(&[
        x.x, x.y, 0.0, x.z, 0.0, 0.0, //
        0.0, x.x, x.y, 0.0, x.z, 0.0, //
        0.0, 0.0, 0.0, x.x, x.y, x.z,
    ])
}

/// The 6x10 matrix `A` with `I a + v x* (I v) = A pi` for one body (angular rows first).
fn body_regressor(v: &Motion, a: &Motion) -> SMatrix<f64, 6, NI> {
    let (w, vl) = (&v.ang, &v.lin);
    let (aw, al) = (&a.ang, &a.lin);
    let (sw, sv) = (skew(w), skew(vl));
    let mut out = SMatrix::<f64, 6, NI>::zeros();
    // Moment rows.
    let h_ang: Matrix3<f64> = -skew(al) - sw * sv + sv * sw;
    out.fixed_view_mut::<3, 3>(0, 1).copy_from(&h_ang);
    out.fixed_view_mut::<3, 6>(0, 4).copy_from(&(inertia_map(aw) + sw * inertia_map(w)));
    // Force rows.
    out.fixed_view_mut::<3, 1>(3, 0).copy_from(&(al + w.cross(vl)));
    out.fixed_view_mut::<3, 3>(3, 1).copy_from(&(skew(aw) + sw * sw));
    out
}

/// `Y(q, qd, qdd)`, `dof x 12 dof`, into and returned from `data.regressor`. Columns follow
/// [`dynforge_proto::params`]: 10 inertial parameters per link, then (Coulomb, viscous) per joint.
///
/// Each body's force regressor is carried once to the base frame (moments about the base origin), and each joint's
/// motion subspace too; joint `i` reads body `j >= i` as their product: for a revolute joint of axis `z` through
/// `p`, `(z, p x z) . (n, f)`, the moment about the axis; for a prismatic one `(0, z) . (n, f)`, the force along it.
/// One transform per body and a dot product per joint pair instead of a transform per pair: half the work of
/// carrying each block joint by joint, for a 7-joint arm.
pub fn regressor<'a>(model: &Model, data: &'a mut Data, q: &[f64], qd: &[f64], qdd: &[f64]) -> &'a DMatrix<f64> {
    super::rnea::forward(model, data, q, Some(qd), Some(qdd), false);
    let n = model.dof();
    data.regressor.fill(0.0);
    for i in 0..n {
        data.base_subspace[i] = data.o_m_i[i].act_motion(model.subspace(i));
    }
    for j in 0..n {
        let block = body_regressor(&data.v[j], &data.a[j]);
        let x = &data.o_m_i[j];
        let force = x.rot * block.fixed_rows::<3>(3);
        let moment = x.rot * block.fixed_rows::<3>(0) + skew(&x.trans) * force;
        for i in 0..=j {
            let s = &data.base_subspace[i];
            let row = s.ang.transpose() * moment + s.lin.transpose() * force;
            data.regressor.view_mut((i, NI * j), (1, NI)).copy_from(&row);
        }
    }
    for i in 0..n {
        data.regressor[(i, NI * n + NF * i)] = sign(qd[i]);
        data.regressor[(i, NI * n + NF * i + 1)] = qd[i];
    }
    &data.regressor
}
