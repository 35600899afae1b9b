//! The paper's per-joint gravity-aware PID:
//! `u_i = (Kp_i + K_G |dz/dq_i|) e_i + Ki_i * integral(e_i) + Kd_i * de_i/dt`,
//! where `dz/dq_i` is the z-row of the end effector's Jacobian: the stiffness rises where joint `i` lifts the end
//! effector against gravity. The paper writes the signed element; its magnitude is used here because a negative
//! value would lower the stiffness below `Kp` (and below zero for large `K_G`) exactly when the joint carries load.
//!
//! The error derivative uses the reference velocity (`de/dt = qd_ref - qd`), so reference changes give no
//! derivative kick. Anti-windup: the integral is clamped so that `Ki * integral` never exceeds `windup_fraction` of
//! the joint's torque limit, and it stops integrating while the output saturates in the error's direction. The
//! output is clamped to the joint's effort limit; that clamped torque is what the motor applies and what is logged.
//!
//! Gains are scheduled on the joint-space inertia: `Kp = max(M_ii(q), floor_i) omega^2`,
//! `Kd = 2 zeta sqrt(Kp M_ii(q))` (critical damping for the joint's actual inertia at that stiffness) and
//! `Ki = Kp omega * integral_ratio`. A fixed gain cannot serve this distribution: the base joint's inertia varies
//! 1000x between a folded and a stretched arm (0.007-7 kg m^2). The floor gives light joints (wrists of 2e-4 kg m^2
//! carrying up to 1 N m of Coulomb friction) the stiffness to push through friction; damping for the true inertia
//! keeps the discrete 1 kHz loop stable: for the lightest wrist, `sqrt(Kp / I) dt` = 0.27 and `Kd dt / I` = 0.54.
//! The integral term is kept as a torque, so gain changes are bumpless. Tuning (bench/simulation.sh, 100 robots):
//! see docs/measurements.md.

use dynforge_proto::sim::PidGains;
use nalgebra::DMatrix;

/// Gains of one joint loop at the current pose (`kp` includes the gravity-aware term).
#[derive(Debug, Clone, Copy, Default)]
struct Scheduled {
    kp: f64,
    kd: f64,
    ki: f64,
}

/// The controller state of one trajectory.
#[derive(Debug, Clone)]
pub struct Pid {
    gains: PidGains,
    effort: Vec<f64>,
    /// Integral term, as a torque.
    integral: Vec<f64>,
    scheduled: Vec<Scheduled>,
}

impl Pid {
    /// A controller whose integral term starts at `hold` (e.g. the gravity torque of the start pose, so the arm
    /// starts in equilibrium instead of sagging), within the anti-windup bound.
    pub fn new(gains: PidGains, effort: Vec<f64>, hold: Vec<f64>) -> Self {
        let n = effort.len();
        let mut pid = Pid { gains, effort, integral: hold, scheduled: vec![Scheduled::default(); n] };
        pid.clamp_integral();
        pid
    }

    fn clamp_integral(&mut self) {
        for j in 0..self.effort.len() {
            let max = self.gains.windup_fraction * self.effort[j];
            self.integral[j] = self.integral[j].clamp(-max, max);
        }
    }

    /// Schedules the loop gains on the pose: the joint-space mass matrix `m` and the end effector's `dz/dq`. The
    /// inertia and the Jacobian change little over a few milliseconds, so callers refresh this every few periods.
    ///
    /// Per-joint gains ignore the coupling between joints, and in stretched poses the effective inertia of a joint
    /// (`1 / (M^-1)_ii`) is far below `M_ii`. The discrete loop stays stable while `dt lambda_max(M^-1 Kd)` is well
    /// below 2; it is kept at most 1 by scaling the loop's frequency (`Kd` by `s`, `Kp` and `Ki` by `s^2`, which
    /// keeps the damping ratio). `lambda_max` is that of the symmetric `Kd^1/2 M^-1 Kd^1/2`.
    pub fn schedule(&mut self, m: &DMatrix<f64>, dz_dq: &[f64], dt: f64) {
        let g = &self.gains;
        let n = self.effort.len();
        let m_inv = m.clone().cholesky().map(|c| c.inverse()).unwrap_or_else(|| DMatrix::zeros(n, n));
        let mut kp = vec![0.0; n];
        let mut kd = vec![0.0; n];
        for j in 0..n {
            let (w, floor) = g.joint(j);
            kp[j] = m[(j, j)].max(floor) * w * w;
            // Damping for the joint's own inertia at this stiffness, so a floored joint is not overdamped into
            // instability: Kd dt / I = 2 zeta sqrt(Kp / I) dt stays small.
            kd[j] = 2.0 * g.zeta * (kp[j] * m[(j, j)]).sqrt();
        }
        let root: Vec<f64> = kd.iter().map(|k| k.sqrt()).collect();
        // `root M^-1 root` with `root` diagonal: each element scaled by its row's and its column's root.
        let scaled = DMatrix::from_fn(n, n, |r, c| root[r] * m_inv[(r, c)] * root[c]);
        let lambda = scaled.symmetric_eigenvalues().max();
        let coupled = (1.0 / (dt * lambda)).min(1.0);
        for j in 0..n {
            let s = match g.per_joint_scale {
                true => (1.0 / (dt * scaled.row(j).iter().map(|v| v.abs()).sum::<f64>())).min(1.0),
                false => coupled,
            };
            let kp_s = kp[j] * s * s;
            self.scheduled[j] = Scheduled {
                kp: kp_s * (1.0 + g.kg_fraction * dz_dq[j].abs()),
                kd: kd[j] * s,
                ki: kp_s * g.joint(j).0 * s * g.integral_ratio,
            };
        }
    }

    /// Torque command for errors `e = q_ref - q` and `ed = qd_ref - qd` with the last scheduled gains, plus a
    /// feedforward torque if one is given; then advances the integral by `dt`. Returns the saturated torque.
    pub fn update(&mut self, e: &[f64], ed: &[f64], feedforward: Option<&[f64]>, dt: f64) -> Vec<f64> {
        let n = self.effort.len();
        let mut out = vec![0.0; n];
        for j in 0..n {
            let k = self.scheduled[j];
            let mut raw = k.kp * e[j] + self.integral[j] + k.kd * ed[j];
            if let Some(ff) = feedforward {
                raw += ff[j];
            }
            out[j] = raw.clamp(-self.effort[j], self.effort[j]);
            let saturated_along_error = out[j] != raw && raw.signum() == e[j].signum();
            if !saturated_along_error {
                self.integral[j] += k.ki * e[j] * dt;
            }
        }
        self.clamp_integral();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two uncoupled joints, the second light and stiff beyond its discrete stability bound: one scale for all
    /// softens the heavy joint too; a scale per joint leaves it alone and still bounds the light one.
    #[test]
    fn a_stiff_light_joint_softens_only_itself_when_scaled_per_joint() {
        let m = DMatrix::from_diagonal(&nalgebra::DVector::from_vec(vec![1.0, 1e-4]));
        let dt = 1e-3;
        let gains = |per_joint_scale| PidGains {
            omega: vec![25.0, 25.0],
            inertia_floor: vec![0.0, 1.0],
            per_joint_scale,
            ..PidGains::default()
        };
        let scheduled = |per_joint| {
            let mut pid = Pid::new(gains(per_joint), vec![100.0, 100.0], vec![0.0, 0.0]);
            pid.schedule(&m, &[0.0, 0.0], dt);
            pid.scheduled
        };
        let (coupled, own) = (scheduled(false), scheduled(true));
        // Joint 1: Kp = 625, Kd = 50 unscaled (critical for its own inertia).
        assert!((own[0].kp - 625.0).abs() < 1e-9 && (own[0].kd - 50.0).abs() < 1e-9, "{:?}", own[0]);
        assert!(coupled[0].kp < 0.1 * own[0].kp, "one scale for all softens joint 1: {:?}", coupled[0]);
        // Joint 2 is held to its bound either way: dt Kd / M = 1.
        for s in [&coupled[1], &own[1]] {
            assert!((dt * s.kd / 1e-4 - 1.0).abs() < 1e-9, "{s:?}");
        }
    }
}
