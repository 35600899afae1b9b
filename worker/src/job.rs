//! A job end to end: generate the robot, plan its tour, simulate one trajectory, write the shard or report the
//! discard.

use std::collections::BTreeMap;
use std::path::Path;

use dynforge_proto::LABELS;
use dynforge_proto::generator::{GENERATOR_VERSION, GeneratorConfig};
use dynforge_proto::job::Job;
use dynforge_proto::shard::{JobRecord, META_JOB, META_LABELS, META_TRAJECTORY, RobotSource};
use dynforge_robot::generator::{GeneratedRobot, generate};
use dynforge_robot::parameters::labels_of;
use dynforge_shard::Metadata;

use nalgebra::Vector3;

use crate::collision::CollisionModel;
use crate::family::FamilyRunner;
use crate::output::{JobError, Outcome, write_shard};
use crate::simulate::{Arm, Discard, Simulation, simulate};
use crate::trajectory::{Config6, Move, PlanError, waypoints};
use dynforge_proto::sim::SimConfig;

/// A simulated job: the robot, and its move with the recording or the discard.
pub struct Simulated {
    pub robot: GeneratedRobot,
    pub result: Result<(Move, Simulation), Discard>,
}

/// A generated robot and its waypoint tour (or why none was found), for (seed, robot).
struct Planned {
    seed: u64,
    id: u64,
    robot: GeneratedRobot,
    tour: Result<Vec<Config6>, PlanError>,
}

/// Runs jobs, keeping the last robot and its tour: consecutive jobs of one robot plan once.
pub struct Runner {
    generator: GeneratorConfig,
    sim: SimConfig,
    cache: Option<Planned>,
    family: Option<FamilyRunner>,
}

impl Runner {
    pub fn new(generator: GeneratorConfig, sim: SimConfig) -> Self {
        Runner { generator, sim, cache: None, family: None }
    }

    /// A runner of a family's jobs instead of the generator's.
    pub fn of_family(family: FamilyRunner, sim: SimConfig) -> Self {
        Runner { family: Some(family), ..Runner::new(GeneratorConfig::default(), sim) }
    }

    pub fn sim_config(&self) -> &SimConfig {
        &self.sim
    }

    fn planned(&mut self, job: &Job) -> Result<&Planned, JobError> {
        let hit = matches!(&self.cache, Some(p) if p.seed == job.seed && p.id == job.robot);
        if !hit {
            let robot = generate(&self.generator, job.seed, job.robot)?;
            let tour = waypoints(&robot, job.seed, &self.sim.trajectory);
            self.cache = Some(Planned { seed: job.seed, id: job.robot, robot, tour });
        }
        Ok(self.cache.as_ref().expect("filled above"))
    }

    /// Simulates a job without writing anything.
    pub fn simulate(&mut self, job: &Job) -> Result<Simulated, JobError> {
        let sim = self.sim.clone();
        let Planned { robot, tour, .. } = self.planned(job)?;
        let robot = robot.clone();
        let result = match tour {
            Ok(tour) => {
                let mv = Move::of_tour(&robot.model, tour, job.trajectory as usize, &sim.trajectory);
                simulate_tour(&robot, &mv, &sim).map(|rec| (mv, rec))
            }
            Err(e) => Err(Discard::Planning(e.clone())),
        };
        Ok(Simulated { robot, result })
    }

    /// Runs a job and writes its shard into `out_dir`.
    pub fn run(&mut self, job: &Job, out_dir: &Path) -> Result<Outcome, JobError> {
        if let Some(family) = &self.family {
            return family.run(job, &self.sim, out_dir);
        }
        let Simulated { robot, result } = match self.simulate(job) {
            Ok(s) => s,
            Err(JobError::Model(e)) => return Ok(Outcome::Discarded(Discard::Rejected(e))),
            Err(e) => return Err(e),
        };
        let (mv, rec) = match result {
            Ok(done) => done,
            Err(d) => return Ok(Outcome::Discarded(d)),
        };
        let metadata = self.metadata(job, &robot, &mv)?;
        write_shard(&out_dir.join(job.shard_name(self.sim.engine.name())), &robot.model, &robot.urdf(), &rec, &metadata)
    }

    fn metadata(&self, job: &Job, robot: &GeneratedRobot, mv: &Move) -> Result<Metadata, JobError> {
        let y = labels_of(&robot.model)?;
        let joined = |q: &Config6| q.iter().map(|v| format!("{v}")).collect::<Vec<_>>().join(" ");
        let source = RobotSource::Generator { version: GENERATOR_VERSION.to_string() };
        let job_meta = JobRecord { job: *job, engine: self.sim.engine.name().to_string(), dt: self.sim.dt, source };
        let job_meta = job_meta.to_metadata();
        let label_meta = LABELS.iter().zip(y).map(|(l, v)| (l.name.to_string(), format!("{v}"))).collect();
        let traj_meta = BTreeMap::from([
            ("start".to_string(), joined(&mv.start)),
            ("goal".to_string(), joined(&mv.goal)),
            ("move_end".to_string(), format!("{}", mv.duration)),
            ("hold_end".to_string(), format!("{}", mv.duration + mv.hold)),
        ]);
        Ok(BTreeMap::from([
            (META_JOB.to_string(), job_meta),
            (META_LABELS.to_string(), label_meta),
            (META_TRAJECTORY.to_string(), traj_meta),
        ]))
    }
}

/// Simulates a move of a generated robot, checked against its own bodies: the gravity-aware gain follows the tip of
/// its last beam.
pub fn simulate_tour(robot: &GeneratedRobot, mv: &Move, cfg: &SimConfig) -> Result<Simulation, Discard> {
    let last = robot.beams.len() - 1;
    let collision = CollisionModel::new(robot, 0.0);
    let arm = Arm {
        model: &robot.model,
        tip: (last, Vector3::new(0.0, 0.0, robot.beams[last].length)),
        collision: &collision,
        feedforward: None,
    };
    simulate(&arm, mv, cfg)
}
