//! The data pipeline after a recording is read (`dynforge_recording`: joint trajectories by name, on a uniform
//! grid), one module per stage: kinematic enrichment with pruned Jacobian features (`features`), windowing with the
//! offset-based secondary sampler (`window`), the robot-level split (`split`), standardisation (`normalize`), and
//! the cache of a dataset's windows (`cache`), its physics (`physics`), and the caches of a run's partitions
//! combined (`partitions`).

pub mod cache;
mod codec;
pub mod dataset;
pub mod features;
pub mod normalize;
pub mod partitions;
pub mod physics;
pub mod split;
pub mod window;
