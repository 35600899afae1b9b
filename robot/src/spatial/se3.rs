//! Rigid transforms ([`Se3`]) and how they act on motions and forces.

use nalgebra::{Matrix3, Matrix6, Unit, Vector3};

use super::{Force, Motion, axis_rotation, rpy_rotation, skew};

/// A rigid transform: rotation and translation of a child frame in its parent frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Se3 {
    pub rot: Matrix3<f64>,
    pub trans: Vector3<f64>,
}

impl Default for Se3 {
    fn default() -> Self {
        Se3::IDENTITY
    }
}

impl Se3 {
    pub const IDENTITY: Se3 =
        Se3 { rot: Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), trans: Vector3::new(0.0, 0.0, 0.0) };

    pub fn new(rot: Matrix3<f64>, trans: Vector3<f64>) -> Self {
        Se3 { rot, trans }
    }

    /// From URDF `xyz` and `rpy`.
    pub fn from_xyz_rpy(xyz: [f64; 3], rpy: [f64; 3]) -> Self {
        Se3::new(rpy_rotation(rpy), Vector3::from(xyz))
    }

    /// Pure rotation about `axis` (unit) by `q`.
    pub fn revolute(axis: &Unit<Vector3<f64>>, q: f64) -> Self {
        Se3::new(axis_rotation(axis, q), Vector3::zeros())
    }

    /// `self * other`: the transform of a grandchild frame.
    #[inline]
    pub fn compose(&self, other: &Se3) -> Se3 {
        Se3::new(self.rot * other.rot, self.rot * other.trans + self.trans)
    }

    /// `self * (pure rotation r)`, cheaper than a full compose.
    #[inline]
    pub fn then_rotate(&self, r: &Matrix3<f64>) -> Se3 {
        Se3::new(self.rot * r, self.trans)
    }

    pub fn inverse(&self) -> Se3 {
        let rt = self.rot.transpose();
        Se3::new(rt, -(rt * self.trans))
    }

    /// Maps a point from child to parent coordinates.
    #[inline]
    pub fn point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rot * p + self.trans
    }

    /// Motion expressed in the child frame -> same motion expressed in the parent frame.
    #[inline]
    pub fn act_motion(&self, m: &Motion) -> Motion {
        let ang = self.rot * m.ang;
        Motion { ang, lin: self.rot * m.lin + self.trans.cross(&ang) }
    }

    /// Motion expressed in the parent frame -> same motion expressed in the child frame.
    #[inline]
    pub fn act_inv_motion(&self, m: &Motion) -> Motion {
        let rt = self.rot.transpose();
        Motion { ang: rt * m.ang, lin: rt * (m.lin - self.trans.cross(&m.ang)) }
    }

    /// Force expressed in the child frame -> same force expressed in the parent frame.
    #[inline]
    pub fn act_force(&self, f: &Force) -> Force {
        let lin = self.rot * f.lin;
        Force { ang: self.rot * f.ang + self.trans.cross(&lin), lin }
    }

    /// Force expressed in the parent frame -> same force expressed in the child frame.
    #[inline]
    pub fn act_inv_force(&self, f: &Force) -> Force {
        let rt = self.rot.transpose();
        Force { ang: rt * (f.ang - self.trans.cross(&f.lin)), lin: rt * f.lin }
    }

    /// The 6x6 matrix mapping parent-frame motion 6-vectors to child-frame ones (`act_inv_motion`). Its transpose
    /// maps child-frame forces to the parent frame.
    pub fn inv_motion_matrix(&self) -> Matrix6<f64> {
        let rt = self.rot.transpose();
        let mut x = Matrix6::zeros();
        x.fixed_view_mut::<3, 3>(0, 0).copy_from(&rt);
        x.fixed_view_mut::<3, 3>(3, 3).copy_from(&rt);
        x.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-rt * skew(&self.trans)));
        x
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix3, Vector3};

    use crate::spatial::tests::sample_se3;
    use crate::spatial::{Force, Inertia, Motion};

    #[test]
    fn matrix_forms_agree_with_operators() {
        let x = sample_se3();
        let m = Motion::new(Vector3::new(0.1, -0.7, 0.3), Vector3::new(1.0, 2.0, -0.5));
        let xm = x.inv_motion_matrix();
        let want = x.act_inv_motion(&m).to_vector();
        assert!((xm * m.to_vector() - want).norm() < 1e-14);
        let f = Force { ang: Vector3::new(0.2, 0.1, -0.4), lin: Vector3::new(-3.0, 0.5, 1.5) };
        let child_force = x.act_inv_force(&f);
        // X^T maps child forces to the parent.
        assert!((xm.transpose() * child_force.to_vector() - f.to_vector()).norm() < 1e-13);
        // Power is frame invariant.
        assert!((x.act_inv_motion(&m).dot(&child_force) - m.dot(&f)).abs() < 1e-13);
        let inertia =
            Inertia::from_com(2.5, Vector3::new(0.1, 0.0, 0.2), Matrix3::from_diagonal(&Vector3::new(0.1, 0.2, 0.15)));
        assert!((inertia.matrix() * m.to_vector() - inertia.apply(&m).to_vector()).norm() < 1e-13);
    }
}
