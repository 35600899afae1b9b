//! dynforge's trainer, split like burn's examples: `data` turns shards and ROS 2 bags into model-ready windows
//! through the paper's preprocessing stages; `model` is the transformer estimator; `training` its optimisation loop;
//! `checkpoint` the self-contained saved model; `evaluation` the paper's scores and tables; `inference` estimates
//! a recording's parameters.

pub mod checkpoint;
pub mod device;
pub mod evaluation;
pub mod inference;
pub mod model;
pub mod sweep;
pub mod training;
