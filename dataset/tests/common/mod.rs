//! Helpers shared by the integration tests of the dataset and the trainer (the trainer's include this file).
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use dynforge_robot::generator::{GeneratedRobot, generate};

use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::job::Job;
use dynforge_proto::sim::SimConfig;
use dynforge_worker::job::Runner;
use dynforge_worker::output::Outcome;

/// Simulates `job` with the default configuration and writes its shard into `dir`; the shard's path and robot.
pub fn write_shard(job: &Job, dir: &Path) -> (PathBuf, GeneratedRobot) {
    let mut runner = Runner::new(GeneratorConfig::default(), SimConfig::default());
    let path = match runner.run(job, dir).unwrap() {
        Outcome::Written { path, .. } => path,
        Outcome::Discarded(d) => panic!("{d}"),
    };
    (path, generate(&GeneratorConfig::default(), job.seed, job.robot).unwrap())
}
