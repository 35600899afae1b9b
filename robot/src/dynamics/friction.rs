//! Joint friction, the paper's model: `tau_f = mu_c sign(qd) + mu_v qd`.

use crate::model::Model;

/// `sign` with `sign(0) = 0` (unlike `f64::signum`), so a joint at rest has no Coulomb term.
#[inline]
pub fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// Friction torque of every joint at joint speeds `qd`, into `out`.
pub fn friction_torque(model: &Model, qd: &[f64], out: &mut [f64]) {
    for ((o, j), &v) in out.iter_mut().zip(model.joints()).zip(qd) {
        *o = j.friction.coulomb * sign(v) + j.friction.viscous * v;
    }
}
