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
    // Izz about the COM 0.05 with the COM on the joint axis: the inertia about the axis is J.
    let text = format!(
        r#"<robot name="turntable"><link name="base"/>
           <link name="disc"><inertial><origin xyz="0 0 0.1"/><mass value="2"/>
             <inertia ixx="0.03" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="{J}"/></inertial></link>
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
    let (mut q, mut qd) = (0.0, 2.0);
    let mut out = JointTrajectory { names: vec!["j0".into()], ..Default::default() };
    for i in 0..samples {
        let t = i as f64 * DT;
        let tau = C + 2.0 * B + 0.6 * (3.0 * t).sin() + 0.2 * (11.0 * t).sin();
        out.t.push(t);
        out.q.push(q);
        out.qd.push(qd);
        out.tau.push(tau);
        let (a, k) = ((tau - C) / B, B / J);
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
    let ls = least_squares(&NormalEquations::of(&model, &traj).unwrap()).unwrap();
    // Only the inertia about the axis (Izz of the joint frame, parameter 9) and the friction pair are identifiable.
    assert_eq!(ls.rank, 3);
    let (j, c, b) = (ls.pi[9], ls.pi[10], ls.pi[11]);
    // The pairing is exact but for the kink of qd at each torque step: the two-step integral of b qd differs from
    // 2 dt b qd_i by b (tau_i - tau_{i-1}) dt / (4 J), and a torque sampled from a smooth signal steps by at most
    // ~2 N m/s x dt: ~5e-6 N m, 1e-5 of the torque. (Central differences of the smooth part err by ~w^2 dt^2 / 6.)
    for (name, got, want) in [("inertia", j, J), ("coulomb", c, C), ("viscous", b, B)] {
        assert!((got - want).abs() < 1e-4 * want, "{name}: {got} vs {want}");
    }

    // The pairing this replaced: the central difference at i with the effort logged at i alone. Solved here
    // independently on the same samples, it misses by half a torque step per sample, which the regression folds
    // into the friction and the inertia: half of ~2 N m/s x dt against a torque spread of ~0.4 N m.
    let (mut a, mut r) = (Matrix3::zeros(), Vector3::zeros());
    for i in 1..traj.len() - 1 {
        let qdd = (traj.qd[i + 1] - traj.qd[i - 1]) / (2.0 * DT);
        let y = Vector3::new(qdd, 1.0, traj.qd[i]);
        a += y * y.transpose();
        r += y * traj.tau[i];
    }
    let naive = a.try_inverse().unwrap() * r;
    let worst = [naive[0] / J, naive[1] / C, naive[2] / B].iter().map(|x| (x - 1.0).abs()).fold(0.0, f64::max);
    assert!(worst > 1e-3, "the naive pairing should be visibly biased: {naive:?}");
}
