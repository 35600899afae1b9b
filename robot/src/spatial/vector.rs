//! Spatial vectors: [`Motion`] (twists, accelerations) and [`Force`] (wrenches), the two dual 6D spaces.
//!
//! They are kept in one file because they are defined by each other: a motion's cross product acts on forces
//! ([`Motion::cross_force`]), their pairing is power ([`Motion::dot`]), and both share the 6-vector packing and
//! addition written once by `six_vector!`.

use nalgebra::{Vector3, Vector6};

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
