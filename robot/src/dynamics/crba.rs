//! Composite rigid-body algorithm: the joint-space mass matrix.

use nalgebra::DMatrix;

use crate::data::Data;
use crate::kinematics::forward_kinematics;
use crate::model::Model;

/// The symmetric mass matrix `M(q)` into (and returned from) `data.mass_matrix`.
pub fn crba<'a>(model: &Model, data: &'a mut Data, q: &[f64]) -> &'a DMatrix<f64> {
    forward_kinematics(model, data, q);
    let n = model.dof();
    for i in 0..n {
        data.composite[i] = *model.inertia(i);
    }
    for i in (0..n).rev() {
        let s = *model.subspace(i);
        let mut f = data.composite[i].apply(&s);
        data.mass_matrix[(i, i)] = s.dot(&f);
        for j in (0..i).rev() {
            f = data.li_m_i[j + 1].act_force(&f);
            let m = model.subspace(j).dot(&f);
            data.mass_matrix[(i, j)] = m;
            data.mass_matrix[(j, i)] = m;
        }
        if i > 0 {
            let child = data.composite[i].transformed(&data.li_m_i[i]);
            data.composite[i - 1] = data.composite[i - 1] + child;
        }
    }
    &data.mass_matrix
}
