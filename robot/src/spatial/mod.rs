//! Spatial (6D) algebra on fixed-size nalgebra types: rigid transforms, motion and force vectors, rigid-body inertia.
//!
//! Conventions (Featherstone's, as used by Pinocchio): a [`Se3`] `(R, p)` maps coordinates of the child frame to the
//! parent frame, `x_parent = R x_child + p`. Motions are (angular, linear) velocity of the frame origin; forces are
//! (moment about the frame origin, force). When packed into 6-vectors the angular part comes first.
//! Everything is `Copy` and stack-allocated so the dynamics loops never touch the heap.
//!
//! One file per concept, as Pinocchio's `spatial/` and nalgebra lay theirs out: `se3.rs` (rigid transforms and their
//! action on motions and forces), `vector.rs` ([`Motion`] and [`Force`] together: they are dual spaces, defined by
//! each other's cross product and pairing, and share their 6-vector packing), `inertia.rs` (rigid-body inertia in
//! its 10 dynamic parameters) and `articulated.rs` (the articulated inertias of ABA). The rotation helpers below are
//! shared by all of them.

mod articulated;
mod inertia;
pub mod log_cholesky;
mod se3;
mod vector;

pub use articulated::ArticulatedInertia;
pub use inertia::Inertia;
pub use se3::Se3;
pub use vector::{Force, Motion};

use nalgebra::{Matrix3, Rotation3, Vector3};

/// Skew-symmetric matrix of `v`: `skew(v) * x == v.cross(&x)`.
#[inline]
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Rotation of angle `q` about unit `axis` (Rodrigues).
#[inline]
pub fn axis_rotation(axis: &Vector3<f64>, q: f64) -> Matrix3<f64> {
    let (s, c) = q.sin_cos();
    let k = skew(axis);
    Matrix3::identity() + k * s + k * k * (1.0 - c)
}

/// URDF roll-pitch-yaw (fixed axes X, then Y, then Z): `R = Rz(yaw) * Ry(pitch) * Rx(roll)`.
pub fn rpy_rotation(rpy: [f64; 3]) -> Matrix3<f64> {
    *Rotation3::from_euler_angles(rpy[0], rpy[1], rpy[2]).matrix()
}

#[cfg(test)]
mod tests {
    use nalgebra::Unit;

    use super::*;

    /// A transform with a rotation about no particular axis and an offset, for the submodules' tests.
    pub(super) fn sample_se3() -> Se3 {
        Se3::from_xyz_rpy([0.3, -0.2, 0.5], [0.4, -1.1, 2.0])
    }

    #[test]
    fn rodrigues_matches_nalgebra() {
        let axis = Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8));
        let want = Rotation3::from_axis_angle(&axis, 0.77);
        assert!((axis_rotation(&axis, 0.77) - want.matrix()).norm() < 1e-15);
    }
}
