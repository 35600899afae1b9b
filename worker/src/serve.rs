//! The worker process: serves the jobs of a run directory's coordinator, over iceoryx2, until told to stop.

use std::path::Path;

use dynforge_ipc::{IpcError, RunId, Worker};

use dynforge_proto::job::{JobReport, JobRequest};
use dynforge_proto::manifest::{Manifest, ManifestError};
use dynforge_proto::run_dir::{MANIFEST, SHARDS};

use crate::job::Runner;
use crate::output::Outcome;

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The worker simulates with the manifest's generator and simulation settings (the coordinator checked the rest
    /// before starting it).
    #[error("{0} (workers are started by `dynforge generate`)")]
    Manifest(#[from] ManifestError),
    #[error("{0}: no run manifest (workers are started by `dynforge generate`)")]
    NoManifest(String),
    #[error(transparent)]
    Ipc(#[from] IpcError),
    #[error(transparent)]
    Family(#[from] crate::family::FamilySetupError),
}

/// Fault injection for tests of the coordinator's hung-worker deadline: when set to a number of seconds, every
/// worker sleeps that long before running each job, so "hung" does not depend on how fast the machine is.
pub const STALL_ENV: &str = "DYNFORGE_FAULT_WORKER_STALL";

/// Fault injection for tests of the coordinator's start deadline: when set to a number of seconds, every worker
/// sleeps that long before it joins the run, as one stopped or stuck in its start-up would.
pub const START_STALL_ENV: &str = "DYNFORGE_FAULT_WORKER_START_STALL";

/// Seconds of the fault injection `name`, if set.
fn stall_of(name: &str) -> Option<f64> {
    std::env::var(name).ok().and_then(|s| s.parse::<f64>().ok()).filter(|s| s.is_finite() && *s > 0.0)
}

/// Serves slot `slot` of the run in `dir`. Returns when the coordinator stops the worker or goes away.
pub fn serve(dir: &Path, slot: usize) -> Result<u64, ServeError> {
    if let Some(seconds) = stall_of(START_STALL_ENV) {
        std::thread::sleep(std::time::Duration::from_secs_f64(seconds));
    }
    let stall = stall_of(STALL_ENV);
    let manifest =
        Manifest::load(dir)?.ok_or_else(|| ServeError::NoManifest(dir.join(MANIFEST).display().to_string()))?;
    let mut runner = match &manifest.family {
        Some(family) => Runner::of_family(crate::family::FamilyRunner::new(dir, family)?, manifest.sim),
        None => Runner::new(manifest.generator, manifest.sim),
    };
    let run = RunId::for_dir(dir)?;
    let mut worker = Worker::new(&run, slot)?;
    let shards = dir.join(SHARDS);
    let mut served = 0;
    while let Some(request) = worker.next_job()? {
        let JobRequest { job_id, job } = request;
        if let Some(seconds) = stall {
            std::thread::sleep(std::time::Duration::from_secs_f64(seconds));
        }
        let report = match runner.run(&job, &shards) {
            Ok(Outcome::Written { samples, content_hash, .. }) => {
                JobReport::Done { job_id, samples: samples as u64, content_hash }
            }
            Ok(Outcome::Discarded(d)) => {
                eprintln!("robot {} trajectory {}: discarded: {d}", job.robot, job.trajectory);
                JobReport::Discarded { job_id, reason: d.code().into() }
            }
            Err(e) => {
                eprintln!("robot {} trajectory {}: error: {e}", job.robot, job.trajectory);
                JobReport::Failed { job_id, message: e.to_string() }
            }
        };
        match worker.report(&report) {
            Ok(()) | Err(IpcError::JobAbandoned(_)) => {}
            Err(e) => return Err(e.into()),
        }
        served += 1;
    }
    Ok(served)
}
