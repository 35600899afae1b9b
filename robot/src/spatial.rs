//! Spatial (6D) algebra on fixed-size nalgebra types: rigid transforms, motion and force vectors, rigid-body inertia.
//!
//! Conventions (Featherstone's, as used by Pinocchio): a [`Se3`] `(R, p)` maps coordinates of the child frame to the
//! parent frame, `x_parent = R x_child + p`. Motions are (angular, linear) velocity of the frame origin; forces are
//! (moment about the frame origin, force). When packed into 6-vectors the angular part comes first.
//! Everything is `Copy` and stack-allocated so the dynamics loops never touch the heap.

use nalgebra::{Matrix3, Matrix6, Rotation3, Unit, Vector3, Vector6};

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

/// A symmetric 6x6 spatial inertia kept as its 3x3 blocks `[[a, b], [b^T, c]]` (angular first): the articulated
/// inertias of ABA. Block algebra on `Matrix3` compiles to straight-line code, where generic 6x6 products do not;
/// this is ABA's inner loop.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ArticulatedInertia {
    pub a: Matrix3<f64>,
    pub b: Matrix3<f64>,
    pub c: Matrix3<f64>,
}

impl ArticulatedInertia {
    pub fn from_rigid(i: &Inertia) -> Self {
        ArticulatedInertia { a: i.i_o, b: skew(&i.h), c: Matrix3::from_diagonal_element(i.mass) }
    }

    /// `self * m`.
    #[inline]
    pub fn apply(&self, m: &Motion) -> Force {
        Force { ang: self.a * m.ang + self.b * m.lin, lin: self.b.tr_mul(&m.ang) + self.c * m.lin }
    }

    /// `self - f f^T * s`, the rank-1 update that removes a joint's degree of freedom.
    #[inline]
    pub fn rank1_sub(&mut self, f: &Force, s: f64) {
        let fa = f.ang * s;
        self.a -= fa * f.ang.transpose();
        self.b -= fa * f.lin.transpose();
        self.c -= f.lin * s * f.lin.transpose();
    }

    /// This inertia, given in `x`'s child frame, expressed in the parent frame: `X^T I X` with
    /// `X = x.inv_motion_matrix()`. Rotate the blocks, then shift by the translation `S = skew(p)`:
    /// `a' = a + S b^T - b S - S c S`, `b' = b + S c`, `c' = c`.
    #[inline]
    pub fn transformed(&self, x: &Se3) -> Self {
        let r = &x.rot;
        let a = r * self.a * r.transpose();
        let b = r * self.b * r.transpose();
        let c = r * self.c * r.transpose();
        let s = skew(&x.trans);
        let sc = s * c;
        ArticulatedInertia { a: a + s * b.transpose() - b * s - sc * s, b: b + sc, c }
    }

    /// The full 6x6 matrix.
    pub fn matrix(&self) -> Matrix6<f64> {
        let mut m = Matrix6::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.a);
        m.fixed_view_mut::<3, 3>(0, 3).copy_from(&self.b);
        m.fixed_view_mut::<3, 3>(3, 0).copy_from(&self.b.transpose());
        m.fixed_view_mut::<3, 3>(3, 3).copy_from(&self.c);
        m
    }
}

impl std::ops::AddAssign for ArticulatedInertia {
    #[inline]
    fn add_assign(&mut self, o: Self) {
        self.a += o.a;
        self.b += o.b;
        self.c += o.c;
    }
}

/// A spatial motion (twist or spatial acceleration) at a frame origin, in that frame's axes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Motion {
    pub ang: Vector3<f64>,
    pub lin: Vector3<f64>,
}

impl Motion {
    pub const ZERO: Motion = Motion { ang: Vector3::new(0.0, 0.0, 0.0), lin: Vector3::new(0.0, 0.0, 0.0) };

    pub fn new(ang: Vector3<f64>, lin: Vector3<f64>) -> Self {
        Motion { ang, lin }
    }

    /// Motion cross product `self x m` (derivative of a motion moving with velocity `self`).
    #[inline]
    pub fn cross_motion(&self, m: &Motion) -> Motion {
        Motion { ang: self.ang.cross(&m.ang), lin: self.ang.cross(&m.lin) + self.lin.cross(&m.ang) }
    }

    /// Force cross product `self x* f`.
    #[inline]
    pub fn cross_force(&self, f: &Force) -> Force {
        Force { ang: self.ang.cross(&f.ang) + self.lin.cross(&f.lin), lin: self.ang.cross(&f.lin) }
    }

    /// Power of a force along this motion.
    #[inline]
    pub fn dot(&self, f: &Force) -> f64 {
        self.ang.dot(&f.ang) + self.lin.dot(&f.lin)
    }
}

impl std::ops::Mul<f64> for Motion {
    type Output = Motion;
    #[inline]
    fn mul(self, s: f64) -> Motion {
        Motion { ang: self.ang * s, lin: self.lin * s }
    }
}

/// A spatial force (wrench): moment about the frame origin and force, in that frame's axes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Force {
    pub ang: Vector3<f64>,
    pub lin: Vector3<f64>,
}

impl Force {
    pub const ZERO: Force = Force { ang: Vector3::new(0.0, 0.0, 0.0), lin: Vector3::new(0.0, 0.0, 0.0) };
}

/// What motions and forces share: packing as 6-vectors (angular first) and addition.
macro_rules! six_vector {
    ($t:ident) => {
        impl $t {
            #[inline]
            pub fn to_vector(&self) -> Vector6<f64> {
                Vector6::new(self.ang.x, self.ang.y, self.ang.z, self.lin.x, self.lin.y, self.lin.z)
            }

            #[inline]
            pub fn from_vector(v: &Vector6<f64>) -> Self {
                $t { ang: v.fixed_rows::<3>(0).into(), lin: v.fixed_rows::<3>(3).into() }
            }
        }

        impl std::ops::Add for $t {
            type Output = $t;
            #[inline]
            fn add(self, o: $t) -> $t {
                $t { ang: self.ang + o.ang, lin: self.lin + o.lin }
            }
        }
    };
}

six_vector!(Motion);
six_vector!(Force);

impl std::ops::AddAssign for Force {
    #[inline]
    fn add_assign(&mut self, o: Force) {
        self.ang += o.ang;
        self.lin += o.lin;
    }
}

/// Rigid-body inertia about a frame origin, stored as mass, first moment of mass `h = m c` and the rotational
/// inertia `i_o` about the origin. These are exactly the body's 10 dynamic parameters, so the inertia is linear in
/// them (what the regressor needs) and sums of bodies are plain sums.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Inertia {
    pub mass: f64,
    pub h: Vector3<f64>,
    pub i_o: Matrix3<f64>,
}

impl Inertia {
    pub const ZERO: Inertia = Inertia {
        mass: 0.0,
        h: Vector3::new(0.0, 0.0, 0.0),
        i_o: Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    };

    /// From mass, centre of mass and the rotational inertia about the COM (all in this frame's axes).
    pub fn from_com(mass: f64, com: Vector3<f64>, i_com: Matrix3<f64>) -> Self {
        let s = skew(&com);
        Inertia { mass, h: com * mass, i_o: i_com - s * s * mass }
    }

    /// Centre of mass (undefined for a massless body: returns zero).
    pub fn com(&self) -> Vector3<f64> {
        if self.mass > 0.0 { self.h / self.mass } else { Vector3::zeros() }
    }

    /// Rotational inertia about the centre of mass.
    pub fn i_com(&self) -> Matrix3<f64> {
        let c = self.com();
        let s = skew(&c);
        self.i_o + s * s * self.mass
    }

    /// The momentum (force-like) produced by a motion: `I * v`.
    #[inline]
    pub fn apply(&self, v: &Motion) -> Force {
        Force { lin: v.lin * self.mass + v.ang.cross(&self.h), ang: self.i_o * v.ang + self.h.cross(&v.lin) }
    }

    /// This inertia, given in a child frame, expressed in the parent frame of `x`. Works on the parameters
    /// directly (no division by the mass), so massless and point-like bodies transform exactly.
    pub fn transformed(&self, x: &Se3) -> Inertia {
        let rh = x.rot * self.h;
        let sp = skew(&x.trans);
        let srh = skew(&rh);
        Inertia {
            mass: self.mass,
            h: rh + x.trans * self.mass,
            i_o: x.rot * self.i_o * x.rot.transpose() - sp * sp * self.mass - sp * srh - srh * sp,
        }
    }

    /// The 6x6 matrix form (angular first).
    pub fn matrix(&self) -> Matrix6<f64> {
        let s = skew(&self.h);
        let mut m = Matrix6::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.i_o);
        m.fixed_view_mut::<3, 3>(0, 3).copy_from(&s);
        m.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-s));
        m.fixed_view_mut::<3, 3>(3, 3).copy_from(&(Matrix3::identity() * self.mass));
        m
    }

    /// Kinetic energy of the body moving with twist `v`.
    #[inline]
    pub fn kinetic_energy(&self, v: &Motion) -> f64 {
        0.5 * v.dot(&self.apply(v))
    }

    /// The 10 dynamic parameters in [`dynforge_proto::InertialParam`] order.
    pub fn to_params(&self) -> [f64; 10] {
        let i = &self.i_o;
        [self.mass, self.h.x, self.h.y, self.h.z, i[(0, 0)], i[(0, 1)], i[(1, 1)], i[(0, 2)], i[(1, 2)], i[(2, 2)]]
    }

    /// Inverse of [`Inertia::to_params`].
    pub fn from_params(p: &[f64; 10]) -> Self {
        let i_o = Matrix3::new(p[4], p[5], p[7], p[5], p[6], p[8], p[7], p[8], p[9]);
        Inertia { mass: p[0], h: Vector3::new(p[1], p[2], p[3]), i_o }
    }
}

impl std::ops::Add for Inertia {
    type Output = Inertia;
    fn add(self, o: Inertia) -> Inertia {
        Inertia { mass: self.mass + o.mass, h: self.h + o.h, i_o: self.i_o + o.i_o }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_se3() -> Se3 {
        Se3::from_xyz_rpy([0.3, -0.2, 0.5], [0.4, -1.1, 2.0])
    }

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

    #[test]
    fn articulated_inertia_block_algebra_equals_the_matrix_forms() {
        let x = sample_se3();
        let body = Inertia::from_com(
            1.7,
            Vector3::new(0.05, -0.1, 0.3),
            Matrix3::new(0.2, 0.01, -0.02, 0.01, 0.3, 0.03, -0.02, 0.03, 0.25),
        );
        assert_eq!(ArticulatedInertia::from_rigid(&body).matrix(), body.matrix());
        // An articulated inertia: a rigid one minus a rank-1 term, as ABA produces.
        let f = Force { ang: Vector3::new(0.1, -0.3, 0.2), lin: Vector3::new(0.5, 0.1, -0.2) };
        let mut ia = ArticulatedInertia::from_rigid(&body);
        ia.rank1_sub(&f, 0.7);
        let want = body.matrix() - f.to_vector() * f.to_vector().transpose() * 0.7;
        assert!((ia.matrix() - want).norm() < 1e-15);
        let m = Motion::new(Vector3::new(0.3, 0.2, -0.1), Vector3::new(0.5, -0.4, 0.9));
        assert!((ia.apply(&m).to_vector() - want * m.to_vector()).norm() < 1e-15);
        let xm = x.inv_motion_matrix();
        let want = xm.transpose() * want * xm;
        assert!((ia.transformed(&x).matrix() - want).norm() < 1e-14 * want.norm());
        // For a rigid inertia it agrees with the parameter-space transform.
        let rigid = ArticulatedInertia::from_rigid(&body).transformed(&x).matrix();
        assert!((rigid - body.transformed(&x).matrix()).norm() < 1e-14);
    }

    #[test]
    fn inertia_transform_preserves_kinetic_energy_and_params_round_trip() {
        let x = sample_se3();
        let body = Inertia::from_com(
            1.7,
            Vector3::new(0.05, -0.1, 0.3),
            Matrix3::new(0.2, 0.01, -0.02, 0.01, 0.3, 0.03, -0.02, 0.03, 0.25),
        );
        let v_child = Motion::new(Vector3::new(0.3, 0.2, -0.1), Vector3::new(0.5, -0.4, 0.9));
        let v_parent = x.act_motion(&v_child);
        let e1 = body.kinetic_energy(&v_child);
        let e2 = body.transformed(&x).kinetic_energy(&v_parent);
        assert!((e1 - e2).abs() < 1e-13 * e1.abs().max(1.0));
        let back = Inertia::from_params(&body.to_params());
        assert!((back.i_o - body.i_o).norm() < 1e-15 && back.h == body.h && back.mass == body.mass);
        assert!((body.i_com() - Matrix3::new(0.2, 0.01, -0.02, 0.01, 0.3, 0.03, -0.02, 0.03, 0.25)).norm() < 1e-14);
    }

    #[test]
    fn rodrigues_matches_nalgebra() {
        let axis = Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8));
        let want = Rotation3::from_axis_angle(&axis, 0.77);
        assert!((axis_rotation(&axis, 0.77) - want.matrix()).norm() < 1e-15);
    }
}
