//! The jobs of a run: robot-major order (consecutive jobs share a robot, so a worker plans each tour once), and
//! deterministic partitions so several hosts can split one dataset.

use dynforge_proto::job::Job;
pub use dynforge_proto::manifest::Partition;

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
    fn partition_parsing_rejects_nonsense() {
        assert_eq!("1/4".parse::<Partition>().unwrap(), Partition { index: 1, count: 4 });
        for bad in ["3/2", "2/2", "0/0", "1", "a/2", "1/b", "-1/2"] {
            assert!(bad.parse::<Partition>().is_err(), "{bad}");
        }
    }
}
