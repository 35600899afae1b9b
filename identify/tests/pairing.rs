//! How torque is paired with acceleration, on a closed-form case: one joint about the vertical axis (gravity does no
//! work on it) with inertia `J`, viscous friction `b` and Coulomb friction `c`, driven by a piecewise-constant torque
//! held over each 1 ms step, exactly as shards and motor drivers log it. While the joint keeps turning one way,
//! `J qdd = tau_i - c - b qd` has the closed-form solution of a first-order system on every step.

use dynforge_identify::{NormalEquations, least_squares};
use dynforge_recording::JointTrajectory;
use dynforge_robot::Model;
use nalgebra::{Matrix3, Vector3};

const DT: f64 = 1e-3;

const J: f64 = 0.05;
const B: f64 = 0.5;
const C: f64 = 0.8;

fn one_joint() -> Model {
    turntable(J)
}

/// The turntable with inertia `j` about its axis (Izz about the COM, with the COM on the axis).
fn turntable(j: f64) -> Model {
    let text = format!(
        r#"<robot name="turntable"><link name="base"/>
           <link name="disc"><inertial><origin xyz="0 0 0.1"/><mass value="2"/>
             <inertia ixx="0.03" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="{j}"/></inertial></link>
           <joint name="j0" type="revolute"><parent link="base"/><child link="disc"/><origin xyz="0 0 0.1"/>
             <axis xyz="0 0 1"/><limit lower="-1000" upper="1000" effort="100" velocity="100"/>
             <dynamics damping="{B}" friction="{C}"/></joint></robot>"#
    );
    dynforge_robot::urdf::parse(&text, "turntable.urdf").unwrap()
}

/// The log: a controller-like torque, `tau(t_i) = c + 2 b + 0.6 sin(3 t_i) + 0.2 sin(11 t_i)` sampled at each step and
/// held over `[t_i, t_i + dt)`; the speed swings between ~0.5 and ~3.5 rad/s without reversing, so Coulomb friction
/// is `c` throughout and separates from viscous friction.
fn log(samples: usize) -> JointTrajectory {
    log_of(samples, J, |t| C + 2.0 * B + 0.6 * (3.0 * t).sin() + 0.2 * (11.0 * t).sin())
}

/// The exact motion of the turntable of inertia `j` under `torque(t_i)` held over each step.
fn log_of(samples: usize, j: f64, torque: impl Fn(f64) -> f64) -> JointTrajectory {
    let (mut q, mut qd) = (0.0, 2.0);
    let mut out = JointTrajectory { names: vec!["j0".into()], ..Default::default() };
    for i in 0..samples {
        let t = i as f64 * DT;
        let tau = torque(t);
        out.t.push(t);
        out.q.push(q);
        out.qd.push(qd);
        out.tau.push(tau);
        let (a, k) = ((tau - C) / B, B / j);
        let decay = (-k * DT).exp();
        q += a * DT + (qd - a) * (1.0 - decay) / k;
        qd = a + (qd - a) * decay;
    }
    assert!(out.qd.iter().all(|&v| v > 0.3), "the joint must not stop");
    out
}

#[test]
fn the_central_difference_is_paired_with_the_mean_of_the_two_efforts_it_integrates() {
    let model = one_joint();
    let traj = log(6000);
    assert_exactly_identified(&model, &traj, J);

    // The naive pairing: the central difference at i with the effort logged at i alone. Solved here
    // independently on the same samples, it misses by half a torque step per sample, which the regression folds
    // into the friction and the inertia: half of ~2 N m/s x dt against a torque spread of ~0.4 N m.
    let worst = worst_of_other_pairing(&traj, J, |i| traj.tau[i]);
    assert!(worst > 1e-3, "the naive pairing should be visibly biased (worst relative error {worst:e})");
}

/// Identifies the turntable from `traj` and checks the inertia `j` and the friction pair exactly.
fn assert_exactly_identified(model: &Model, traj: &JointTrajectory, j: f64) {
    let ls = least_squares(&NormalEquations::of(model, traj).unwrap()).unwrap();
    // Only the inertia about the axis (Izz of the joint frame, parameter 9) and the friction pair are identifiable.
    assert_eq!(ls.rank, 3);
    // For this joint the pairing is exact: integrating J qdd = tau - c - b qd over the two steps gives
    // J (qd[i+1] - qd[i-1]) = (tau[i-1] + tau[i]) dt - 2 c dt - b (q[i+1] - q[i-1]), which is what is regressed.
    // Only rounding remains (~1e-16 relative per sample, amplified by the conditioning).
    for (name, got, want) in [("inertia", ls.pi[9], j), ("coulomb", ls.pi[10], C), ("viscous", ls.pi[11], B)] {
        assert!((got - want).abs() < 1e-8 * want, "{name}: {got} vs {want}");
    }
}

/// Least squares of `tau_at(i) = j qdd + c + b qd[i]` with the central-difference `qdd`, solved independently of the
/// crate: the largest relative error of `(j, c, b)`.
fn worst_of_other_pairing(traj: &JointTrajectory, j: f64, tau_at: impl Fn(usize) -> f64) -> f64 {
    let (mut a, mut r) = (Matrix3::zeros(), Vector3::zeros());
    for i in 1..traj.len() - 1 {
        let qdd = (traj.qd[i + 1] - traj.qd[i - 1]) / (2.0 * DT);
        let y = Vector3::new(qdd, 1.0, traj.qd[i]);
        a += y * y.transpose();
        r += y * tau_at(i);
    }
    let x = a.try_inverse().unwrap() * r;
    [x[0] / j, x[1] / C, x[2] / B].iter().map(|v| (v - 1.0).abs()).fold(0.0, f64::max)
}

#[test]
fn viscous_friction_is_paired_with_the_mean_velocity_of_the_span() {
    // A light joint (viscous rate b / J = 500 /s: the velocity relaxes within a step) under a torque that steps by
    // 0.4 N m every 50 ms, as a controller's output does when the reference changes.
    let light = 1e-3;
    let model = turntable(light);
    let traj = log_of(6000, light, |t| C + 2.0 * B + 0.6 * (3.0 * t).sin() + 0.2 * (20.0 * t).sin().signum());
    assert_exactly_identified(&model, &traj, light);

    // Pairing the viscous force with qd[i] instead misses the kink each torque step puts in qd at t_i: b dt / 4
    // times the step of acceleration, i.e. (b / J) dt / 4 = 1/8 of each 0.4 N m step, folded into the estimates.
    let worst = worst_of_other_pairing(&traj, light, |i| 0.5 * (traj.tau[i - 1] + traj.tau[i]));
    assert!(worst > 1e-3, "pairing with qd[i] should be visibly biased (worst relative error {worst:e})");
}
