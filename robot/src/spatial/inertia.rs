//! Rigid-body inertia ([`Inertia`]) in its 10 dynamic parameters.

use nalgebra::{Matrix3, Matrix4, Matrix6, SymmetricEigen, Vector3};

use super::{Force, Motion, Se3, skew};

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

    /// The pseudo-inertia `J = [[Sigma, h], [h^T, m]]`, `Sigma = tr(I_o)/2 1 - I_o` the second moments of mass about
    /// the origin: linear in the parameters, and positive definite exactly when they are a physical body (positive
    /// mass, principal moments obeying the triangle inequalities strictly; Wensing, Kim, Slotine, RA-L 2017).
    pub fn pseudo(&self) -> Matrix4<f64> {
        let mut j = Matrix4::zeros();
        j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(Matrix3::identity() * (0.5 * self.i_o.trace()) - self.i_o));
        j.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.h);
        j.fixed_view_mut::<1, 3>(3, 0).copy_from(&self.h.transpose());
        j[(3, 3)] = self.mass;
        j
    }

    /// Inverse of [`Inertia::pseudo`] (of any symmetric `j`).
    pub fn from_pseudo(j: &Matrix4<f64>) -> Self {
        let sigma = j.fixed_view::<3, 3>(0, 0).into_owned();
        Inertia {
            mass: j[(3, 3)],
            h: j.fixed_view::<3, 1>(0, 3).into_owned(),
            i_o: Matrix3::identity() * sigma.trace() - sigma,
        }
    }

    /// The physical body nearest to these parameters: the pseudo-inertia, its second moments taken in units of the
    /// length `length` (so that all of it is in kilograms), with every eigenvalue raised to at least `floor` kg.
    /// A body already that far inside physics is returned as it is.
    pub fn nearest_body(&self, length: f64, floor: f64) -> Inertia {
        let scale = |l: f64| Matrix4::from_diagonal(&nalgebra::Vector4::new(l, l, l, 1.0));
        let s = scale(1.0 / length);
        let eig = SymmetricEigen::new(s * self.pseudo() * s);
        if eig.eigenvalues.iter().all(|&l| l >= floor) {
            return *self;
        }
        let clipped = eig.eigenvalues.map(|l| l.max(floor));
        let j = eig.eigenvectors * Matrix4::from_diagonal(&clipped) * eig.eigenvectors.transpose();
        Inertia::from_pseudo(&(scale(length) * j * scale(length)))
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
    use nalgebra::{Matrix3, Vector3};

    use crate::spatial::tests::sample_se3;
    use crate::spatial::{Inertia, Motion};

    /// The pseudo-inertia round-trips, is positive definite for a body and not for a negative mass; the nearest body
    /// to a non-physical inertia is physical, and a body well inside physics is its own nearest.
    #[test]
    fn the_nearest_body_of_a_non_physical_inertia_is_physical() {
        let body = Inertia::from_com(
            1.7,
            Vector3::new(0.05, -0.1, 0.3),
            Matrix3::new(0.2, 0.01, -0.02, 0.01, 0.3, 0.03, -0.02, 0.03, 0.25),
        );
        let back = Inertia::from_pseudo(&body.pseudo());
        assert!(
            (back.to_params().iter().zip(body.to_params()).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)) < 1e-15
        );
        assert!(body.pseudo().cholesky().is_some());
        let negative = Inertia { mass: -0.1, ..body };
        assert!(negative.pseudo().cholesky().is_none());
        let near = negative.nearest_body(0.4, 1e-3);
        assert!(crate::model::check_physical(&near).is_ok(), "{near:?}");
        assert!(near.mass >= 1e-3 * 0.99, "{near:?}");
        assert_eq!(body.nearest_body(0.4, 1e-6), body);
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
}
