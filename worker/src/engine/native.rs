//! The native engine: the robot crate's ABA integrated with classical RK4, with joint friction handled by the
//! engine itself.
//!
//! - Viscous friction is part of the ODE. Its stiffness `M^-1 D` can exceed RK4's stability range on light wrists
//!   (`mu_v / I` up to ~3000 /s at 1 ms), so the period is split into substeps that keep the largest eigenvalue
//!   times the substep below 1 (re-estimated every few periods from the generalized eigenproblem `D x = l M x`).
//! - Coulomb friction has exact stick/slip: a joint whose velocity reached exactly zero stays stuck while the torque
//!   needed to hold it (from the constrained dynamics with every stuck joint locked) is within `+-mu_c`; joints that
//!   need more break away in the direction of that torque (an active-set solve, most violating joint first). A
//!   sliding joint whose velocity changes sign during a substep stops there. Within a substep the friction sign is
//!   fixed, so RK4 integrates a smooth ODE and nothing chatters.

use dynforge_robot::{Data, Model, aba, aba_locked, crba};
use nalgebra::{Matrix6, Vector6};

use super::{Engine, EngineKind};
use crate::trajectory::Config6;

/// Periods between re-estimates of the viscous stiffness.
const STIFFNESS_REFRESH: usize = 20;
/// Largest `lambda * h` allowed (RK4 is stable to 2.78 on the negative real axis; 1 keeps it accurate too).
const MAX_LAMBDA_H: f64 = 1.0;

pub struct NativeEngine<'m> {
    model: &'m Model,
    data: Data,
    dt: f64,
    q: Config6,
    qd: Config6,
    coulomb: Config6,
    viscous: Config6,
    substeps: usize,
    min_substeps: usize,
    periods: usize,
}

impl<'m> NativeEngine<'m> {
    /// An engine stepping `model` with control period `dt` [s].
    pub fn new(model: &'m Model, dt: f64) -> Self {
        assert_eq!(model.dof(), 6, "the worker simulates 6-joint arms");
        let coulomb = std::array::from_fn(|j| model.joints()[j].friction.coulomb);
        let viscous = std::array::from_fn(|j| model.joints()[j].friction.viscous);
        NativeEngine {
            model,
            data: Data::new(model),
            dt,
            q: [0.0; 6],
            qd: [0.0; 6],
            coulomb,
            viscous,
            substeps: 1,
            min_substeps: 1,
            periods: 0,
        }
    }

    /// The same engine with at least `n` substeps per period: RK4's error falls as `(dt / n)^4`, which lets a
    /// benchmark compare engines at equal accuracy rather than at equal step size.
    pub fn with_min_substeps(mut self, n: usize) -> Self {
        self.min_substeps = n.max(1);
        self
    }

    /// Substeps per period in use.
    pub fn substeps(&self) -> usize {
        self.substeps
    }

    fn mass_matrix(&mut self, q: &Config6) -> Matrix6<f64> {
        let m = crba(self.model, &mut self.data, q);
        Matrix6::from_fn(|r, c| m[(r, c)])
    }

    /// Largest eigenvalue of `M^-1 D` (D = diag(mu_v)), via `L^-1 D L^-T` with `M = L L^T`.
    fn viscous_stiffness(&mut self) -> f64 {
        let q = self.q;
        let m = self.mass_matrix(&q);
        let Some(chol) = m.cholesky() else { return f64::INFINITY };
        let l_inv = chol.l().try_inverse().unwrap_or_else(Matrix6::zeros);
        let d = Matrix6::from_diagonal(&Vector6::from(self.viscous));
        let s = l_inv * d * l_inv.transpose();
        s.symmetric_eigenvalues().max()
    }

    /// Joint accelerations with the joints in `stuck` locked, friction signs `sign` for the others.
    fn acceleration(&mut self, q: &Config6, qd: &Config6, tau: &Config6, sign: &Config6, stuck: &[bool; 6]) -> Config6 {
        let mut net = [0.0; 6];
        for j in 0..6 {
            net[j] = tau[j] - self.coulomb[j] * sign[j] - self.viscous[j] * qd[j];
        }
        if !stuck.iter().any(|&s| s) {
            let a = aba(self.model, &mut self.data, q, qd, &net);
            return std::array::from_fn(|j| a[j]);
        }
        let (qdd, _) = self.locked_dynamics(q, qd, &net, stuck);
        qdd
    }

    /// Dynamics with the `stuck` joints locked: the free joints' accelerations and the torque each locked joint needs
    /// to stay locked (to be compared with its Coulomb limit). `net` is the applied torque minus sliding friction.
    fn locked_dynamics(&mut self, q: &Config6, qd: &Config6, net: &Config6, stuck: &[bool; 6]) -> (Config6, Config6) {
        let qdd = aba_locked(self.model, &mut self.data, q, qd, net, stuck);
        let qdd: Config6 = std::array::from_fn(|j| qdd[j]);
        (qdd, std::array::from_fn(|j| self.data.tau[j]))
    }

    /// Decides which joints at rest stay stuck, and the friction sign of every joint for the next substep.
    fn classify(&mut self, tau: &Config6) -> ([bool; 6], Config6) {
        let mut stuck = [false; 6];
        let mut sign = [0.0; 6];
        for j in 0..6 {
            if self.qd[j] == 0.0 && self.coulomb[j] > 0.0 {
                stuck[j] = true;
            } else {
                sign[j] = dynforge_robot::dynamics::sign(self.qd[j]);
            }
        }
        while stuck.iter().any(|&s| s) {
            let (q, qd) = (self.q, self.qd);
            let net: Config6 = std::array::from_fn(|j| tau[j] - self.coulomb[j] * sign[j] - self.viscous[j] * qd[j]);
            let (_, needed) = self.locked_dynamics(&q, &qd, &net, &stuck);
            let worst = (0..6)
                .filter(|&j| stuck[j])
                .map(|j| (j, needed[j].abs() - self.coulomb[j]))
                .max_by(|a, b| a.1.total_cmp(&b.1));
            match worst {
                Some((j, excess)) if excess > 0.0 => {
                    stuck[j] = false;
                    sign[j] = needed[j].signum();
                }
                _ => break,
            }
        }
        (stuck, sign)
    }

    fn substep(&mut self, tau: &Config6, h: f64) {
        let (stuck, sign) = self.classify(tau);
        let (q0, v0) = (self.q, self.qd);
        let add = |x: &Config6, k: &Config6, s: f64| -> Config6 { std::array::from_fn(|j| x[j] + s * k[j]) };
        let a1 = self.acceleration(&q0, &v0, tau, &sign, &stuck);
        let (q2, v2) = (add(&q0, &v0, h / 2.0), add(&v0, &a1, h / 2.0));
        let a2 = self.acceleration(&q2, &v2, tau, &sign, &stuck);
        let (q3, v3) = (add(&q0, &v2, h / 2.0), add(&v0, &a2, h / 2.0));
        let a3 = self.acceleration(&q3, &v3, tau, &sign, &stuck);
        let (q4, v4) = (add(&q0, &v3, h), add(&v0, &a3, h));
        let a4 = self.acceleration(&q4, &v4, tau, &sign, &stuck);
        for j in 0..6 {
            if stuck[j] {
                continue;
            }
            self.q[j] = q0[j] + h / 6.0 * (v0[j] + 2.0 * v2[j] + 2.0 * v3[j] + v4[j]);
            let v = v0[j] + h / 6.0 * (a1[j] + 2.0 * a2[j] + 2.0 * a3[j] + a4[j]);
            // Coulomb friction cannot reverse a motion: a sign change means the joint stopped within the substep.
            self.qd[j] = if self.coulomb[j] > 0.0 && sign[j] != 0.0 && v * sign[j] < 0.0 { 0.0 } else { v };
        }
    }
}

impl Engine for NativeEngine<'_> {
    fn kind(&self) -> EngineKind {
        EngineKind::Native
    }

    fn reset(&mut self, q: &Config6, qd: &Config6) {
        self.q = *q;
        self.qd = *qd;
        self.periods = 0;
    }

    fn step(&mut self, tau: &Config6) {
        if self.periods.is_multiple_of(STIFFNESS_REFRESH) {
            let lambda = self.viscous_stiffness();
            // 1.5x margin for the inertia changing before the next estimate.
            let stable = (1.5 * lambda * self.dt / MAX_LAMBDA_H).ceil() as usize;
            self.substeps = stable.clamp(1, 64).max(self.min_substeps);
        }
        self.periods += 1;
        let h = self.dt / self.substeps as f64;
        for _ in 0..self.substeps {
            self.substep(tau, h);
        }
    }

    fn q(&self) -> &Config6 {
        &self.q
    }

    fn qd(&self) -> &Config6 {
        &self.qd
    }
}
