//! Scratch buffers for the algorithms, allocated once per model and reused (one `Data` per thread).

use nalgebra::DMatrix;

use crate::model::Model;
use crate::spatial::{ArticulatedInertia, Force, Inertia, Motion, Se3};

/// Per-call workspace and results. Fields hold the results of the last algorithm that wrote them.
#[derive(Debug, Clone)]
pub struct Data {
    /// Joint `i`'s frame (= link `i`'s frame) in its parent's frame, at the last `q`.
    pub li_m_i: Vec<Se3>,
    /// Link frames in the base frame (filled by [`crate::forward_kinematics`] and every dynamics call).
    pub o_m_i: Vec<Se3>,
    /// Link twists in link frames.
    pub v: Vec<Motion>,
    /// Link spatial accelerations in link frames (gravity included as a base acceleration).
    pub a: Vec<Motion>,
    /// Link forces in link frames.
    pub f: Vec<Force>,
    /// Joint torques (RNEA output).
    pub tau: Vec<f64>,
    /// Joint accelerations (ABA output).
    pub ddq: Vec<f64>,
    /// Joint-space mass matrix (CRBA output; full, both triangles).
    pub mass_matrix: DMatrix<f64>,
    /// Linear-in-parameters regressor, `dof x (12 dof)` (regressor output).
    pub regressor: DMatrix<f64>,
    /// Geometric Jacobian `6 x dof`, rows: linear velocity (x, y, z) then angular velocity, in base axes.
    pub jacobian: DMatrix<f64>,
    pub(crate) composite: Vec<Inertia>,
    pub(crate) art_inertia: Vec<ArticulatedInertia>,
    pub(crate) art_bias: Vec<Force>,
    pub(crate) u_vec: Vec<Force>,
    pub(crate) d_inv: Vec<f64>,
    pub(crate) u: Vec<f64>,
    pub(crate) c: Vec<Motion>,
    pub(crate) s: Vec<Motion>,
    /// Joint motion subspaces in the base frame (the regressor's).
    pub(crate) base_subspace: Vec<Motion>,
}

impl Data {
    pub fn new(model: &Model) -> Self {
        let n = model.dof();
        Data {
            li_m_i: vec![Se3::IDENTITY; n],
            o_m_i: vec![Se3::IDENTITY; n],
            v: vec![Motion::ZERO; n],
            a: vec![Motion::ZERO; n],
            f: vec![Force::ZERO; n],
            tau: vec![0.0; n],
            ddq: vec![0.0; n],
            mass_matrix: DMatrix::zeros(n, n),
            regressor: DMatrix::zeros(n, dynforge_proto::params::num_params(n)),
            jacobian: DMatrix::zeros(6, n),
            composite: vec![Inertia::ZERO; n],
            art_inertia: vec![ArticulatedInertia::default(); n],
            art_bias: vec![Force::ZERO; n],
            u_vec: vec![Force::ZERO; n],
            d_inv: vec![0.0; n],
            u: vec![0.0; n],
            c: vec![Motion::ZERO; n],
            s: vec![Motion::ZERO; n],
            base_subspace: vec![Motion::ZERO; n],
        }
    }
}
