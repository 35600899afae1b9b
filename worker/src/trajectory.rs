//! Collision-free waypoints and the reference motions between them.
//!
//! Each robot gets 16 random joint-space waypoints (the paper's "16 workspace waypoints"), drawn inside the joint
//! limits and accepted only if the robot, with its collision bodies grown by a safety margin, touches neither itself,
//! its pedestal nor the ground there, and along the straight joint-space path from the previous waypoint. The 16
//! waypoints form a closed tour (the path from the last back to the first is checked too), and trajectory `t` of the
//! robot is the move from waypoint `t` to waypoint `t + 1 (mod 16)`: 16 trajectories per robot, as in the paper.
//!
//! A move follows a minimum-jerk reference `q0 + (q1 - q0) (10 s^3 - 15 s^4 + 6 s^5)`, `s = t / T`, whose duration
//! `T` keeps every joint under a fraction of its speed limit (peak speed `1.875 |dq| / T`) and is at least
//! `min_move` seconds; then the reference holds the goal for `hold` seconds. With the defaults a trajectory lasts at
//! least 6 s, enough for a 64 x 64 ms window plus offsets.

use dynforge_proto::sim::TrajectoryConfig;
use dynforge_proto::sim::straight_path_free;
use dynforge_robot::generator::GeneratedRobot;
use dynforge_robot::rng::{Rng, domain};
use dynforge_robot::{Data, Model, forward_kinematics};

use crate::collision::CollisionModel;

/// What a run follows: a reference that starts at rest at `start` and ends at rest at `goal` after `total` seconds.
pub trait Reference {
    fn start(&self) -> &[f64];
    fn goal(&self) -> &[f64];
    /// Duration of the run [s].
    fn total(&self) -> f64;
    /// Reference position, velocity and acceleration at time `t`.
    fn at(&self, t: f64) -> [Vec<f64>; 3];
}

/// Joint-space configuration of a generated (6-joint) arm: the tours plan for the generator's robots only.
pub type Config6 = [f64; 6];

/// Why no waypoints could be found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("robot {robot}: no collision-free waypoint {waypoint} after {attempts} draws")]
pub struct PlanError {
    pub robot: u64,
    pub waypoint: usize,
    pub attempts: usize,
}

/// Checks configurations and straight joint-space paths against a collision model.
pub struct PathChecker<'a> {
    model: &'a Model,
    data: Data,
    collision: CollisionModel,
    step: f64,
}

impl<'a> PathChecker<'a> {
    pub fn new(robot: &'a GeneratedRobot, clearance: f64, step: f64) -> Self {
        PathChecker {
            model: &robot.model,
            data: Data::new(&robot.model),
            collision: CollisionModel::new(robot, clearance),
            step,
        }
    }

    pub fn config_free(&mut self, q: &Config6) -> bool {
        forward_kinematics(self.model, &mut self.data, q);
        self.collision.check(&self.data.o_m_i).is_none()
    }

    /// Both ends and every intermediate configuration no more than `step` apart (in the max norm) are free.
    pub fn path_free(&mut self, a: &Config6, b: &Config6) -> bool {
        let step = self.step;
        straight_path_free(a, b, step, |q| self.config_free(&std::array::from_fn(|j| q[j])))
    }
}

/// The robot's waypoint tour, deterministic in (seed, robot id).
pub fn waypoints(robot: &GeneratedRobot, seed: u64, cfg: &TrajectoryConfig) -> Result<Vec<Config6>, PlanError> {
    let model = &robot.model;
    let mut rng = Rng::stream(seed, &[domain::TRAJECTORY, robot.id]);
    let mut checker = PathChecker::new(robot, cfg.clearance, cfg.path_step);
    let draw = |rng: &mut Rng| -> Config6 {
        std::array::from_fn(|j| {
            let l = &model.joints()[j].limits;
            let (lo, hi) = cfg.waypoint_range(l.lower, l.upper);
            rng.uniform(lo, hi)
        })
    };
    let mut tour: Vec<Config6> = Vec::with_capacity(cfg.waypoints);
    for k in 0..cfg.waypoints {
        let last = k + 1 == cfg.waypoints;
        let mut found = None;
        for _ in 0..cfg.max_attempts {
            let q = draw(&mut rng);
            let ok = checker.config_free(&q)
                && tour.last().is_none_or(|p| checker.path_free(p, &q))
                && (!last || checker.path_free(&q, &tour[0]));
            if ok {
                found = Some(q);
                break;
            }
        }
        tour.push(found.ok_or(PlanError { robot: robot.id, waypoint: k, attempts: cfg.max_attempts })?);
    }
    Ok(tour)
}

/// One trajectory: a minimum-jerk move then a hold.
#[derive(Debug, Clone, PartialEq)]
pub struct Move {
    pub start: Config6,
    pub goal: Config6,
    /// Duration of the move [s].
    pub duration: f64,
    /// Hold at the goal afterwards [s].
    pub hold: f64,
}

impl Move {
    /// Trajectory `t` of a tour.
    pub fn of_tour(model: &Model, tour: &[Config6], t: usize, cfg: &TrajectoryConfig) -> Move {
        let (start, goal) = (tour[t % tour.len()], tour[(t + 1) % tour.len()]);
        let needed = cfg.move_duration((0..6).map(|j| (goal[j] - start[j], model.joints()[j].limits.velocity)));
        Move { start, goal, duration: needed, hold: cfg.hold }
    }
}

impl Reference for Move {
    fn start(&self) -> &[f64] {
        &self.start
    }

    fn goal(&self) -> &[f64] {
        &self.goal
    }

    fn total(&self) -> f64 {
        self.duration + self.hold
    }

    fn at(&self, t: f64) -> [Vec<f64>; 3] {
        let [p, dp, ddp] = dynforge_proto::sim::minimum_jerk(t, self.duration);
        let d: Vec<f64> = (0..self.start.len()).map(|j| self.goal[j] - self.start[j]).collect();
        [
            d.iter().zip(&self.start).map(|(d, s)| s + d * p).collect(),
            d.iter().map(|d| d * dp).collect(),
            d.iter().map(|d| d * ddp).collect(),
        ]
    }
}
