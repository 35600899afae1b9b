//! Articulated-body inertias ([`ArticulatedInertia`]): the symmetric 6x6 inertias ABA propagates.

use nalgebra::{Matrix3, Matrix6};

use super::{Force, Inertia, Motion, Se3, skew};

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

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix3, Vector3};

    use crate::spatial::tests::sample_se3;
    use crate::spatial::{ArticulatedInertia, Force, Inertia, Motion};

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
}
