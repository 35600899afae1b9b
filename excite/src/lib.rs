//! Excitation design for a robot described by its URDF: joint trajectories that start and end at rest, keep the
//! URDF's limits, and make its dynamic parameters as identifiable from its torques as possible (D-optimality of the
//! base parameters' information, as FloBaRoID and FIGAROH optimize it). What `identify` and the robot's family
//! learn from then comes from motions chosen for them instead of whatever the robot happened to do.

pub mod baseline;
pub mod collision;
pub mod design;
pub mod information;
pub mod motion;
mod options;
mod sampler;
pub mod tours;
pub mod write;

pub use collision::SelfCollision;
pub use design::{Clearance, Design, MAX_DESIGN_SAMPLES, MAX_WRITTEN_SAMPLES, design, design_with, start_pose};
pub use options::Options;

#[derive(Debug, thiserror::Error)]
pub enum ExciteError {
    #[error("{0}")]
    Option(String),
    #[error(
        "no motion fits the limits: even small motions around the start pose need more effort than the URDF's \
         effort limits allow (check the start pose and the limits)"
    )]
    Infeasible,
    #[error("{file}: {source}")]
    Write { file: String, source: std::io::Error },
    #[error(transparent)]
    Mcap(#[from] dynforge_shard::ShardError),
    #[error("collision geometry: {0}")]
    Mesh(#[from] dynforge_robot::collision::MeshError),
    #[error("no collision-free motion found: {0} kept touching (check the start pose, or loosen the limits)")]
    Collision(String),
}
