//! Simulation engines: one trait, so the controller, the failure checks and the logging are shared.

mod native;
mod rapier;

pub use native::NativeEngine;
pub use rapier::{DEFAULT_SUBSTEPS as RAPIER_SUBSTEPS, RapierEngine};

use crate::trajectory::Config6;

/// Which engine runs a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum EngineKind {
    /// Featherstone ABA + RK4 with exact stick/slip Coulomb friction (this crate).
    Native,
    /// rapier3d-f64's reduced-coordinate multibody (semi-implicit Euler substeps).
    Rapier,
}

impl EngineKind {
    pub fn name(self) -> &'static str {
        match self {
            EngineKind::Native => "native",
            EngineKind::Rapier => "rapier",
        }
    }
}

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
