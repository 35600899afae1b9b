//! dynforge's coordinator: plans a dataset's jobs, hands them to worker processes over iceoryx2, and keeps the
//! durable record (manifest + ledger + atomic shards) that makes interrupted runs resumable and datasets verifiable.
//!
//! A run directory holds `manifest.toml` (what the dataset is), `ledger.tsv` (one fsync'd line per finished job),
//! `shards/` (one MCAP file per kept job) and `logs/` (one log per worker slot).

// Index loops over worker slots mirror the per-slot state vectors they update together.
#![allow(clippy::needless_range_loop)]

pub mod merge;
pub mod plan;
pub mod prune;
pub mod run;
pub mod status;
pub mod verify;

// The run directory's ledger and lock are file contracts every crate reading a run directory shares.
