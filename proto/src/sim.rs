//! The simulation settings of a run: controller tuning, waypoint tours, engine and failure checks. A contract: part
//! of every run manifest (the worker simulates with them, the coordinator refuses to resume under others). What
//! they drive lives in `dynforge_worker`: `control` (the gravity-aware PID), `trajectory` (tours and moves),
//! `engine` and `simulate`.

use serde::{Deserialize, Serialize};

/// Everything that shapes a simulation besides the robot and its move.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Control and logging period [s] (the paper logs at 1 kHz).
    pub dt: f64,
    pub engine: EngineKind,
    pub gains: PidGains,
    pub trajectory: TrajectoryConfig,
    /// Periods between collision checks (exact geometry, no margin; the planned path keeps a clearance).
    pub collision_every: usize,
    /// A joint faster than this multiple of its speed limit means the simulation went unstable.
    pub velocity_blowup: f64,
    /// Energy may exceed its start value plus the work done by the motors by this much [J] plus 5 % of the scale.
    pub energy_slack: f64,
    /// At the end of the hold every joint must be this close to the goal [rad], else the run timed out.
    pub goal_tolerance: f64,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            dt: 1e-3,
            engine: EngineKind::Native,
            gains: PidGains::default(),
            trajectory: TrajectoryConfig::default(),
            collision_every: 10,
            velocity_blowup: 1.5,
            energy_slack: 1.0,
            goal_tolerance: 0.02,
        }
    }
}

/// Which engine runs a job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EngineKind {
    /// Featherstone ABA + RK4 with exact stick/slip Coulomb friction (`dynforge_worker`'s own).
    Native,
    /// rapier3d-f64's reduced-coordinate multibody (semi-implicit Euler substeps).
    Rapier,
}

impl EngineKind {
    pub fn name(self) -> &'static str {
        match self {
            EngineKind::Native => "native",
            EngineKind::Rapier => "rapier",
        }
    }
}

/// Controller tuning.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PidGains {
    /// Closed-loop natural frequency per joint [rad/s] (joints beyond the list take its last entry, as do those of
    /// the next two lists).
    pub omega: Vec<f64>,
    /// Smallest inertia the gains are scheduled on per joint [kg m^2]: light joints get the stiffness needed to
    /// push through Coulomb friction, up to the discrete loop's stability bound (`2 zeta omega dt I_floor / I` < 1.5
    /// for the lightest generated joint).
    pub inertia_floor: Vec<f64>,
    /// Damping ratio.
    pub zeta: f64,
    /// Integral corner as a fraction of `omega`.
    pub integral_ratio: f64,
    /// Gravity-aware gain `K_G` as a fraction of `Kp`, per metre of end-effector height per radian.
    pub kg_fraction: f64,
    /// Largest share of the effort limit the integral term may hold.
    pub windup_fraction: f64,
    /// Control periods between gain schedules (inertia, Jacobian, stability scale).
    pub schedule_every: usize,
    /// Scale each joint's loop by its own row of the stability bound (`dt` times the Gershgorin row sum of
    /// `Kd^1/2 M^-1 Kd^1/2` at most 1) instead of all of them by its largest eigenvalue: a stiff light wrist then no
    /// longer softens the base. Off for the generator's robots.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub per_joint_scale: bool,
}

impl PidGains {
    /// Joint `j`'s natural frequency and inertia floor.
    pub fn joint(&self, j: usize) -> (f64, f64) {
        let at = |v: &[f64]| v.get(j).or(v.last()).copied().unwrap_or(0.0);
        (at(&self.omega), at(&self.inertia_floor))
    }
}

impl Default for PidGains {
    fn default() -> Self {
        PidGains {
            omega: vec![25.0; 6],
            inertia_floor: vec![0.3, 0.8, 0.3, 0.06, 0.02, 0.02],
            zeta: 1.0,
            integral_ratio: 1.0,
            kg_fraction: 0.5,
            windup_fraction: 0.7,
            schedule_every: 5,
            per_joint_scale: false,
        }
    }
}

/// The minimum-jerk profile of a move of `duration` at time `t`: the share of the way covered, and its first and
/// second time derivatives (`10 s^3 - 15 s^4 + 6 s^5`, `s = t / duration`; at rest before and after).
pub fn minimum_jerk(t: f64, duration: f64) -> [f64; 3] {
    let s = (t / duration).clamp(0.0, 1.0);
    let moving = t > 0.0 && t < duration;
    let p = s * s * s * (10.0 + s * (-15.0 + 6.0 * s));
    let dp = if moving { 30.0 * s * s * (1.0 - s) * (1.0 - s) / duration } else { 0.0 };
    let ddp = if moving { 60.0 * s * (1.0 - s) * (1.0 - 2.0 * s) / (duration * duration) } else { 0.0 };
    [p, dp, ddp]
}

/// How waypoints and moves are drawn.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrajectoryConfig {
    /// Waypoints per robot = trajectories per robot.
    pub waypoints: usize,
    /// Clearance kept from every collision [m].
    pub clearance: f64,
    /// Waypoints stay this far inside the joint limits [rad].
    pub limit_margin: f64,
    /// Largest joint-space step between collision checks along a path [rad].
    pub path_step: f64,
    /// Peak joint speed of a move as a fraction of the joint's speed limit.
    pub speed_fraction: f64,
    /// Shortest move [s].
    pub min_move: f64,
    /// Time the goal is held after a move [s].
    pub hold: f64,
    /// Candidate draws per waypoint before giving up.
    pub max_attempts: usize,
}

impl Default for TrajectoryConfig {
    fn default() -> Self {
        TrajectoryConfig {
            waypoints: 16,
            clearance: 0.02,
            limit_margin: 0.15,
            path_step: 0.02,
            speed_fraction: 0.5,
            min_move: 4.0,
            hold: 2.0,
            max_attempts: 2000,
        }
    }
}

impl TrajectoryConfig {
    /// The interval a joint with position limits `[lower, upper]` draws its waypoints from: within half a turn of 0,
    /// `limit_margin` inside the limits.
    pub fn waypoint_range(&self, lower: f64, upper: f64) -> (f64, f64) {
        let (lo, hi) = (lower.max(-std::f64::consts::PI), upper.min(std::f64::consts::PI));
        (lo + self.limit_margin, hi - self.limit_margin)
    }

    /// Duration of a move given per joint as (distance, speed limit): the minimum-jerk peak speed `1.875 |dq| / T`
    /// kept at `speed_fraction` of each limit, and at least `min_move`.
    pub fn move_duration(&self, joints: impl Iterator<Item = (f64, f64)>) -> f64 {
        joints.map(|(dq, speed)| 1.875 * dq.abs() / (self.speed_fraction * speed)).fold(self.min_move, f64::max)
    }
}

/// Whether the straight joint-space path from `a` to `b` is `free`: both ends and points on it no more than `step`
/// apart (in the max norm).
pub fn straight_path_free(a: &[f64], b: &[f64], step: f64, mut free: impl FnMut(&[f64]) -> bool) -> bool {
    let span = a.iter().zip(b).map(|(x, y)| (y - x).abs()).fold(0.0, f64::max);
    let n = (span / step).ceil().max(1.0) as usize;
    let mut q = vec![0.0; a.len()];
    (0..=n).all(|k| {
        let s = k as f64 / n as f64;
        for (q, (x, y)) in q.iter_mut().zip(a.iter().zip(b)) {
            *q = x + s * (y - x);
        }
        free(&q)
    })
}
