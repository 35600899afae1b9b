//! How a run goes: counts by outcome for displays ([`Observer`]) and the live record monitors read
//! (`dynforge status`, over iceoryx2's status service).

use std::collections::BTreeMap;

use dynforge_ipc::StatusMsg;
use dynforge_proto::job::Job;

use super::Run;
use dynforge_proto::ledger::{Entry, Status};

/// How the run is going, for progress displays.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Progress {
    /// Jobs of this run (after the partition), including those finished in earlier runs.
    pub total: u64,
    /// Finished before this invocation (resumed).
    pub resumed: u64,
    pub done: u64,
    pub discarded: u64,
    pub failed: u64,
    pub reasons: BTreeMap<String, u64>,
    pub in_flight: u32,
    pub workers_alive: u32,
    pub respawns: u32,
    /// Finished jobs per second in this invocation.
    pub rate: f64,
    /// Per worker slot: the job it runs, if any.
    pub slots: Vec<Option<Job>>,
    /// CPU seconds the coordinator process used (at the end of a run; 0 where the OS does not say).
    pub cpu_seconds: f64,
}

impl Progress {
    pub fn finished(&self) -> u64 {
        self.done + self.discarded + self.failed
    }

    /// Counts one finished job.
    pub fn record(&mut self, status: &Status) {
        match status {
            Status::Done { .. } => self.done += 1,
            Status::Discarded { reason } => {
                self.discarded += 1;
                *self.reasons.entry(reason.clone()).or_default() += 1;
            }
            Status::Failed { .. } => self.failed += 1,
        }
    }

    /// Counts of a ledger's records (the last record of a job wins) for a run of `total` jobs.
    pub fn from_ledger(total: u64, entries: &[Entry]) -> Progress {
        let mut p = Progress { total, ..Progress::default() };
        for e in dynforge_proto::ledger::latest(entries).values() {
            p.record(&e.status);
        }
        p
    }
}

impl std::fmt::Display for Progress {
    /// One line: counts by outcome (discards by reason), in flight, rate.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let reasons = self.reasons.iter().map(|(r, n)| format!("{r} {n}")).collect::<Vec<_>>().join(", ");
        write!(
            f,
            "done {} | discarded {}{} | failed {} | in flight {} | {:.1} jobs/s",
            self.done,
            self.discarded,
            if reasons.is_empty() { String::new() } else { format!(" ({reasons})") },
            self.failed,
            self.in_flight,
            self.rate
        )
    }
}

/// Receives progress (a terminal display, logs, tests).
pub trait Observer {
    fn update(&mut self, p: &Progress);
    fn message(&mut self, text: &str);
}

impl Run<'_> {
    /// Brings the progress up to date and hands it to the observer and to monitors.
    pub(super) fn publish(&mut self, observer: &mut dyn Observer) {
        let p = &mut self.progress;
        p.rate = (p.finished() - p.resumed) as f64 / self.started.elapsed().as_secs_f64().max(1e-9);
        p.in_flight = self.running.iter().filter(|r| r.is_some()).count() as u32;
        p.workers_alive = self.procs.alive() as u32;
        p.slots = self.running.iter().map(|r| r.map(|(j, _)| j)).collect();
        observer.update(p);
        let remaining = p.total - p.finished();
        let status = StatusMsg {
            done: p.done,
            discarded: p.discarded,
            failed: p.failed,
            in_flight: p.in_flight,
            workers_alive: p.workers_alive,
            total: p.total,
            rate_per_s: p.rate,
            updated_unix_ms: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_millis() as u64),
            eta_s: if p.rate > 0.0 { remaining as f64 / p.rate } else { 0.0 },
            coordinator_pid: std::process::id(),
            respawns: p.respawns,
        };
        let _ = self.ipc.publish_status(&status);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(job_id: u64, status: Status) -> Entry {
        Entry { job_id, robot: job_id / 2, trajectory: (job_id % 2) as u32, status }
    }

    fn done() -> Status {
        Status::Done { samples: 5, shard_hash: 9 }
    }

    fn failed() -> Status {
        Status::Failed { message: "its worker died".into() }
    }

    fn discarded(reason: &str) -> Status {
        Status::Discarded { reason: reason.into() }
    }

    /// A job retried after a failure has several records; counting them all would finish more jobs than there are.
    #[test]
    fn ledger_counts_take_each_job_s_latest_record_and_add_up() {
        let entries = vec![
            entry(0, failed()),
            entry(0, done()),
            entry(1, discarded("timeout")),
            entry(2, discarded("collision")),
            entry(3, discarded("timeout")),
            entry(4, done()),
            entry(4, failed()),
            entry(5, failed()),
            entry(5, failed()),
        ];
        let p = Progress::from_ledger(10, &entries);
        assert_eq!(p.total, 10);
        assert_eq!((p.done, p.discarded, p.failed), (1, 3, 2), "jobs 0 done; 1, 2, 3 discarded; 4, 5 failed");
        let jobs: std::collections::BTreeSet<u64> = entries.iter().map(|e| e.job_id).collect();
        assert_eq!(p.finished(), jobs.len() as u64, "one outcome per job");
        assert_eq!(p.reasons.values().sum::<u64>(), p.discarded, "every discard has its reason counted");
        assert_eq!(p.reasons.get("timeout"), Some(&2));
    }

    #[test]
    fn recording_an_outcome_finishes_one_job_of_its_kind() {
        let mut p = Progress { total: 3, ..Progress::default() };
        for (k, status) in [done(), discarded("unstable"), failed()].iter().enumerate() {
            let before = p.clone();
            p.record(status);
            assert_eq!(p.finished(), k as u64 + 1);
            let grew = [(before.done, p.done), (before.discarded, p.discarded), (before.failed, p.failed)];
            assert_eq!(grew.iter().filter(|(a, b)| b == &(a + 1)).count(), 1, "{status:?} counts once");
            assert_eq!(grew[k].1, grew[k].0 + 1, "{status:?} counts as its own kind");
        }
        assert_eq!(p.reasons.get("unstable"), Some(&1));
        let line = p.to_string();
        assert!(line.contains("unstable 1"), "the line names discards by reason: {line}");
    }
}
