//! Why a log could not be read, whatever its format.

use crate::samples::SamplesError;

/// Why a log could not be read: its container, its joint states, its run's manifest, or its content.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error(transparent)]
    Shard(#[from] dynforge_shard::ShardError),
    #[error(transparent)]
    Samples(#[from] SamplesError),
    #[error(transparent)]
    Manifest(#[from] dynforge_proto::manifest::ManifestError),
    #[error("{file}: {problem}")]
    Content { file: String, problem: String },
}
