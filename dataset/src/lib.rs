//! A dataset as dynforge's estimators read it, and the scores they are judged by; no ML framework here, so the
//! coordinator (which caches before pruning and merges partitions' caches) and `identify` users never build one.
//!
//! From a recording to inputs: the window geometry and the paper's offset sampler (`window`), the Jacobian
//! features (`features`), a recording's windows (`windows`), the physics evidence of windows and recordings
//! against the generator's parameter prior (`evidence`). Of a run directory: its caches, one generic mechanism for
//! both kinds, and the caches of its partitions combined (`cache`), built ahead of training (`prepare`). For
//! training: the robot-level split (`split`), standardisation (`normalize`) and the examples of each estimator
//! (`examples`). For evaluation: R2 and RMSE per label (`metrics`) and the report of an estimator through any
//! implementation of `evaluation::Estimator` (the paper's tables, the torque and identification checks).

pub mod cache;
pub mod evaluation;
pub mod evidence;
pub mod examples;
pub mod features;
pub mod metrics;
pub mod normalize;
pub mod prepare;
pub mod split;
pub mod window;
pub mod windows;
