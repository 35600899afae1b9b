//! Simulation engines: one trait, so the controller, the failure checks and the logging are shared.

mod native;
mod rapier;

pub use native::NativeEngine;
pub use rapier::{DEFAULT_SUBSTEPS as RAPIER_SUBSTEPS, RapierEngine};

pub use dynforge_proto::sim::EngineKind;

use crate::trajectory::Config6;

/// A simulated arm advanced one control period at a time under a held motor torque.
pub trait Engine {
    fn kind(&self) -> EngineKind;
    /// Puts the arm in state (`q`, `qd`).
    fn reset(&mut self, q: &Config6, qd: &Config6);
    /// Advances by one control period with the motor torque `tau` held constant (zero-order hold).
    fn step(&mut self, tau: &Config6);
    fn q(&self) -> &Config6;
    fn qd(&self) -> &Config6;
}
