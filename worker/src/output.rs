//! What a job leaves: its shard (the recording as joint states, its job record and labels), or its discard.

use std::path::{Path, PathBuf};

use dynforge_proto::shard::JointState;
use dynforge_shard::{Metadata, ShardContent, ShardError};

use crate::simulate::{Discard, Simulation};

/// What a job produced.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    Written { path: PathBuf, samples: usize, duration: f64, saturated: f64, content_hash: u64 },
    Discarded(Discard),
}

/// Failures that are not the simulation's (those are discards): bad configuration, unwritable output.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    #[error(transparent)]
    Model(#[from] dynforge_robot::ModelError),
    #[error(transparent)]
    Shard(#[from] ShardError),
    /// A family's variant could not be drawn (its URDF was checked before the run: this is a bug, not a discard).
    #[error("drawing the family's variant: {0}")]
    Family(String),
}

/// Writes the shard of a recording of `model` (described by `urdf`) at `path`.
pub(crate) fn write_shard(
    path: &Path,
    model: &dynforge_robot::Model,
    urdf: &str,
    rec: &Simulation,
    metadata: &Metadata,
) -> Result<Outcome, JobError> {
    let messages = joint_states(model, rec);
    let content_hash = dynforge_shard::write(path, &ShardContent { urdf, joint_states: &messages, metadata })?;
    Ok(Outcome::Written {
        path: path.to_path_buf(),
        samples: rec.len(),
        duration: rec.duration(),
        saturated: rec.saturated,
        content_hash,
    })
}

/// The recording as ROS 2 joint-state messages stamped with sim time.
pub fn joint_states(model: &dynforge_robot::Model, rec: &Simulation) -> Vec<JointState> {
    let names: std::sync::Arc<[String]> = model.joints().iter().map(|j| j.name.clone()).collect();
    let dt_ns = (rec.dt * 1e9).round() as i64;
    (0..rec.len())
        .map(|k| {
            let t = k as i64 * dt_ns;
            JointState {
                sec: (t / 1_000_000_000) as i32,
                nanosec: (t % 1_000_000_000) as u32,
                frame_id: String::new(),
                name: names.clone(),
                position: rec.q[k].clone(),
                velocity: rec.qd[k].clone(),
                effort: rec.tau[k].clone(),
            }
        })
        .collect()
}
