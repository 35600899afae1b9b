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
pub fn regressor<'a>(model: &Model, data: &'a mut Data, q: &[f64], qd: &[f64], qdd: &[f64]) -> &'a DMatrix<f64> {
    super::rnea::run(model, data, q, Some(qd), Some(qdd));
    let n = model.dof();
    data.regressor.fill(0.0);
    for j in 0..n {
        // Body j's force regressor, carried towards the base; joint i sees its part along its motion subspace: the
        // moment about a revolute axis, the force along a prismatic one.
        let mut block = body_regressor(&data.v[j], &data.a[j]);
        for i in (0..=j).rev() {
            let rows = if model.is_prismatic(i) { 3 } else { 0 };
            let row = model.axis(i).transpose() * block.fixed_rows::<3>(rows);
            data.regressor.view_mut((i, NI * j), (1, NI)).copy_from(&row);
            if i > 0 {
                // To the parent's frame as a force: X^T = [[R, [p]x R], [0, R]] on 3x3 blocks, without forming
                // the 6x6 matrix (a third of the multiplications).
                let x = &data.li_m_i[i];
                let bottom = x.rot * block.fixed_rows::<3>(3);
                let top = x.rot * block.fixed_rows::<3>(0) + skew(&x.trans) * bottom;
                block.fixed_rows_mut::<3>(0).copy_from(&top);
                block.fixed_rows_mut::<3>(3).copy_from(&bottom);
            }
        }
    }
    for i in 0..n {
        data.regressor[(i, NI * n + NF * i)] = sign(qd[i]);
        data.regressor[(i, NI * n + NF * i + 1)] = qd[i];
    }
    &data.regressor
}
