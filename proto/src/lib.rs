//! The contracts every dynforge process agrees on.
//!
//! Anything that crosses a process or file boundary is defined here exactly once, so that the generator, the
//! worker, the shards and the trainer can never disagree about what column 17 means: the label layout the trainer
//! regresses (`labels`), the per-link dynamic parameter layout (`params`), the shard schema (`shard`), the run
//! directory and its temporary-file rule (`run_dir`), the run manifest (`manifest`, with the generator's and the
//! simulation's settings it holds: `generator`, `sim`), and what a job is with the messages about it between the
//! coordinator and its workers (`job`).

pub mod generator;
pub mod job;
pub mod labels;
pub mod manifest;
pub mod parallel;
pub mod params;
pub mod run_dir;
pub mod shard;
pub mod sim;

pub use labels::{LABELS, Label, LabelKind, NUM_LABELS};
pub use params::{FRICTION_PARAMS_PER_JOINT, INERTIAL_PARAMS_PER_LINK, InertialParam};
