//! Classical identification of a manipulator's dynamic parameters from its joint recordings, beside the network.
//!
//! Rigid-body dynamics with joint friction are linear in the parameters: `tau = Y(q, qd, qdd) pi` (the robot
//! crate's `regressor`). Every moving sample of a recording contributes its rows of `Y` to one set of normal
//! equations ([`NormalEquations`]), from which
//! - [`least_squares`] gives the classical estimate: the minimum-norm `pi` over the identifiable (base) parameter
//!   combinations, with their count (rank) and the residual noise level. It predicts torques but cannot name the
//!   paper's individual labels, most of which are not identifiable from joint torques alone;
//! - [`refine`] gives the labels: the maximum-a-posteriori estimate under a Gaussian prior on the 38 labels (the
//!   network's estimate and its error, or the training distribution), so that the data pin down every identifiable
//!   combination and the prior decides only what the data cannot see.
//!
//! - [`calibrate`] calibrates a robot description (URDF) to logs without a network: the physically consistent
//!   parameters of every link and joint (`consistent`, over `dynforge_robot::prior`'s log-Cholesky coordinates), the URDF as
//!   prior, from logs conditioned as real drivers write them (`signals`, `rows`), with each joint's drive terms that
//!   a URDF cannot state (`dynforge_robot::drive`: rotor inertia, a torque offset).
//!
//! The same normal equations score any parameter set's torque prediction on a recording ([`NormalEquations::nrmse`])
//! without re-running the dynamics per parameter set.

pub mod calibrate;
pub mod consistent;
mod labels;
mod latent;
mod normal;
mod refine;
pub mod rows;
mod samples;
pub mod signals;
mod solve;

pub use calibrate::{CalibrateError, Identification, Options, identify_logs};
pub use labels::{labels_of_parameters, parameters_of_labels};
pub use latent::{
    BatchScatter, Evidence, LatentSums, ParameterPrior, Posterior, batch_scatter, latent_blocks, packed_len,
};
pub use normal::{NormalEquations, TorqueError};
pub use refine::{Prior, Refined, refine};
pub use samples::{PAIRED_NOISE_GAIN, PAIRING_REVISION, REST_SPEED, STOPPED_SPEED};
pub use solve::{LeastSquares, least_squares};

/// Why an identification failed.
#[derive(Debug, thiserror::Error)]
pub enum IdentifyError {
    #[error("the recording has no moving samples to identify from (every joint slower than {REST_SPEED} rad/s)")]
    NoData,
    #[error("{0} joints given where {1} are needed")]
    Dof(usize, usize),
    #[error("the eigen-decomposition of the normal equations failed")]
    Decomposition,
    #[error("the prior's standard deviation of label {0} is {1}, not a positive number")]
    Prior(&'static str, f64),
    #[error("a parameter prior needs at least two parameter vectors of one length ({0} given)")]
    PriorSamples(usize),
    #[error("{0}: not a physical body (its pseudo-inertia is not positive definite)")]
    NotPhysical(String),
    #[error(
        "joint '{joint}' moves too little: {rows} usable samples (moving, and away from its stops and reversals); \
         record more motion of it, or weld it with --fix {joint}"
    )]
    TooFewRows { joint: String, rows: usize },
}

impl From<dynforge_robot::prior::PriorError> for IdentifyError {
    fn from(e: dynforge_robot::prior::PriorError) -> Self {
        match e {
            dynforge_robot::prior::PriorError::NotPhysical(what) => IdentifyError::NotPhysical(what),
        }
    }
}
