//! A robot's joint recording: `/joint_states` of a dataset shard, of any ROS 2 bag (MCAP or sqlite3 storage) or of
//! a table read by its column map ([`table`]), joints matched by name
//! to the robot's model ([`samples`]), put on the uniform 1 kHz grid that identification and the trainer work on
//! ([`resample`]), with the robot and, for dataset shards, the labels and robot id ([`read`]). [`dataset`] lists
//! the shards of a run directory (or any folder of shards), also while a generation is still adding them.
//!
//! [`log`] reads a user's log as its driver wrote it (own rate, segments between gaps, the robot with the joints the
//! log does not move welded), for identification.
//!
//! Nothing here depends on the trainer's ML framework: physics-only commands (`identify`) read logs through this
//! crate.

pub mod dataset;
mod error;
pub mod info;
pub mod log;
mod read;
pub mod resample;
pub mod samples;
pub mod sqlite;
pub mod table;

pub use error::ReadError;
pub use read::{
    GRID_DT, Gap, Reading, Recording, check_not_an_input, first_gap, log_files, read, read_bag, read_shard_bytes,
    recording_of, robot_document,
};
pub use samples::JointTrajectory;
