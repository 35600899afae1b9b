//! A robot's joint recording: `/joint_states` of a dataset shard or of any ROS 2 bag (MCAP), joints matched by name
//! to the robot's model ([`samples`]), put on the uniform 1 kHz grid that identification and the trainer work on
//! ([`resample`]), with the robot and, for dataset shards, the labels and robot id ([`read`]). [`dataset`] lists
//! the shards of a run directory (or any folder of shards), also while a generation is still adding them.
//!
//! Nothing here depends on the trainer's ML framework: physics-only commands (`identify`) read logs through this
//! crate.

pub mod dataset;
pub mod info;
mod read;
pub mod resample;
pub mod samples;

pub use read::{GRID_DT, ReadError, Recording, log_file, read, robot_document};
pub use samples::JointTrajectory;
