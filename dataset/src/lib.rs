//! A dataset as dynforge's estimators read it; no ML framework here, so the coordinator (which caches before pruning
//! and merges partitions' caches) never builds one.
//!
//! From a recording to inputs: the window geometry and the paper's offset sampler (`window`), the Jacobian
//! features (`features`), a recording's windows (`windows`), the physics evidence of windows and recordings
//! against the generator's parameter prior (`evidence`). Of a run directory: its caches, one generic mechanism for
//! both kinds, and the caches of its partitions combined (`cache`), built ahead of training (`prepare`). For
//! training: the robot-level split (`split`), standardisation (`normalize`) and the examples of each estimator
//! (`examples`), and R2 and RMSE per label (`metrics`), the scores of every epoch. How an estimator is judged is
//! `dynforge_evaluation`'s.

pub mod cache;
pub mod evidence;
pub mod examples;
pub mod features;
pub mod metrics;
pub mod normalize;
pub mod prepare;
pub mod split;
pub mod window;
pub mod windows;
