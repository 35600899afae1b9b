//! dynforge's transport between the dataset coordinator and its worker processes, over iceoryx2 shared memory.
//!
//! Per worker slot `k`, a request-response service `dynforge/worker/{k}/jobs` (coordinator = client, worker =
//! server; one job in flight, answered by progress reports then exactly one final report) and an event service
//! `dynforge/worker/{k}/poke` (the coordinator wakes the worker). Shared by all: the event service
//! `dynforge/reports` (workers wake the coordinator after each report) and the publish-subscribe service
//! `dynforge/status` (history 1) for monitors. Every name lives under the run's [`RunId`] prefix.
//!
//! Nothing is pushed on a worker's death: the coordinator polls [`Coordinator::dead_workers`] on a tick and
//! catches hung workers itself with a deadline on [`Coordinator::last_heard`].
//!
//! ```no_run
//! # use dynforge_ipc::*;
//! # use dynforge_proto::job::{Job, JobRequest};
//! # use std::time::Duration;
//! # fn main() -> Result<(), IpcError> {
//! let run = RunId::for_dir(std::path::Path::new("data"))?;
//! let mut coord = Coordinator::new(&run, 2)?;
//! // spawn the worker process of slot 0 (it calls Worker::new(&run, 0)), then:
//! coord.attach_worker(0)?;
//! while !coord.worker_ready(0) { std::thread::sleep(Duration::from_millis(5)); }
//! coord.send(0, &JobRequest { job_id: 1, job: Job { seed: 1, robot: 7, trajectory: 3 } })?;
//! for (slot, report) in coord.wait(Duration::from_millis(100))? { println!("{slot}: {report:?}"); }
//! # Ok(()) }
//! ```

mod coordinator;
mod error;
mod monitor;
mod run;
mod services;
mod types;
mod worker;

pub use coordinator::{Coordinator, REPOKE_INTERVAL};
pub use error::IpcError;
pub use monitor::StatusReader;
pub use run::{RunId, cleanup_stale};
pub use types::{FIXED_STR_CAPACITY, FixedStr, StatusMsg};
pub use worker::{COORDINATOR_CHECK_INTERVAL, SLOT_WAIT, Worker};
