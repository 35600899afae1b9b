//! Mechanical energy, the invariant the simulation tests check.

use crate::data::Data;
use crate::model::Model;

/// Kinetic and potential energy [J]; potential is zero with every COM at the base frame's z = 0 plane (more
/// precisely: `-m g . c` summed over links).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Energy {
    pub kinetic: f64,
    pub potential: f64,
}

impl Energy {
    pub fn total(&self) -> f64 {
        self.kinetic + self.potential
    }
}

/// Energy of the chain in state (`q`, `qd`).
pub fn energy(model: &Model, data: &mut Data, q: &[f64], qd: &[f64]) -> Energy {
    super::rnea::run(model, data, q, Some(qd), None);
    let g = model.gravity();
    let mut e = Energy { kinetic: 0.0, potential: 0.0 };
    for i in 0..model.dof() {
        let inertia = model.inertia(i);
        e.kinetic += inertia.kinetic_energy(&data.v[i]);
        e.potential -= inertia.mass * g.dot(&data.o_m_i[i].point(&inertia.com()));
    }
    e
}
