//! Rigid-body dynamics of the chain, one module per algorithm as the literature names them.
//!
//! All algorithms take the immutable [`Model`](crate::Model) and a mutable [`Data`](crate::Data) and never allocate.
//! The rigid-body algorithms (`rnea`, `crba`, `aba`) do not include joint friction, exactly like Pinocchio's: the
//! full equation of motion is `M qdd + C qd + G + F_friction(qd) = tau`, with [`friction_torque`] for the last term.

mod aba;
mod crba;
mod energy;
mod friction;
mod regressor;
mod rnea;

pub use aba::{aba, aba_locked};
pub use crba::crba;
pub use energy::{Energy, energy};
pub use friction::{friction_torque, sign};
pub use regressor::regressor;
pub use rnea::{gravity_torque, nonlinear_effects, rnea};
