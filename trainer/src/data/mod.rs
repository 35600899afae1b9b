//! The data pipeline, one module per stage: reading joint trajectories (`source`), timestep unification
//! (`resample`), kinematic enrichment with pruned Jacobian features (`features`), windowing with the offset-based
//! secondary sampler (`window`), and the robot-level split (`split`).

pub mod cache;
pub mod dataset;
pub mod features;
pub mod follow;
pub mod normalize;
pub mod resample;
pub mod source;
pub mod split;
pub mod window;
