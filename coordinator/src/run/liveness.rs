//! Workers that died (their iceoryx2 node is dead, or their process exited) or hung (no final report within the
//! job timeout) are killed and replaced; their jobs go back to the queue through `settle`.
//!
//! Start-up is bounded too: a worker process that has not opened its job service within the start deadline, or that
//! ends before it has, failed to start. It is replaced up to [`MAX_FAILED_STARTS`] times in a row; then its slot is
//! given up, and when no slot is left the run ends with an error naming the worker's log and its last error. (A broken
//! manifest, shared memory another user spoiled, a stopped process: each would otherwise cost a respawn loop that
//! never ends, or a run that waits for ever with nothing in flight.)

use std::path::Path;
use std::process::ExitStatus;
use std::time::{Duration, Instant};

use dynforge_proto::job::Job;

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
    pub(super) fn liveness(&mut self, observer: &mut dyn Observer) -> Result<(), GenerateError> {
        let dead = self.ipc.dead_workers();
        let exited = self.procs.exited();
        for k in 0..self.starts.len() {
            if self.starts[k].since.is_some() && self.ipc.worker_ready(k) {
                self.starts[k] = Start::ready();
            }
        }
        let lost = lost_slots(dead, exited, &self.running, &self.starts, self.cfg.job_timeout, Instant::now());
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

/// The worker slots to replace at `now`, each once, with why (the first reason found): dead to iceoryx2 (`dead`),
/// exited (`exited`), hung (`running` a job for longer than `job_timeout`), or not ready for jobs (`starts`, where
/// the slots seen ready are marked so) by the start deadline, the longer of `job_timeout` and [`MIN_START_DEADLINE`].
fn lost_slots(
    dead: Vec<usize>,
    exited: Vec<(usize, ExitStatus)>,
    running: &[Option<(Job, Instant)>],
    starts: &[Start],
    job_timeout: Duration,
    now: Instant,
) -> Vec<(usize, String)> {
    let mut lost: Vec<(usize, String)> = dead.into_iter().map(|k| (k, "its worker died".to_string())).collect();
    for (k, status) in exited {
        if !lost.iter().any(|(s, _)| *s == k) {
            lost.push((k, format!("its worker exited ({status})")));
        }
    }
    for (k, started) in running.iter().enumerate().filter_map(|(k, r)| r.map(|(_, t)| (k, t))) {
        if now.saturating_duration_since(started) > job_timeout && !lost.iter().any(|(s, _)| *s == k) {
            lost.push((k, format!("its worker hung (no result after {} s)", job_timeout.as_secs_f64())));
        }
    }
    let deadline = job_timeout.max(MIN_START_DEADLINE);
    for (k, start) in starts.iter().enumerate() {
        let Some(since) = start.since else { continue };
        if now.saturating_duration_since(since) > deadline && !lost.iter().any(|(s, _)| *s == k) {
            lost.push((k, format!("its worker was not ready within {} s", deadline.as_secs_f64())));
        }
    }
    lost
}

/// The last error a worker's log holds (the line `error: ...` its process ended with), else its last line.
fn last_error(log: &Path) -> Option<String> {
    let text = std::fs::read(log).ok()?;
    let text = String::from_utf8_lossy(&text[text.len().saturating_sub(64 * 1024)..]).into_owned();
    let lines: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    let line = lines.iter().rev().find(|l| l.starts_with("error:")).or(lines.last())?;
    Some(line.chars().take(400).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::process::ExitStatusExt;

    const JOB: Job = Job { seed: 1, robot: 0, trajectory: 0 };

    fn secs(s: f64) -> Duration {
        Duration::from_secs_f64(s)
    }

    fn slots(lost: &[(usize, String)]) -> Vec<usize> {
        lost.iter().map(|(k, _)| *k).collect()
    }

    #[test]
    fn a_job_running_longer_than_the_timeout_marks_its_worker_hung() {
        let t0 = Instant::now();
        let timeout = secs(10.0);
        let running = [Some((JOB, t0)), Some((JOB, t0 + secs(5.0))), None];
        let starts = [Start::ready(); 3];
        let at = |s: f64| lost_slots(vec![], vec![], &running, &starts, timeout, t0 + secs(s));
        assert!(at(9.9).is_empty(), "within its timeout a job is not hung");
        assert!(at(10.0).is_empty(), "a job gets its whole timeout");
        let lost = at(10.5);
        assert_eq!(slots(&lost), [0], "only the job started first is overdue; an idle worker never is");
        assert!(lost[0].1.contains("hung"), "{}", lost[0].1);
        assert_eq!(slots(&at(15.5)), [0, 1]);
    }

    /// A slot listed twice would be settled and respawned twice: its job re-queued twice, or a fresh worker killed.
    #[test]
    fn a_worker_lost_several_ways_at_once_is_replaced_once_for_the_first_reason() {
        let t0 = Instant::now();
        let timeout = secs(1.0);
        let running = [Some((JOB, t0)), Some((JOB, t0)), Some((JOB, t0)), None];
        let starts = [Start::ready(); 4];
        let exited = vec![(0, ExitStatus::from_raw(1 << 8)), (1, ExitStatus::from_raw(9))];
        let lost = lost_slots(vec![0], exited, &running, &starts, timeout, t0 + secs(2.0));
        let mut found = slots(&lost);
        found.sort();
        assert_eq!(found, [0, 1, 2], "dead, exited and hung slots, each once");
        let why = |k: usize| lost.iter().find(|(s, _)| *s == k).unwrap().1.clone();
        assert!(why(0).contains("died"), "{}", why(0));
        assert!(why(1).contains("exited"), "{}", why(1));
        assert!(why(2).contains("hung"), "{}", why(2));
    }

    /// A short job timeout must not cut a worker's start short (it opens shared memory, may wait for its slot's
    /// previous process); a long one stretches the start deadline with it.
    #[test]
    fn a_starting_worker_gets_the_longer_of_the_job_timeout_and_the_minimum_start_deadline() {
        let t0 = Instant::now();
        let starting = Start { since: Some(t0), failed: 0, given_up: false };
        let starts = [starting, Start::ready()];
        let running = [None, None];
        let at =
            |timeout: Duration, after: Duration| lost_slots(vec![], vec![], &running, &starts, timeout, t0 + after);
        let short = secs(1.0);
        assert!(at(short, secs(2.0)).is_empty());
        let late = at(short, MIN_START_DEADLINE + secs(0.1));
        assert_eq!(slots(&late), [0], "only the slot still starting; a ready one has no start deadline");
        assert!(late[0].1.contains("not ready"), "{}", late[0].1);
        let long = MIN_START_DEADLINE * 4;
        assert!(at(long, MIN_START_DEADLINE + secs(0.1)).is_empty());
        assert_eq!(slots(&at(long, long + secs(0.1))), [0]);
    }

    #[test]
    fn a_worker_log_s_last_error_is_its_last_error_line_else_its_last_line() {
        let tmp = tempfile::tempdir().unwrap();
        let log = tmp.path().join("worker-0.log");
        assert_eq!(last_error(&log), None, "no log yet");
        std::fs::write(&log, "").unwrap();
        assert_eq!(last_error(&log), None, "an empty log");
        std::fs::write(&log, "starting\nerror: first\n  error: manifest unreadable  \nshutting down\n\n").unwrap();
        assert_eq!(last_error(&log).as_deref(), Some("error: manifest unreadable"));
        std::fs::write(&log, "starting\nwaiting for slot\n\n  \n").unwrap();
        assert_eq!(last_error(&log).as_deref(), Some("waiting for slot"));
        let long = format!("error: {}", "x".repeat(2000));
        std::fs::write(&log, &long).unwrap();
        let said = last_error(&log).unwrap();
        assert!(said.chars().count() < long.len() && long.starts_with(&said), "a long line is cut, not lost");
    }
}
