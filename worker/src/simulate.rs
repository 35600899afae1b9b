//! One trajectory of one robot: reference, controller, engine, failure checks, recording.

use dynforge_proto::sim::EngineKind;
use dynforge_proto::sim::SimConfig;
use dynforge_robot::{Data, Model, crba, energy, point_jacobian, rnea};
use nalgebra::Vector3;

use crate::collision::{Collides, Contact};
use crate::control::Pid;
use crate::engine::{Engine, NativeEngine, RAPIER_SUBSTEPS, RapierEngine};
use crate::trajectory::{PlanError, Reference};

/// The arm a run simulates: its model, the point whose height the gravity-aware gain follows (a link and a point in
/// that link's frame), its collision bodies, and the model its controller's feedforward believes in, if it has one
/// (the inverse dynamics of the reference, as a robot's own controller computes it from its URDF: the PID then
/// only corrects what that model gets wrong).
pub struct Arm<'a> {
    pub model: &'a Model,
    pub tip: (usize, Vector3<f64>),
    pub collision: &'a dyn Collides,
    pub feedforward: Option<&'a Model>,
}

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
    /// The engine cannot simulate this arm (rapier and a prismatic joint).
    #[error("the {engine} engine cannot simulate joint {joint} ({why})")]
    Unsupported { engine: &'static str, joint: usize, why: &'static str },
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
            Discard::Unsupported { .. } => "unsupported",
        }
    }
}

/// The logged 1 kHz data: sample `k` is the state at `t = k dt` and the motor torque applied over `[t, t + dt)`.
#[derive(Debug, Clone, PartialEq)]
pub struct Simulation {
    pub dt: f64,
    pub q: Vec<Vec<f64>>,
    pub qd: Vec<Vec<f64>>,
    pub tau: Vec<Vec<f64>>,
    /// Share of samples where some joint's torque saturated.
    pub saturated: f64,
}

impl Simulation {
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

/// Builds the configured engine for an arm.
pub fn engine_for<'m>(kind: EngineKind, model: &'m Model, dt: f64) -> Result<Box<dyn Engine + 'm>, Discard> {
    if let Some(why) = unsupported(kind, model) {
        return Err(why);
    }
    match kind {
        EngineKind::Native => Ok(Box::new(NativeEngine::new(model, dt))),
        EngineKind::Rapier => Ok(Box::new(RapierEngine::new(model, dt, RAPIER_SUBSTEPS))),
    }
}

/// Why the engine `kind` cannot simulate `model`, if it cannot: the rapier arm is built of revolute joints only.
pub fn unsupported(kind: EngineKind, model: &Model) -> Option<Discard> {
    match kind {
        EngineKind::Native => None,
        EngineKind::Rapier => (0..model.dof()).find(|&j| model.is_prismatic(j)).map(|joint| Discard::Unsupported {
            engine: kind.name(),
            joint,
            why: "prismatic",
        }),
    }
}

/// A state no stable simulation of a controlled arm reaches: not finite, outside the joint limits, or faster than
/// `cfg.velocity_blowup` times a joint's speed limit.
fn check_state(model: &Model, q: &[f64], qd: &[f64], t: f64, cfg: &SimConfig) -> Result<(), Discard> {
    if q.iter().chain(qd).any(|v| !v.is_finite()) {
        return Err(Discard::NonFinite { t });
    }
    for j in 0..model.dof() {
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

/// Simulates `reference` on `arm`, starting at rest in equilibrium at its start.
pub fn simulate(arm: &Arm, reference: &dyn Reference, cfg: &SimConfig) -> Result<Simulation, Discard> {
    let model = arm.model;
    let n = model.dof();
    let mut engine = engine_for(cfg.engine, model, cfg.dt)?;
    let mut data = Data::new(model);
    let start = reference.start();
    let effort: Vec<f64> = model.joints().iter().map(|j| j.limits.effort).collect();
    // With a feedforward the start pose's gravity is in it; without, the integral term holds it.
    let hold = match arm.feedforward {
        Some(_) => vec![0.0; n],
        None => dynforge_robot::gravity_torque(model, &mut data, start).to_vec(),
    };
    let mut feedforward = arm.feedforward.map(|m| (m, Data::new(m)));
    let mut pid = Pid::new(cfg.gains.clone(), effort.clone(), hold);
    let rest = vec![0.0; n];
    engine.reset(start, &rest);
    let steps = (reference.total() / cfg.dt).round() as usize;
    let mut rec = Simulation {
        dt: cfg.dt,
        q: Vec::with_capacity(steps),
        qd: Vec::with_capacity(steps),
        tau: Vec::with_capacity(steps),
        saturated: 0.0,
    };
    let e0 = energy(model, &mut data, start, &rest).total();
    let mut work = 0.0;
    let mut saturated = 0usize;
    for k in 0..steps {
        let t = k as f64 * cfg.dt;
        let (q, qd) = (engine.q().to_vec(), engine.qd().to_vec());
        check_state(model, &q, &qd, t, cfg)?;
        if k.is_multiple_of(cfg.collision_every) {
            let e = energy(model, &mut data, &q, &qd).total();
            let excess = e - e0 - work;
            if excess > cfg.energy_slack + 0.05 * (e0.abs() + work.abs()) {
                return Err(Discard::EnergyBlowup { excess, t });
            }
            // `energy` left the link frames of q in `data`.
            if let Some(contact) = arm.collision.contact(&data.o_m_i) {
                return Err(Discard::Collision { contact, t });
            }
        }
        if k.is_multiple_of(cfg.gains.schedule_every.max(1)) {
            let m = crba(model, &mut data, &q).clone();
            // `crba` left the link frames of q in `data`.
            point_jacobian(model, &mut data, arm.tip.0, &arm.tip.1);
            let dz_dq: Vec<f64> = (0..n).map(|j| data.jacobian[(2, j)]).collect();
            pid.schedule(&m, &dz_dq, cfg.dt);
        }
        let [q_ref, qd_ref, qdd_ref] = reference.at(t);
        let e: Vec<f64> = (0..n).map(|j| q_ref[j] - q[j]).collect();
        let ed: Vec<f64> = (0..n).map(|j| qd_ref[j] - qd[j]).collect();
        let ff = feedforward.as_mut().map(|(m, d)| rnea(m, d, &q_ref, &qd_ref, &qdd_ref).to_vec());
        let tau = pid.update(&e, &ed, ff.as_deref(), cfg.dt);
        if (0..n).any(|j| tau[j].abs() >= effort[j]) {
            saturated += 1;
        }
        engine.step(&tau);
        // Motor work over the period: exact for a torque held constant, tau . (q_next - q).
        let q_next = engine.q();
        work += (0..n).map(|j| tau[j] * (q_next[j] - q[j])).sum::<f64>();
        rec.q.push(q);
        rec.qd.push(qd);
        rec.tau.push(tau);
    }
    let (q_end, goal) = (engine.q(), reference.goal());
    for j in 0..n {
        let error = (q_end[j] - goal[j]).abs();
        if error > cfg.goal_tolerance {
            return Err(Discard::Timeout { joint: j, error });
        }
    }
    rec.saturated = saturated as f64 / steps.max(1) as f64;
    Ok(rec)
}
