//! dynforge's robot crate: the model of a fixed-base serial chain of revolute joints, the paper's random robot
//! generator, URDF input/output, and the rigid-body algorithms the simulator, the controller and the identification
//! run millions of times (named as in the literature and Pinocchio: `rnea`, `crba`, `aba`, `regressor`).
//!
//! ```
//! use dynforge_proto::generator::GeneratorConfig;
//! use dynforge_robot::{generator, Data, rnea, aba};
//! let robot = generator::generate(&GeneratorConfig::default(), 1, 7).unwrap();
//! let model = &robot.model;
//! let mut data = Data::new(model);
//! let (q, qd, qdd) = ([0.1; 6], [0.2; 6], [0.3; 6]);
//! let tau = rnea(model, &mut data, &q, &qd, &qdd).to_vec();
//! let back = aba(model, &mut data, &q, &qd, &tau);
//! assert!(back.iter().zip(&qdd).all(|(a, b)| (a - b).abs() < 1e-9));
//! ```

// `!(a < b)` is deliberate in the validators: it also rejects NaN. Index loops mirror the algorithms' notation.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

#[cfg(feature = "collision")]
pub mod collision;
pub mod data;
pub mod drive;
pub mod dynamics;
pub mod generator;
pub mod jacobian;
pub mod kinematics;
pub mod mjcf;
pub mod model;
pub mod parameters;
pub mod prior;
pub mod rng;
pub mod spatial;
pub mod summary;
pub mod urdf;

pub use data::Data;
pub use dynamics::{
    Energy, aba, aba_locked, crba, energy, friction_torque, gravity_torque, nonlinear_effects, regressor, rnea,
};
pub use jacobian::point_jacobian;
pub use kinematics::{forward_kinematics, link_com};
pub use model::{Model, ModelError, ModelProblem};
