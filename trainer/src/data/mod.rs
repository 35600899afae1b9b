//! The data pipeline, one module per stage: reading joint trajectories (`source`), timestep unification
//! (`resample`), windowing with the offset-based secondary sampler (`window`), and the robot-level split (`split`).

pub mod resample;
pub mod source;
pub mod split;
pub mod window;
