//! `dynforge status`: how a generation stands, live from its coordinator (the status service) or, when none runs,
//! from its ledger.

use std::path::Path;
use std::time::Duration;

use dynforge_ipc::{RunId, StatusMsg, StatusReader};
use dynforge_proto::run_dir::LEDGER;

use crate::ledger;
use crate::plan::Plan;
use crate::run::Progress;
use dynforge_proto::manifest::Manifest;

#[derive(Debug, thiserror::Error)]
pub enum StatusError {
    #[error("{0}: no run manifest (not a dynforge generate directory)")]
    NoManifest(String),
    #[error(transparent)]
    Manifest(#[from] dynforge_proto::manifest::ManifestError),
    #[error(transparent)]
    Ledger(#[from] ledger::LedgerError),
    #[error(transparent)]
    Ipc(#[from] dynforge_ipc::IpcError),
}

/// A run's standing.
pub enum RunStatus {
    /// A coordinator runs and published this.
    Live(StatusMsg),
    /// None publishes here: the ledger's counts for the manifest's jobs. `holder` is who holds the directory's lock
    /// if someone does: a coordinator on another host sharing the directory (its status is in that host's memory).
    Stopped { progress: Progress, pending: u64, holder: Option<crate::lock::Holder> },
}

/// The standing of the run in `dir`.
pub fn status(dir: &Path) -> Result<RunStatus, StatusError> {
    let run = RunId::for_dir(dir)?;
    if let Some(mut reader) = StatusReader::open(&run)?
        && let Some(s) = reader.latest_timeout(Duration::from_millis(500))
    {
        return Ok(RunStatus::Live(s));
    }
    let manifest = Manifest::load(dir)?.ok_or_else(|| StatusError::NoManifest(dir.display().to_string()))?;
    let plan = Plan::of(&manifest);
    // Records of jobs the manifest does not plan are not its progress (`verify` names them).
    let entries: Vec<ledger::Entry> =
        ledger::read(&dir.join(LEDGER))?.into_iter().filter(|e| plan.records(e)).collect();
    let total = plan.len();
    let progress = Progress::from_ledger(total, &entries);
    let pending = total.saturating_sub(progress.finished());
    Ok(RunStatus::Stopped { progress, pending, holder: crate::lock::holder(dir) })
}

impl RunStatus {
    /// The same figures as JSON (`live` tells which kind).
    pub fn json(&self) -> serde_json::Value {
        match self {
            RunStatus::Live(s) => serde_json::json!({
                "live": true, "total": s.total, "done": s.done, "discarded": s.discarded, "failed": s.failed,
                "in_flight": s.in_flight, "workers_alive": s.workers_alive, "rate_per_s": s.rate_per_s,
                "eta_s": s.eta_s, "respawns": s.respawns, "coordinator_pid": s.coordinator_pid,
            }),
            RunStatus::Stopped { progress: p, pending, holder } => serde_json::json!({
                "live": holder.is_some(), "total": p.total, "done": p.done, "discarded": p.discarded,
                "failed": p.failed, "reasons": p.reasons, "pending": pending,
                "holder": holder.as_ref().map(|h| h.to_string()),
            }),
        }
    }
}

impl std::fmt::Display for RunStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunStatus::Live(s) => write!(
                f,
                "running (coordinator pid {}): {}/{} jobs finished: done {}, discarded {}, failed {}; {} in flight on {} \
                 workers; {:.1} jobs/s, ETA {:.0} s",
                s.coordinator_pid,
                s.done + s.discarded + s.failed,
                s.total,
                s.done,
                s.discarded,
                s.failed,
                s.in_flight,
                s.workers_alive,
                s.rate_per_s,
                s.eta_s
            ),
            RunStatus::Stopped { progress: p, pending, holder } => {
                let reasons: Vec<String> = p.reasons.iter().map(|(r, n)| format!("{r} {n}")).collect();
                let state = match holder {
                    Some(h) => format!("running ({h}), no live figures on this host; the ledger has"),
                    None => "not running:".into(),
                };
                write!(
                    f,
                    "{state} {}/{} jobs finished (done {}, discarded {}{}, failed {}); {pending} pending",
                    p.finished(),
                    p.total,
                    p.done,
                    p.discarded,
                    if reasons.is_empty() { String::new() } else { format!(": {}", reasons.join(", ")) },
                    p.failed
                )
            }
        }
    }
}
