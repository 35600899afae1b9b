//! The jobs of a run: robot-major order (consecutive jobs share a robot, so a worker plans each tour once), and
//! deterministic partitions so several hosts can split one dataset.

use dynforge_proto::job::Job;
use dynforge_proto::ledger::Entry;
use dynforge_proto::manifest::Manifest;
use dynforge_proto::manifest::Partition;

/// Stable identity of a job within a run, recorded in the ledger.
pub fn job_id(job: &Job, trajectories: u32) -> u64 {
    job.robot * trajectories as u64 + job.trajectory as u64
}

/// Every job of the partition, robot-major.
pub fn jobs(seed: u64, robots: u64, trajectories: u32, partition: Partition) -> impl Iterator<Item = Job> {
    (0..robots)
        .filter(move |r| partition.contains(*r))
        .flat_map(move |robot| (0..trajectories).map(move |trajectory| Job { seed, robot, trajectory }))
}

/// The jobs of a run: what a manifest plans. Counted and tested without listing them, so that neither depends on
/// how many there are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Plan {
    pub seed: u64,
    pub robots: u64,
    pub trajectories: u32,
    pub partition: Partition,
}

impl Plan {
    pub fn of(m: &Manifest) -> Plan {
        Plan { seed: m.seed, robots: m.robots, trajectories: m.trajectories, partition: m.partition }
    }

    /// How many jobs it has.
    pub fn len(&self) -> u64 {
        let (i, n) = (self.partition.index as u64, self.partition.count as u64);
        let robots = if self.robots > i { (self.robots - i).div_ceil(n) } else { 0 };
        robots.saturating_mul(self.trajectories as u64)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Every job, robot-major, as [`jobs`] lists them.
    pub fn jobs(&self) -> impl Iterator<Item = Job> + use<> {
        jobs(self.seed, self.robots, self.trajectories, self.partition)
    }

    /// Whether the ledger record `e` is of one of its jobs: its robot is one of the partition's, its trajectory one
    /// of a robot's, and its job id the one they give.
    pub fn records(&self, e: &Entry) -> bool {
        e.robot < self.robots
            && e.trajectory < self.trajectories
            && self.partition.contains(e.robot)
            && e.job_id == job_id(&e.job(self.seed), self.trajectories)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn partitions_cover_the_run_exactly_once() {
        let all: Vec<Job> = jobs(5, 23, 16, Partition::WHOLE).collect();
        assert_eq!(all.len(), 23 * 16);
        let mut union = Vec::new();
        for i in 0..3 {
            union.extend(jobs(5, 23, 16, Partition { index: i, count: 3 }));
        }
        assert_eq!(union.len(), all.len());
        assert_eq!(union.iter().collect::<HashSet<_>>(), all.iter().collect::<HashSet<_>>());
        let ids: HashSet<u64> = all.iter().map(|j| job_id(j, 16)).collect();
        assert_eq!(ids.len(), all.len());
    }

    #[test]
    fn a_plan_counts_and_recognises_its_jobs_without_listing_them() {
        for (robots, index, count) in [(23, 0, 3), (23, 2, 3), (2, 2, 3), (1, 0, 1), (0, 0, 1)] {
            let partition = Partition { index, count };
            let plan = Plan { seed: 5, robots, trajectories: 16, partition };
            assert_eq!(plan.len(), plan.jobs().count() as u64, "{robots} robots, partition {partition}");
            for j in plan.jobs() {
                let e = Entry {
                    job_id: job_id(&j, 16),
                    robot: j.robot,
                    trajectory: j.trajectory,
                    status: dynforge_proto::ledger::Status::Discarded { reason: "x".into() },
                };
                assert!(plan.records(&e));
                assert!(!plan.records(&Entry { job_id: e.job_id + 1, ..e.clone() }), "another job's id");
                assert!(!plan.records(&Entry { robot: j.robot + robots, ..e.clone() }), "a robot beyond the plan");
            }
        }
        // Ten billion robots are counted, not listed.
        let huge = Plan { seed: 0, robots: 10_000_000_000, trajectories: 16, partition: Partition::WHOLE };
        assert_eq!(huge.len(), 160_000_000_000);
    }

    #[test]
    fn partition_parsing_rejects_nonsense() {
        assert_eq!("1/4".parse::<Partition>().unwrap(), Partition { index: 1, count: 4 });
        for bad in ["3/2", "2/2", "0/0", "1", "a/2", "1/b", "-1/2"] {
            assert!(bad.parse::<Partition>().is_err(), "{bad}");
        }
    }
}
