//! Dynamics against analytic closed forms and against each other.

mod common;

use common::{joint_xml, link_xml, parse, random_state, robot};
use dynforge_robot::model::GRAVITY;
use dynforge_robot::parameters::dynamic_parameters;
use dynforge_robot::rng::Rng;
use dynforge_robot::{
    Data, aba, crba, energy, forward_kinematics, friction_torque, gravity_torque, nonlinear_effects, point_jacobian,
    regressor, rnea,
};
use nalgebra::{DMatrix, DVector, Vector3};

const EPS: f64 = f64::EPSILON;

/// Condition number of a symmetric positive-definite matrix.
fn condition(m: &DMatrix<f64>) -> f64 {
    let ev = m.clone().symmetric_eigenvalues();
    ev.max() / ev.min()
}

#[test]
fn single_pendulum_matches_closed_form() {
    // A body with COM at distance l on the link's z axis, joint about y: the COM sits at (l sin q, 0, l cos q), so
    // tau = (Iyy + m l^2) qdd - m g l sin q, with no velocity term.
    let (m, l, iyy) = (2.3, 0.37, 0.041);
    let model = parse(&(link_xml("l1", m, l, [0.05, iyy, 0.02]) + &joint_xml("j0", "base", "l1", 0.1, "0 1 0")));
    let mut data = Data::new(&model);
    for &(q, qd, qdd) in &[(0.3, 1.2, -0.7), (-2.1, -0.4, 3.0), (0.0, 5.0, 0.0)] {
        let want = (iyy + m * l * l) * qdd - m * GRAVITY * l * f64::sin(q);
        let tau = rnea(&model, &mut data, &[q], &[qd], &[qdd])[0];
        assert!((tau - want).abs() < 1e-13 * want.abs().max(1.0), "rnea {tau} vs {want}");
        let acc = aba(&model, &mut data, &[q], &[qd], &[want])[0];
        assert!((acc - qdd).abs() < 1e-13, "aba {acc} vs {qdd}");
        let mm = crba(&model, &mut data, &[q])[(0, 0)];
        assert!((mm - (iyy + m * l * l)).abs() < 1e-15);
    }
}

#[test]
fn double_pendulum_matches_closed_form() {
    let (m1, l1, i1, len1) = (3.0, 0.21, 0.08, 0.45);
    let (m2, l2, i2) = (1.7, 0.16, 0.03);
    let model = parse(
        &(link_xml("l1", m1, l1, [0.1, i1, 0.05])
            + &link_xml("l2", m2, l2, [0.04, i2, 0.02])
            + &joint_xml("j0", "base", "l1", 0.0, "0 1 0")
            + &joint_xml("j1", "l1", "l2", len1, "0 1 0")),
    );
    let mut data = Data::new(&model);
    let g = GRAVITY;
    let mut rng = Rng::stream(5, &[]);
    for _ in 0..20 {
        let (t1, t2) = (rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0));
        let (d1, d2) = (rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0));
        let (a1, a2) = (rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0));
        let c2 = t2.cos();
        let h = m2 * len1 * l2 * t2.sin();
        let m11 = i1 + i2 + m1 * l1 * l1 + m2 * (len1 * len1 + l2 * l2 + 2.0 * len1 * l2 * c2);
        let m12 = i2 + m2 * (l2 * l2 + len1 * l2 * c2);
        let m22 = i2 + m2 * l2 * l2;
        let g1 = -g * ((m1 * l1 + m2 * len1) * t1.sin() + m2 * l2 * (t1 + t2).sin());
        let g2 = -g * m2 * l2 * (t1 + t2).sin();
        let tau1 = m11 * a1 + m12 * a2 - h * (2.0 * d1 * d2 + d2 * d2) + g1;
        let tau2 = m12 * a1 + m22 * a2 + h * d1 * d1 + g2;
        let tau = rnea(&model, &mut data, &[t1, t2], &[d1, d2], &[a1, a2]).to_vec();
        let scale = tau1.abs().max(tau2.abs()).max(1.0);
        assert!(
            (tau[0] - tau1).abs() < 1e-13 * scale && (tau[1] - tau2).abs() < 1e-13 * scale,
            "{tau:?} vs {tau1} {tau2}"
        );
        let mm = crba(&model, &mut data, &[t1, t2]);
        for (got, want) in [(mm[(0, 0)], m11), (mm[(0, 1)], m12), (mm[(1, 0)], m12), (mm[(1, 1)], m22)] {
            assert!((got - want).abs() < 1e-14, "M {got} vs {want}");
        }
        let gt = gravity_torque(&model, &mut data, &[t1, t2]).to_vec();
        assert!((gt[0] - g1).abs() < 1e-13 * scale && (gt[1] - g2).abs() < 1e-13 * scale);
    }
}

#[test]
fn aba_equals_inverse_mass_matrix_times_bias_free_torque_and_inverts_rnea() {
    let mut rng = Rng::stream(11, &[]);
    for id in 0..50 {
        let model = robot(id).model;
        let mut data = Data::new(&model);
        for _ in 0..20 {
            let (q, qd, _) = random_state(&model, &mut rng);
            let tau: Vec<f64> = model.joints().iter().map(|j| rng.uniform(-0.3, 0.3) * j.limits.effort).collect();
            let b = DVector::from_column_slice(nonlinear_effects(&model, &mut data, &q, &qd));
            let m = crba(&model, &mut data, &q).clone();
            let want =
                m.clone().cholesky().expect("M is positive definite").solve(&(DVector::from_column_slice(&tau) - &b));
            let qdd = DVector::from_column_slice(aba(&model, &mut data, &q, &qd, &tau));
            // Two backward-stable solvers of M x = r agree to about cond(M) * eps relative to |x|.
            let tol = 100.0 * condition(&m) * EPS * want.norm();
            assert!((&qdd - &want).norm() < tol, "robot {id}: |diff| {} > {tol}", (&qdd - &want).norm());
            // RNEA(q, qd, ABA(q, qd, tau)) == tau: RNEA is a forward, well-conditioned evaluation.
            let back = DVector::from_column_slice(rnea(&model, &mut data, &q, &qd, qdd.as_slice()));
            let tau_v = DVector::from_column_slice(&tau);
            let tol = 100.0 * condition(&m) * EPS * tau_v.norm();
            assert!((&back - &tau_v).norm() < tol, "robot {id}: rnea(aba) off by {}", (&back - &tau_v).norm());
        }
    }
}

#[test]
fn regressor_times_parameters_is_rnea_plus_friction() {
    let mut rng = Rng::stream(12, &[]);
    for id in 0..30 {
        let model = robot(id).model;
        let pi = DVector::from_vec(dynamic_parameters(&model));
        let mut data = Data::new(&model);
        let mut fric = vec![0.0; model.dof()];
        for _ in 0..20 {
            let (q, qd, qdd) = random_state(&model, &mut rng);
            let mut want = DVector::from_column_slice(rnea(&model, &mut data, &q, &qd, &qdd));
            friction_torque(&model, &qd, &mut fric);
            want += DVector::from_column_slice(&fric);
            let y = regressor(&model, &mut data, &q, &qd, &qdd).clone();
            let got = &y * &pi;
            // Same arithmetic regrouped: a few hundred roundings of terms bounded by |Y| |pi|.
            let tol = 1e3 * EPS * y.abs().max() * pi.abs().max() * pi.len() as f64;
            assert!((&got - &want).norm() < tol, "robot {id}: |Y pi - tau| = {} > {tol}", (&got - &want).norm());
        }
    }
}

#[test]
fn mass_matrix_is_symmetric_positive_definite_and_gives_kinetic_energy() {
    let mut rng = Rng::stream(13, &[]);
    let model = robot(3).model;
    let mut data = Data::new(&model);
    for _ in 0..50 {
        let (q, qd, _) = random_state(&model, &mut rng);
        let m = crba(&model, &mut data, &q).clone();
        assert_eq!(m, m.transpose());
        assert!(m.clone().cholesky().is_some());
        let qdv = DVector::from_column_slice(&qd);
        let ke_crba = 0.5 * qdv.dot(&(&m * &qdv));
        let ke = energy(&model, &mut data, &q, &qd).kinetic;
        assert!((ke - ke_crba).abs() < 1e-13 * ke.max(1.0), "{ke} vs {ke_crba}");
    }
}

#[test]
fn gravity_torque_is_the_gradient_of_potential_energy() {
    // Central differences: truncation error h^2/6 |V'''| ~ 1e-12 with h = 1e-6 and |V'''| ~ 100 J; rounding
    // |V| eps / h ~ 1e-9 for |V| ~ 50 J. Tolerance 1e-7 bounds both with margin.
    let mut rng = Rng::stream(14, &[]);
    let model = robot(4).model;
    let mut data = Data::new(&model);
    let zero = vec![0.0; 6];
    let h = 1e-6;
    for _ in 0..20 {
        let (q, _, _) = random_state(&model, &mut rng);
        let g = gravity_torque(&model, &mut data, &q).to_vec();
        for j in 0..6 {
            let (mut qp, mut qm) = (q.clone(), q.clone());
            qp[j] += h;
            qm[j] -= h;
            let dv = (energy(&model, &mut data, &qp, &zero).potential
                - energy(&model, &mut data, &qm, &zero).potential)
                / (2.0 * h);
            assert!((dv - g[j]).abs() < 1e-7, "joint {j}: dV/dq {dv} vs G {}", g[j]);
        }
    }
}

#[test]
fn jacobian_matches_finite_differences_of_forward_kinematics() {
    // Same error budget as above: positions ~1 m, h = 1e-6 -> rounding ~2e-10, truncation ~1e-12.
    let mut rng = Rng::stream(15, &[]);
    let model = robot(5).model;
    let mut data = Data::new(&model);
    let h = 1e-6;
    for _ in 0..20 {
        let (q, _, _) = random_state(&model, &mut rng);
        for link in 0..6 {
            let p = Vector3::new(rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(0.0, 0.4));
            forward_kinematics(&model, &mut data, &q);
            point_jacobian(&model, &mut data, link, &p);
            let jac = data.jacobian.clone();
            for j in 0..6 {
                let mut world = |dq: f64| {
                    let mut qq = q.clone();
                    qq[j] += dq;
                    forward_kinematics(&model, &mut data, &qq);
                    (data.o_m_i[link].point(&p), data.o_m_i[link].rot)
                };
                let ((pp, rp), (pm, rm), (_, r0)) = (world(h), world(-h), world(0.0));
                let dp = (pp - pm) / (2.0 * h);
                // Angular velocity from the skew part of dR/dq R^T.
                let w = (rp - rm) / (2.0 * h) * r0.transpose();
                let dw = Vector3::new(w[(2, 1)] - w[(1, 2)], w[(0, 2)] - w[(2, 0)], w[(1, 0)] - w[(0, 1)]) / 2.0;
                for r in 0..3 {
                    assert!((jac[(r, j)] - dp[r]).abs() < 1e-7, "link {link} joint {j} row {r}");
                    assert!((jac[(r + 3, j)] - dw[r]).abs() < 1e-8, "link {link} joint {j} angular row {r}");
                }
            }
        }
    }
}

#[test]
fn aba_with_locked_joints_matches_the_reduced_mass_matrix_solve() {
    // Locking joints K (qd_K = 0) leaves M_FF qdd_F = tau_F - b_F for the free joints, and each locked joint needs
    // tau_K - b_K - M_KF qdd_F to stay put. Independent route: CRBA + RNEA + a dense Cholesky solve.
    use dynforge_robot::aba_locked;
    let mut rng = Rng::stream(16, &[]);
    for id in 0..20 {
        let model = robot(id).model;
        let mut data = Data::new(&model);
        for mask in 1u32..64 {
            if mask % 7 != id as u32 % 7 {
                continue;
            }
            let locked: Vec<bool> = (0..6).map(|j| mask & (1 << j) != 0).collect();
            let (q, mut qd, _) = random_state(&model, &mut rng);
            for j in 0..6 {
                if locked[j] {
                    qd[j] = 0.0;
                }
            }
            let tau: Vec<f64> = model.joints().iter().map(|j| rng.uniform(-0.2, 0.2) * j.limits.effort).collect();
            let b = DVector::from_column_slice(nonlinear_effects(&model, &mut data, &q, &qd));
            let m = crba(&model, &mut data, &q).clone();
            let free: Vec<usize> = (0..6).filter(|&j| !locked[j]).collect();
            let mff = DMatrix::from_fn(free.len(), free.len(), |r, c| m[(free[r], free[c])]);
            let rhs = DVector::from_fn(free.len(), |r, _| tau[free[r]] - b[free[r]]);
            let qdd_f = mff.cholesky().unwrap().solve(&rhs);
            let mut want = DVector::zeros(6);
            for (r, &j) in free.iter().enumerate() {
                want[j] = qdd_f[r];
            }
            let hold = &m * &want;
            let got = aba_locked(&model, &mut data, &q, &qd, &tau, &locked).to_vec();
            let tol = 100.0 * condition(&m) * EPS * want.norm().max(1.0);
            for j in 0..6 {
                assert!(
                    (got[j] - want[j]).abs() < tol,
                    "robot {id} mask {mask:06b} qdd[{j}] {} vs {}",
                    got[j],
                    want[j]
                );
                let needed = if locked[j] { tau[j] - b[j] - hold[j] } else { 0.0 };
                let scale = tau.iter().fold(1.0f64, |a, t| a.max(t.abs()));
                assert!(
                    (data.tau[j] - needed).abs() < 1e-9 * scale,
                    "robot {id} mask {mask:06b} hold[{j}] {} vs {needed}",
                    data.tau[j]
                );
            }
        }
    }
}
