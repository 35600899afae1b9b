//! The contracts every dynforge process agrees on.
//!
//! Anything that crosses a process or file boundary (the label layout the trainer regresses, the per-link dynamic
//! parameter layout, the shard schema, the run directory and its temporary-file rule, the job messages between the
//! coordinator and its workers) is defined here exactly once, so that the generator, the worker, the shards and the
//! trainer can never disagree about what column 17 means.

pub mod job;
pub mod labels;
pub mod params;
pub mod run_dir;
pub mod shard;

pub use labels::{LABELS, Label, LabelKind, NUM_LABELS};
pub use params::{FRICTION_PARAMS_PER_JOINT, INERTIAL_PARAMS_PER_LINK, InertialParam};
