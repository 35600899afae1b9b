//! Geometric Jacobians of points attached to links.

use nalgebra::Vector3;

use crate::data::Data;
use crate::model::Model;

/// Jacobian of the point `point` (in link `link`'s frame) into `data.jacobian`, after [`crate::forward_kinematics`].
///
/// Row `r` < 3 is the point's linear velocity along base axis `r` per unit joint speed; rows 3-5 are the link's
/// angular velocity. Row 2 (`dz/dq_i`) is the gravity-aware PID's `dJ_i/dz` term when gravity is along -z.
/// Columns of joints after `link` are zero.
pub fn point_jacobian(model: &Model, data: &mut Data, link: usize, point: &Vector3<f64>) {
    let p = data.o_m_i[link].point(point);
    data.jacobian.fill(0.0);
    for j in 0..=link {
        let frame = &data.o_m_i[j];
        let z = frame.rot * model.axis(j).into_inner();
        let (lin, ang) = if model.is_prismatic(j) { (z, Vector3::zeros()) } else { (z.cross(&(p - frame.trans)), z) };
        for r in 0..3 {
            data.jacobian[(r, j)] = lin[r];
            data.jacobian[(r + 3, j)] = ang[r];
        }
    }
}
