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
use nalgebra::DMatrix;

use super::Engine;

use dynforge_proto::sim::EngineKind;

/// Periods between re-estimates of the viscous stiffness.
const STIFFNESS_REFRESH: usize = 20;
/// Largest `lambda * h` allowed (RK4 is stable to 2.78 on the negative real axis; 1 keeps it accurate too).
const MAX_LAMBDA_H: f64 = 1.0;

pub struct NativeEngine<'m> {
    model: &'m Model,
    data: Data,
    dt: f64,
    q: Vec<f64>,
    qd: Vec<f64>,
    coulomb: Vec<f64>,
    viscous: Vec<f64>,
    substeps: usize,
    min_substeps: usize,
    periods: usize,
    net: Vec<f64>,
    stages: Stages,
}

/// `A diag(d) A^T`, summed in the order nalgebra's fixed-size product sums it (so a 6-joint arm's substep count is
/// what it was when the engine used 6x6 matrices); a dynamic-size product would go through `matrixmultiply`, whose
/// kernels are chosen by the CPU at run time and would make shards differ between machines.
pub(crate) fn congruence(a: &DMatrix<f64>, d: &[f64]) -> DMatrix<f64> {
    let n = a.nrows();
    DMatrix::from_fn(n, n, |r, c| {
        let mut sum = a[(r, 0)] * d[0] * a[(c, 0)];
        for k in 1..n {
            sum += a[(r, k)] * d[k] * a[(c, k)];
        }
        sum
    })
}

/// The applied torque minus sliding friction (`coulomb` and `viscous` per joint), into `net`.
fn sliding_net(net: &mut [f64], tau: &[f64], (coulomb, viscous): (&[f64], &[f64]), sign: &[f64], qd: &[f64]) {
    for j in 0..net.len() {
        net[j] = tau[j] - coulomb[j] * sign[j] - viscous[j] * qd[j];
    }
}

impl<'m> NativeEngine<'m> {
    /// An engine stepping `model` with control period `dt` [s].
    pub fn new(model: &'m Model, dt: f64) -> Self {
        let n = model.dof();
        NativeEngine {
            model,
            data: Data::new(model),
            dt,
            q: vec![0.0; n],
            qd: vec![0.0; n],
            coulomb: model.joints().iter().map(|j| j.friction.coulomb).collect(),
            viscous: model.joints().iter().map(|j| j.friction.viscous).collect(),
            substeps: 1,
            min_substeps: 1,
            periods: 0,
            net: vec![0.0; n],
            stages: Stages::new(n),
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

    fn dof(&self) -> usize {
        self.q.len()
    }

    /// Largest eigenvalue of `M^-1 D` (D = diag(mu_v)), via `L^-1 D L^-T` with `M = L L^T`.
    fn viscous_stiffness(&mut self) -> f64 {
        let m = crba(self.model, &mut self.data, &self.q).clone();
        let Some(chol) = m.cholesky() else { return f64::INFINITY };
        let n = self.dof();
        let l_inv = chol.l().try_inverse().unwrap_or_else(|| DMatrix::zeros(n, n));
        congruence(&l_inv, &self.viscous).symmetric_eigenvalues().max()
    }

    /// Joint accelerations with the joints in `stuck` locked, friction signs `sign` for the others, into `out`.
    fn acceleration(&mut self, q: &[f64], qd: &[f64], tau: &[f64], sign: &[f64], stuck: &[bool], out: &mut [f64]) {
        sliding_net(&mut self.net, tau, (&self.coulomb, &self.viscous), sign, qd);
        let a = if stuck.iter().any(|&s| s) {
            aba_locked(self.model, &mut self.data, q, qd, &self.net, stuck)
        } else {
            aba(self.model, &mut self.data, q, qd, &self.net)
        };
        out.copy_from_slice(a);
    }

    /// Decides which joints at rest stay stuck, and the friction sign of every joint for the next substep.
    fn classify(&mut self, tau: &[f64]) -> (Vec<bool>, Vec<f64>) {
        let n = self.dof();
        let mut stuck = vec![false; n];
        let mut sign = vec![0.0; n];
        for j in 0..n {
            if self.qd[j] == 0.0 && self.coulomb[j] > 0.0 {
                stuck[j] = true;
            } else {
                sign[j] = dynforge_robot::dynamics::sign(self.qd[j]);
            }
        }
        while stuck.iter().any(|&s| s) {
            sliding_net(&mut self.net, tau, (&self.coulomb, &self.viscous), &sign, &self.qd);
            // With the stuck joints locked, `data.tau` holds the torque each needs to stay locked, to be compared
            // with its Coulomb limit.
            aba_locked(self.model, &mut self.data, &self.q, &self.qd, &self.net, &stuck);
            let needed = &self.data.tau;
            let worst = (0..n)
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

    fn substep(&mut self, tau: &[f64], h: f64) {
        let (stuck, sign) = self.classify(tau);
        // Stages: states (q_i, v_i) and accelerations a_i, i = 1..4 (q_1, v_1 the current state).
        let mut rk = std::mem::take(&mut self.stages);
        rk.q[0].copy_from_slice(&self.q);
        rk.v[0].copy_from_slice(&self.qd);
        for i in 0..4 {
            let (q, v) = (&rk.q[i], &rk.v[i]);
            self.acceleration(q, v, tau, &sign, &stuck, &mut rk.a[i]);
            if i < 3 {
                // Stages 2 and 3 step half a substep from the start, stage 4 a whole one.
                let s = if i < 2 { h / 2.0 } else { h };
                for j in 0..self.dof() {
                    rk.q[i + 1][j] = rk.q[0][j] + s * rk.v[i][j];
                    rk.v[i + 1][j] = rk.v[0][j] + s * rk.a[i][j];
                }
            }
        }
        let (q, v, a) = (&rk.q, &rk.v, &rk.a);
        for j in 0..self.dof() {
            if stuck[j] {
                continue;
            }
            self.q[j] = q[0][j] + h / 6.0 * (v[0][j] + 2.0 * v[1][j] + 2.0 * v[2][j] + v[3][j]);
            let vel = v[0][j] + h / 6.0 * (a[0][j] + 2.0 * a[1][j] + 2.0 * a[2][j] + a[3][j]);
            // Coulomb friction cannot reverse a motion: a sign change means the joint stopped within the substep.
            self.qd[j] = if self.coulomb[j] > 0.0 && sign[j] != 0.0 && vel * sign[j] < 0.0 { 0.0 } else { vel };
        }
        self.stages = rk;
    }
}

/// RK4's stage states and accelerations, kept between substeps so a step allocates nothing.
#[derive(Default)]
struct Stages {
    q: [Vec<f64>; 4],
    v: [Vec<f64>; 4],
    a: [Vec<f64>; 4],
}

impl Stages {
    fn new(n: usize) -> Self {
        let z = || std::array::from_fn(|_| vec![0.0; n]);
        Stages { q: z(), v: z(), a: z() }
    }
}

impl Engine for NativeEngine<'_> {
    fn kind(&self) -> EngineKind {
        EngineKind::Native
    }

    fn reset(&mut self, q: &[f64], qd: &[f64]) {
        self.q.copy_from_slice(q);
        self.qd.copy_from_slice(qd);
        self.periods = 0;
    }

    fn step(&mut self, tau: &[f64]) {
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

    fn q(&self) -> &[f64] {
        &self.q
    }

    fn qd(&self) -> &[f64] {
        &self.qd
    }
}
