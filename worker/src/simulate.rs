//! One trajectory of one robot: reference, controller, engine, failure checks, recording.

use dynforge_proto::sim::EngineKind;
pub use dynforge_proto::sim::SimConfig;
use dynforge_robot::generator::GeneratedRobot;
use dynforge_robot::{Data, crba, energy, point_jacobian};
use nalgebra::{Matrix6, Vector3};

use crate::collision::{CollisionModel, Contact};
use crate::control::Pid;
use crate::engine::{Engine, NativeEngine, RAPIER_SUBSTEPS, RapierEngine};
use crate::trajectory::{Config6, Move, PlanError};

/// Why a run was discarded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Discard {
    #[error("non-finite state at t = {t:.3} s")]
    NonFinite { t: f64 },
    #[error("joint {joint} reached {speed:.2} rad/s at t = {t:.3} s (velocity blow-up)")]
    VelocityBlowup { joint: usize, speed: f64, t: f64 },
    #[error("energy exceeded the motors' work by {excess:.2} J at t = {t:.3} s (energy blow-up)")]
    EnergyBlowup { excess: f64, t: f64 },
    #[error("joint {joint} left its limits at t = {t:.3} s")]
    JointLimit { joint: usize, t: f64 },
    #[error("{contact} at t = {t:.3} s")]
    Collision { contact: Contact, t: f64 },
    #[error("joint {joint} ended {error:.4} rad from the goal (waypoint timeout)")]
    Timeout { joint: usize, error: f64 },
    #[error(transparent)]
    Planning(PlanError),
    /// The generator refused the robot of this seed and id (its configuration allows robots no model can be made
    /// of): as deterministic as a collision, so recorded once rather than retried on every resume.
    #[error("the generator rejected the robot: {0}")]
    Rejected(dynforge_robot::ModelError),
}

impl Discard {
    /// Stable reason code, for counts and reports.
    pub fn code(&self) -> &'static str {
        match self {
            Discard::NonFinite { .. } => "non_finite",
            Discard::VelocityBlowup { .. } => "velocity_blowup",
            Discard::EnergyBlowup { .. } => "energy_blowup",
            Discard::JointLimit { .. } => "joint_limit",
            Discard::Collision { .. } => "collision",
            Discard::Timeout { .. } => "timeout",
            Discard::Planning(_) => "planning",
            Discard::Rejected(_) => "rejected",
        }
    }
}

/// The logged 1 kHz data: sample `k` is the state at `t = k dt` and the motor torque applied over `[t, t + dt)`.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    pub dt: f64,
    pub q: Vec<Config6>,
    pub qd: Vec<Config6>,
    pub tau: Vec<Config6>,
    /// Share of samples where some joint's torque saturated.
    pub saturated: f64,
}

impl Recording {
    pub fn len(&self) -> usize {
        self.q.len()
    }
    pub fn is_empty(&self) -> bool {
        self.q.is_empty()
    }
    pub fn duration(&self) -> f64 {
        self.len() as f64 * self.dt
    }
}

/// Builds the configured engine for a robot.
pub fn engine_for<'m>(kind: EngineKind, robot: &'m GeneratedRobot, dt: f64) -> Box<dyn Engine + 'm> {
    match kind {
        EngineKind::Native => Box::new(NativeEngine::new(&robot.model, dt)),
        EngineKind::Rapier => Box::new(RapierEngine::new(&robot.model, dt, RAPIER_SUBSTEPS)),
    }
}

/// A state no stable simulation of a controlled arm reaches: not finite, outside the joint limits, or faster than
/// `cfg.velocity_blowup` times a joint's speed limit.
fn check_state(
    model: &dynforge_robot::Model,
    q: &Config6,
    qd: &Config6,
    t: f64,
    cfg: &SimConfig,
) -> Result<(), Discard> {
    if q.iter().chain(qd).any(|v| !v.is_finite()) {
        return Err(Discard::NonFinite { t });
    }
    for j in 0..6 {
        let lim = &model.joints()[j].limits;
        if q[j] < lim.lower || q[j] > lim.upper {
            return Err(Discard::JointLimit { joint: j, t });
        }
        if qd[j].abs() > cfg.velocity_blowup * lim.velocity {
            return Err(Discard::VelocityBlowup { joint: j, speed: qd[j].abs(), t });
        }
    }
    Ok(())
}

/// Simulates `mv` on `robot`, starting at rest in equilibrium at the move's start.
pub fn simulate(robot: &GeneratedRobot, mv: &Move, cfg: &SimConfig) -> Result<Recording, Discard> {
    let model = &robot.model;
    let mut engine = engine_for(cfg.engine, robot, cfg.dt);
    let mut data = Data::new(model);
    let collision = CollisionModel::new(robot, 0.0);
    let effort: Config6 = std::array::from_fn(|j| model.joints()[j].limits.effort);
    let hold: Config6 = {
        let g = dynforge_robot::gravity_torque(model, &mut data, &mv.start);
        std::array::from_fn(|j| g[j])
    };
    let mut pid = Pid::new(cfg.gains.clone(), effort, hold);
    engine.reset(&mv.start, &[0.0; 6]);
    let tip = Vector3::new(0.0, 0.0, robot.beams[5].length);
    let steps = (mv.total() / cfg.dt).round() as usize;
    let mut rec = Recording {
        dt: cfg.dt,
        q: Vec::with_capacity(steps),
        qd: Vec::with_capacity(steps),
        tau: Vec::with_capacity(steps),
        saturated: 0.0,
    };
    let e0 = energy(model, &mut data, &mv.start, &[0.0; 6]).total();
    let mut work = 0.0;
    let mut saturated = 0usize;
    for k in 0..steps {
        let t = k as f64 * cfg.dt;
        let (q, qd) = (*engine.q(), *engine.qd());
        check_state(model, &q, &qd, t, cfg)?;
        if k.is_multiple_of(cfg.collision_every) {
            let e = energy(model, &mut data, &q, &qd).total();
            let excess = e - e0 - work;
            if excess > cfg.energy_slack + 0.05 * (e0.abs() + work.abs()) {
                return Err(Discard::EnergyBlowup { excess, t });
            }
            // `energy` left the link frames of q in `data`.
            if let Some(contact) = collision.check(&data.o_m_i) {
                return Err(Discard::Collision { contact, t });
            }
        }
        if k.is_multiple_of(cfg.gains.schedule_every.max(1)) {
            let m = {
                let m = crba(model, &mut data, &q);
                Matrix6::from_fn(|r, c| m[(r, c)])
            };
            // `crba` left the link frames of q in `data`.
            point_jacobian(model, &mut data, 5, &tip);
            let dz_dq: Config6 = std::array::from_fn(|j| data.jacobian[(2, j)]);
            pid.schedule(&m, &dz_dq, cfg.dt);
        }
        let (q_ref, qd_ref, _) = mv.reference(t);
        let e: Config6 = std::array::from_fn(|j| q_ref[j] - q[j]);
        let ed: Config6 = std::array::from_fn(|j| qd_ref[j] - qd[j]);
        let tau = pid.update(&e, &ed, cfg.dt);
        if (0..6).any(|j| tau[j].abs() >= effort[j]) {
            saturated += 1;
        }
        rec.q.push(q);
        rec.qd.push(qd);
        rec.tau.push(tau);
        engine.step(&tau);
        // Motor work over the period: exact for a torque held constant, tau . (q_next - q).
        let q_next = engine.q();
        work += (0..6).map(|j| tau[j] * (q_next[j] - q[j])).sum::<f64>();
    }
    let q_end = engine.q();
    for j in 0..6 {
        let error = (q_end[j] - mv.goal[j]).abs();
        if error > cfg.goal_tolerance {
            return Err(Discard::Timeout { joint: j, error });
        }
    }
    rec.saturated = saturated as f64 / steps.max(1) as f64;
    Ok(rec)
}
