//! Forward kinematics: link frames and centres of mass in the base frame.

use nalgebra::Vector3;

use crate::data::Data;
use crate::model::Model;
use crate::spatial::Se3;

/// Joint `i`'s frame in its parent's frame at position `q` (an angle, or a displacement along a prismatic axis).
#[inline]
pub(crate) fn joint_transform(model: &Model, i: usize, q: f64) -> Se3 {
    let x = model.placement(i);
    if model.is_prismatic(i) {
        return Se3::new(x.rot, x.trans + x.rot * (model.axis(i).into_inner() * q));
    }
    x.then_rotate(&crate::spatial::axis_rotation(model.axis(i), q))
}

/// Fills `data.li_m_i` and `data.o_m_i` for configuration `q`.
pub fn forward_kinematics(model: &Model, data: &mut Data, q: &[f64]) {
    assert_eq!(q.len(), model.dof(), "q has the wrong length");
    for i in 0..model.dof() {
        data.li_m_i[i] = joint_transform(model, i, q[i]);
        data.o_m_i[i] = if i == 0 { data.li_m_i[0] } else { data.o_m_i[i - 1].compose(&data.li_m_i[i]) };
    }
}

/// Centre of mass of link `i` in the base frame (after [`forward_kinematics`]).
pub fn link_com(model: &Model, data: &Data, i: usize) -> Vector3<f64> {
    data.o_m_i[i].point(&model.inertia(i).com())
}
