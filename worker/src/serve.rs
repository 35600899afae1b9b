//! The worker process: serves the jobs of a run directory's coordinator, over iceoryx2, until told to stop.

use std::path::Path;

use dynforge_ipc::{IpcError, JobReport, RunId, Worker};
use dynforge_proto::run_dir::{MANIFEST, SHARDS};
use dynforge_robot::generator::GeneratorConfig;

use crate::job::{Job, Outcome, Runner};
use crate::simulate::SimConfig;

#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("{path}: {problem} (workers are started by `dynforge generate`)")]
    Manifest { path: String, problem: String },
    #[error(transparent)]
    Ipc(#[from] IpcError),
}

/// What a worker takes from the run manifest: the robots' generator and the simulation settings (the coordinator
/// owns the rest of the manifest and checks it before starting any worker).
#[derive(serde::Deserialize)]
struct JobSettings {
    generator: GeneratorConfig,
    sim: SimConfig,
}

fn settings(dir: &Path) -> Result<JobSettings, ServeError> {
    let path = dir.join(MANIFEST);
    let fail = |problem: String| ServeError::Manifest { path: path.display().to_string(), problem };
    let text = std::fs::read_to_string(&path).map_err(|e| fail(e.to_string()))?;
    toml::from_str(&text).map_err(|e| fail(format!("not a run manifest: {e}")))
}

/// Fault injection for tests of the coordinator's hung-worker deadline: when set to a number of seconds, every
/// worker sleeps that long before running each job, so "hung" does not depend on how fast the machine is.
pub const STALL_ENV: &str = "DYNFORGE_FAULT_WORKER_STALL";

/// Serves slot `slot` of the run in `dir`. Returns when the coordinator stops the worker or goes away.
pub fn serve(dir: &Path, slot: usize) -> Result<u64, ServeError> {
    let stall = std::env::var(STALL_ENV).ok().and_then(|s| s.parse::<f64>().ok()).filter(|s| s.is_finite() && *s > 0.0);
    let settings = settings(dir)?;
    let run = RunId::for_dir(dir)?;
    let mut worker = Worker::new(&run, slot)?;
    let mut runner = Runner::new(settings.generator, settings.sim);
    let shards = dir.join(SHARDS);
    let mut served = 0;
    while let Some(request) = worker.next_job()? {
        let job = Job { seed: request.seed, robot: request.robot, trajectory: request.trajectory };
        let job_id = request.job_id;
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
