//! Identification's pairing of torque with motion, against the simulator: the true parameters of a generated robot
//! must reproduce the torques it logged, on every joint, stops and starts included.

use dynforge_identify::NormalEquations;
use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::sim::SimConfig;
use dynforge_recording::JointTrajectory;
use dynforge_robot::generator::generate;
use dynforge_robot::parameters::dynamic_parameters;
use dynforge_worker::job::simulate_tour;
use dynforge_worker::trajectory::{Move, waypoints};

#[test]
fn true_parameters_reproduce_the_simulated_torques_on_every_joint() {
    let cfg = SimConfig::default();
    let mut worst = 0.0f64;
    for (robot, leg) in [(4, 0), (4, 3), (9, 1)] {
        let r = generate(&GeneratorConfig::default(), 5, robot).unwrap();
        let tour = waypoints(&r, 5, &cfg.trajectory).unwrap();
        let mv = Move::of_tour(&r.model, &tour, leg, &cfg.trajectory);
        let rec = simulate_tour(&r, &mv, &cfg).expect("the run completes");
        let traj = JointTrajectory {
            names: r.model.joints().iter().map(|j| j.name.clone()).collect(),
            t: (0..rec.q.len()).map(|i| i as f64 * rec.dt).collect(),
            q: rec.q.concat(),
            qd: rec.qd.concat(),
            tau: rec.tau.concat(),
        };
        let ne = NormalEquations::of(&r.model, &traj).unwrap();
        let e = ne.nrmse(&dynamic_parameters(&r.model));
        println!("robot {robot} leg {leg}: {e:?}");
        worst = e.iter().copied().fold(worst, f64::max);
    }
    // What the pairing leaves is second order in the step: the state at t_i stands for the span's mean state, an
    // error of (omega dt)^2 / 24 of the swinging part of the torque, ~1.7e-5 for the ~20 rad/s closed loop (measured:
    // <= 3e-6). Spans with stops and starts kept in, or the viscous force paired with `qd[i]`, would leave far more
    // on some joint (`docs/measurements.md`).
    assert!(worst < 2e-5, "worst joint's NRMSE of the true parameters: {worst:e}");
}
