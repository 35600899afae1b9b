//! The jobs of a run: robot-major order (consecutive jobs share a robot, so a worker plans each tour once), and
//! deterministic partitions so several hosts can split one dataset.

use std::fmt;
use std::str::FromStr;

use dynforge_worker::job::Job;
use serde::{Deserialize, Serialize};

/// `i/n`: this host runs the robots `r` with `r % n == i`. The union of `0/n .. (n-1)/n` is the whole run, and
/// partitions never share a robot (so they never share a shard).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Partition {
    pub index: u32,
    pub count: u32,
}

impl Partition {
    pub const WHOLE: Partition = Partition { index: 0, count: 1 };

    pub fn contains(&self, robot: u64) -> bool {
        robot % self.count as u64 == self.index as u64
    }
}

impl fmt::Display for Partition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Partition {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (i, n) = s.split_once('/').ok_or_else(|| format!("partition '{s}' is not of the form i/n"))?;
        let index: u32 = i.trim().parse().map_err(|_| format!("partition '{s}': '{i}' is not a number"))?;
        let count: u32 = n.trim().parse().map_err(|_| format!("partition '{s}': '{n}' is not a number"))?;
        if count == 0 || index >= count {
            return Err(format!("partition '{s}': i must be in 0..n (n > 0)"));
        }
        Ok(Partition { index, count })
    }
}

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
