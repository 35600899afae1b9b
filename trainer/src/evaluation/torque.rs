//! The torque check: how well a set of parameters predicts a recording's torques by inverse dynamics.
//!
//! For every sample, `tau_hat = RNEA(q, qd, qdd) + mu_c sign(qd) + mu_v qd` with `qdd` by central differences of
//! `qd` on the 1 kHz grid, against the recorded (applied) torque. Samples where a joint is (nearly) at rest are left
//! out for that joint: there Coulomb friction is static and takes any value in `[-mu_c, mu_c]`, so no parameter set
//! predicts it. NRMSE per joint = RMSE / standard deviation of the recorded torque over the same samples; the
//! overall value is the mean over joints.

use dynforge_robot::{Data, Model, friction_torque, rnea};

use crate::data::source::JointTrajectory;

/// Joint speed [rad/s] under which a sample is treated as static for that joint.
pub const REST_SPEED: f64 = 1e-2;

/// Running sums of torque residuals per joint, over any number of recordings.
#[derive(Debug, Clone, Default)]
pub struct TorqueResidual {
    se: Vec<f64>,
    sum: Vec<f64>,
    sum2: Vec<f64>,
    n: Vec<usize>,
}

impl TorqueResidual {
    /// Adds the residuals of `model`'s inverse dynamics on `t` (joints in model order, uniform grid `dt`).
    pub fn add(&mut self, model: &Model, t: &JointTrajectory, dt: f64) {
        let n = model.dof();
        if self.se.len() != n {
            *self = TorqueResidual { se: vec![0.0; n], sum: vec![0.0; n], sum2: vec![0.0; n], n: vec![0; n] };
        }
        let mut data = Data::new(model);
        let (mut qdd, mut fr) = (vec![0.0; n], vec![0.0; n]);
        for i in 1..t.len().saturating_sub(1) {
            let row = |v: &[f64], k: usize| v[k * n..(k + 1) * n].to_vec();
            let (q, qd) = (row(&t.q, i), row(&t.qd, i));
            let (before, after) = (row(&t.qd, i - 1), row(&t.qd, i + 1));
            for j in 0..n {
                qdd[j] = (after[j] - before[j]) / (2.0 * dt);
            }
            friction_torque(model, &qd, &mut fr);
            let tau = rnea(model, &mut data, &q, &qd, &qdd);
            for j in 0..n {
                if qd[j].abs() < REST_SPEED {
                    continue;
                }
                let recorded = t.tau[i * n + j];
                self.se[j] += (tau[j] + fr[j] - recorded).powi(2);
                self.sum[j] += recorded;
                self.sum2[j] += recorded * recorded;
                self.n[j] += 1;
            }
        }
    }

    /// NRMSE per joint (NaN for a joint that never moved).
    pub fn per_joint(&self) -> Vec<f64> {
        (0..self.se.len())
            .map(|j| {
                let n = self.n[j] as f64;
                let var = self.sum2[j] / n - (self.sum[j] / n).powi(2);
                (self.se[j] / n).sqrt() / var.max(0.0).sqrt()
            })
            .collect()
    }

    /// Mean NRMSE over the joints that moved.
    pub fn overall(&self) -> f64 {
        let v: Vec<f64> = self.per_joint().into_iter().filter(|x| x.is_finite()).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynforge_robot::generator::{GeneratorConfig, generate};
    use dynforge_robot::parameters::{labels, with_labels};

    /// Torques of `model` along q_j(t) = a_j sin(w_j t + p_j), from the exact acceleration.
    fn trajectory(model: &Model, dt: f64, samples: usize) -> JointTrajectory {
        let n = model.dof();
        let mut t = JointTrajectory { names: vec![], t: vec![], q: vec![], qd: vec![], tau: vec![] };
        let mut data = Data::new(model);
        let mut fr = vec![0.0; n];
        for i in 0..samples {
            let time = i as f64 * dt;
            let (a, w, p) =
                (|j: usize| 0.4 + 0.1 * j as f64, |j: usize| 1.0 + 0.3 * j as f64, |j: usize| 0.7 * j as f64);
            let q: Vec<f64> = (0..n).map(|j| a(j) * (w(j) * time + p(j)).sin()).collect();
            let qd: Vec<f64> = (0..n).map(|j| a(j) * w(j) * (w(j) * time + p(j)).cos()).collect();
            let qdd: Vec<f64> = (0..n).map(|j| -a(j) * w(j) * w(j) * (w(j) * time + p(j)).sin()).collect();
            friction_torque(model, &qd, &mut fr);
            let tau: Vec<f64> = rnea(model, &mut data, &q, &qd, &qdd).iter().zip(&fr).map(|(a, b)| a + b).collect();
            t.t.push(time);
            t.q.extend(q);
            t.qd.extend(qd);
            t.tau.extend(tau);
        }
        t
    }

    #[test]
    fn true_parameters_predict_the_torques_to_the_finite_difference_error_and_wrong_ones_do_not() {
        let cfg = GeneratorConfig::default();
        let truth = generate(&cfg, 1, 0).unwrap().model;
        let other = generate(&cfg, 1, 1).unwrap().model;
        let (dt, samples) = (1e-3, 4000);
        let t = trajectory(&truth, dt, samples);
        let mut exact = TorqueResidual::default();
        exact.add(&truth, &t, dt);
        // Central differences of qd err by w^2 dt^2 / 6 relative to qdd (w <= 2.5 rad/s): below 1e-6.
        assert!(exact.overall() < 1e-5, "{:?}", exact.per_joint());
        let (wrong, _) = with_labels(&truth, &labels(&other).unwrap()).unwrap();
        let mut off = TorqueResidual::default();
        off.add(&wrong, &t, dt);
        assert!(off.overall() > 1e-2, "{:?}", off.per_joint());
    }
}
