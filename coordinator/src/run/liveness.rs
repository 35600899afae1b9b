//! Workers that died (their iceoryx2 node is dead, or their process exited) or hung (no final report within the
//! job timeout) are killed and replaced; their jobs go back to the queue through `settle`.
//!
//! Start-up is bounded too: a worker process that has not opened its job service within the start deadline, or that
//! ends before it has, failed to start. It is replaced up to [`MAX_FAILED_STARTS`] times in a row; then its slot is
//! given up, and when no slot is left the run ends with an error naming the worker's log and its last error. (A broken
//! manifest, shared memory another user spoiled, a stopped process: each would otherwise cost a respawn loop that
//! never ends, or a run that waits for ever with nothing in flight.)

use std::path::Path;
use std::time::{Duration, Instant};

use super::{GenerateError, Observer, Run};

/// Failed starts in a row after which a worker slot is given up.
pub const MAX_FAILED_STARTS: u32 = 3;

/// The least time a worker process is given to start, whatever the job timeout (the start deadline is the longer of
/// the two): a start takes well under a second, but it opens shared memory and may wait for its slot's previous
/// process to go.
pub const MIN_START_DEADLINE: Duration = Duration::from_secs(5);

/// A worker slot's start-up.
#[derive(Debug, Clone, Copy)]
pub(super) struct Start {
    /// When its process was started, until it is ready for jobs.
    since: Option<Instant>,
    /// Failed starts in a row.
    failed: u32,
    /// No more starts: it failed [`MAX_FAILED_STARTS`] times in a row.
    given_up: bool,
}

impl Start {
    pub(super) fn new() -> Self {
        Start { since: Some(Instant::now()), failed: 0, given_up: false }
    }

    /// Its worker is ready for jobs: started.
    pub(super) fn ready() -> Self {
        Start { since: None, failed: 0, given_up: false }
    }
}

impl Run<'_> {
    fn start_deadline(&self) -> Duration {
        self.cfg.job_timeout.max(MIN_START_DEADLINE)
    }

    pub(super) fn liveness(&mut self, observer: &mut dyn Observer) -> Result<(), GenerateError> {
        let mut lost: Vec<(usize, String)> =
            self.ipc.dead_workers().into_iter().map(|k| (k, "its worker died".to_string())).collect();
        for (k, status) in self.procs.exited() {
            if !lost.iter().any(|(s, _)| *s == k) {
                lost.push((k, format!("its worker exited ({status})")));
            }
        }
        let timeout = self.cfg.job_timeout;
        for (k, started) in self.running.iter().enumerate().filter_map(|(k, r)| r.map(|(_, t)| (k, t))) {
            if started.elapsed() > timeout && !lost.iter().any(|(s, _)| *s == k) {
                lost.push((k, format!("its worker hung (no result after {} s)", timeout.as_secs_f64())));
            }
        }
        let deadline = self.start_deadline();
        for k in 0..self.starts.len() {
            let Some(since) = self.starts[k].since else { continue };
            if self.ipc.worker_ready(k) {
                self.starts[k] = Start::ready();
            } else if since.elapsed() > deadline && !lost.iter().any(|(s, _)| *s == k) {
                lost.push((k, format!("its worker was not ready within {} s", deadline.as_secs_f64())));
            }
        }
        for (k, why) in lost {
            self.procs.kill(k);
            if let Some((job, _)) = self.running[k].take() {
                self.settle(job, None, &why, observer)?;
            }
            if self.starts[k].since.is_some() {
                self.failed_start(k, &why, observer);
            }
            if !self.interrupted && !self.starts[k].given_up && !self.pending.is_empty() {
                self.progress.respawns += 1;
                self.procs.spawn(k)?;
                self.ipc.attach_worker(k)?;
                self.starts[k].since = Some(Instant::now());
            }
        }
        Ok(())
    }

    /// Counts a failed start of slot `k` (`why`), says so with the worker's last error, and gives the slot up after
    /// [`MAX_FAILED_STARTS`] in a row; the run ends when no slot is left.
    fn failed_start(&mut self, k: usize, why: &str, observer: &mut dyn Observer) {
        let start = &mut self.starts[k];
        start.failed += 1;
        let log = self.procs.log(k);
        let said = last_error(&log).map_or(String::new(), |e| format!(": {e}"));
        let why = why.strip_prefix("its worker ").unwrap_or(why);
        let detail = format!("{why}; its log {}{said}", log.display());
        if start.failed < MAX_FAILED_STARTS {
            let again = format!("starting it again ({} of {MAX_FAILED_STARTS})", start.failed + 1);
            observer.message(&format!("worker {k} failed to start ({detail}); {again}"));
            return;
        }
        start.given_up = true;
        observer.message(&format!("worker {k} failed to start ({detail}): {MAX_FAILED_STARTS} times in a row"));
        if self.starts.iter().all(|s| s.given_up) {
            self.no_workers = Some(format!("worker {k}, {MAX_FAILED_STARTS} times in a row: {detail}"));
        }
    }
}

/// The last error a worker's log holds (the line `error: ...` its process ended with), else its last line.
fn last_error(log: &Path) -> Option<String> {
    let text = std::fs::read(log).ok()?;
    let text = String::from_utf8_lossy(&text[text.len().saturating_sub(64 * 1024)..]).into_owned();
    let lines: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    let line = lines.iter().rev().find(|l| l.starts_with("error:")).or(lines.last())?;
    Some(line.chars().take(400).collect())
}
