//! Simulation engines: one trait, so the controller, the failure checks and the logging are shared.

mod native;
mod rapier;

pub use native::NativeEngine;
pub use rapier::{DEFAULT_SUBSTEPS as RAPIER_SUBSTEPS, RapierEngine};

use dynforge_proto::sim::EngineKind;

/// A simulated arm advanced one control period at a time under a held motor torque.
pub trait Engine {
    fn kind(&self) -> EngineKind;
    /// Puts the arm in state (`q`, `qd`), one value per joint.
    fn reset(&mut self, q: &[f64], qd: &[f64]);
    /// Advances by one control period with the motor torque `tau` held constant (zero-order hold).
    fn step(&mut self, tau: &[f64]);
    fn q(&self) -> &[f64];
    fn qd(&self) -> &[f64];
}
