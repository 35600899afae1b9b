//! The native engine against physics: energy conservation, stick/slip, and inverse dynamics of its own output.

use dynforge_robot::generator::{GeneratedRobot, generate};

use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::sim::SimConfig;
use dynforge_robot::model::Friction;
use dynforge_robot::{Data, crba, energy, friction_torque, gravity_torque, rnea};
use dynforge_worker::engine::{Engine, NativeEngine, RapierEngine};
use dynforge_worker::job::simulate_tour;
use dynforge_worker::trajectory::{Move, waypoints};

fn robot(id: u64) -> GeneratedRobot {
    generate(&GeneratorConfig::default(), 5, id).unwrap()
}

fn frictionless(r: &GeneratedRobot) -> dynforge_robot::Model {
    let inertials: Vec<_> = r.model.links().iter().map(|l| l.inertial).collect();
    r.model.with_dynamics(&inertials, &[Friction::default(); 6]).unwrap()
}

const Q0: [f64; 6] = [0.3, 0.9, -0.7, 1.1, 0.4, -0.8];
const QD0: [f64; 6] = [0.5, -0.3, 0.8, -1.0, 2.0, 1.5];

/// Largest |E(t) - E(0)| over a free swing of `seconds` from (Q0, QD0), relative to the peak kinetic energy.
fn swing_drift(model: &dynforge_robot::Model, mut engine: impl Engine, dt: f64, seconds: f64) -> f64 {
    let mut data = Data::new(model);
    let (q0, qd0) = (Q0, QD0);
    engine.reset(&q0, &qd0);
    let e0 = energy(model, &mut data, &q0, &qd0).total();
    let (mut drift, mut peak_kinetic) = (0.0f64, 0.0f64);
    for _ in 0..(seconds / dt).round() as usize {
        engine.step(&[0.0; 6]);
        let e = energy(model, &mut data, engine.q(), engine.qd());
        drift = drift.max((e.total() - e0).abs());
        peak_kinetic = peak_kinetic.max(e.kinetic);
    }
    drift / peak_kinetic
}

#[test]
fn free_swing_conserves_energy_at_fourth_order() {
    // RK4's global error is O(h^4): halving the step must shrink the energy drift ~16x (>= 8x allowing for the
    // chaotic swing and rounding), and at the 1 ms production step the drift over 10 s must stay below 1e-4 of the
    // peak kinetic energy (the target).
    let model = frictionless(&robot(2));
    let coarse = swing_drift(&model, NativeEngine::new(&model, 1e-3), 1e-3, 10.0);
    let fine = swing_drift(&model, NativeEngine::new(&model, 5e-4), 5e-4, 10.0);
    assert!(coarse < 1e-4, "drift {coarse:e} over 10 s at 1 ms");
    assert!(coarse / fine > 8.0, "drift ratio {} (coarse {coarse:e}, fine {fine:e}) is not 4th order", coarse / fine);
}

#[test]
fn stiction_holds_below_the_coulomb_limit_and_breaks_away_above() {
    let r = robot(3);
    let model = &r.model;
    let mut data = Data::new(model);
    let q0 = [0.2, 0.6, -0.9, 0.7, 0.3, -0.4];
    let g = gravity_torque(model, &mut data, &q0).to_vec();
    let mu5 = model.joints()[5].friction.coulomb;
    let mut engine = NativeEngine::new(model, 1e-3);

    // Exactly the holding torque, then 90 % of the Coulomb limit on top of it at joint 5: nothing may move at all.
    for extra in [0.0, 0.9 * mu5, -0.9 * mu5] {
        engine.reset(&q0, &[0.0; 6]);
        let mut tau: [f64; 6] = std::array::from_fn(|j| g[j]);
        tau[5] += extra;
        for _ in 0..500 {
            engine.step(&tau);
        }
        assert_eq!(engine.q(), &q0, "extra {extra}");
        assert_eq!(engine.qd(), &[0.0; 6], "extra {extra}");
    }

    // 110 % of the limit: joint 5 breaks away in the push direction. With the other joints held (their needed
    // friction is far below their limits) it is a 1-DOF system M_55 v' = 0.1 mu_c - mu_v v over the first period
    // (velocity-product terms are O(v^2), negligible from rest), so v(dt) = F / mu_v (1 - exp(-mu_v dt / M_55)).
    engine.reset(&q0, &[0.0; 6]);
    let mut tau: [f64; 6] = std::array::from_fn(|j| g[j]);
    tau[5] += 1.1 * mu5;
    engine.step(&tau);
    let m55 = crba(model, &mut data, &q0)[(5, 5)];
    let mu_v = model.joints()[5].friction.viscous;
    let expected = 0.1 * mu5 / mu_v * (1.0 - (-mu_v * 1e-3 / m55).exp());
    let got = engine.qd()[5];
    assert!(got > 0.0 && ((got - expected) / expected).abs() < 1e-3, "qd5 {got} vs {expected}");
    assert_eq!(&engine.qd()[..5], &[0.0; 5]);
}

/// Relative RMS of `RNEA(midpoint state, mean acceleration) + friction - torque` over the periods where every joint
/// slides throughout, from consecutive samples `(q, qd)` and the torque held between them; and how many periods.
fn inverse_dynamics_residual(
    model: &dynforge_robot::Model,
    q: &[Vec<f64>],
    qd: &[Vec<f64>],
    tau: &[Vec<f64>],
    dt: f64,
) -> (f64, usize) {
    let mut data = Data::new(model);
    let (mut err2, mut ref2, mut used) = (0.0, 0.0, 0);
    let mut fric = [0.0; 6];
    for k in 0..q.len() - 1 {
        let (v0, v1) = (&qd[k], &qd[k + 1]);
        if (0..6).any(|j| v0[j] * v1[j] <= 0.0) {
            continue;
        }
        let qm: Vec<f64> = (0..6).map(|j| 0.5 * (q[k][j] + q[k + 1][j])).collect();
        let vm: Vec<f64> = (0..6).map(|j| 0.5 * (v0[j] + v1[j])).collect();
        let acc: Vec<f64> = (0..6).map(|j| (v1[j] - v0[j]) / dt).collect();
        let id = rnea(model, &mut data, &qm, &vm, &acc).to_vec();
        friction_torque(model, &vm, &mut fric);
        for j in 0..6 {
            err2 += (id[j] + fric[j] - tau[k][j]).powi(2);
            ref2 += tau[k][j].powi(2);
        }
        used += 1;
    }
    ((err2 / ref2).sqrt(), used)
}

#[test]
fn logged_torque_matches_inverse_dynamics_of_the_logged_motion() {
    // Sample k holds the state at t_k and the torque held over [t_k, t_k+1]. The mean acceleration over the period
    // is (qd_k+1 - qd_k) / dt; RNEA at the midpoint state plus friction reproduces the torque up to the midpoint
    // rule's O(dt^2) error, (omega dt)^2 / 24 ~ 1e-5 for the ~20 rad/s closed loop. Samples where a joint sticks or
    // reverses are excluded: there the friction torque is not sign(qd) mu_c.
    let r = robot(4);
    let cfg = SimConfig::default();
    let tour = waypoints(&r, 5, &cfg.trajectory).unwrap();
    let mv = Move::of_tour(&r.model, &tour, 0, &cfg.trajectory);
    let rec = simulate_tour(&r, &mv, &cfg).expect("the run completes");
    let (rel, used) = inverse_dynamics_residual(&r.model, &rec.q, &rec.qd, &rec.tau, rec.dt);
    assert!(used > rec.len() / 4, "only {used} of {} samples slide on every joint", rec.len());
    assert!(rel < 1e-3, "relative RMS torque residual {rel:e} over {used} samples");
}

#[test]
fn rapier_inverse_dynamics_residual_is_its_first_order_integration_error() {
    // rapier integrates with semi-implicit Euler substeps, so the same midpoint check leaves an O(h) residual:
    // quadrupling the substeps must cut it ~4x (accepted: 2.5-6x). Frictionless, under a varying torque, so the
    // check isolates the integrator (rapier's dry-friction constraint is a separate model; see docs/generator.md).
    let model = frictionless(&robot(4));
    let residual = |substeps: usize| {
        let mut engine = RapierEngine::new(&model, 1e-3, substeps);
        engine.reset(&Q0, &QD0);
        let (mut q, mut qd, mut tau) = (vec![engine.q().to_vec()], vec![engine.qd().to_vec()], Vec::new());
        for k in 0..300 {
            let t = [20.0 * (k as f64 * 0.01).sin(), 30.0, 10.0, 2.0, 0.5, 0.3];
            engine.step(&t);
            tau.push(t.to_vec());
            q.push(engine.q().to_vec());
            qd.push(engine.qd().to_vec());
        }
        inverse_dynamics_residual(&model, &q, &qd, &tau, 1e-3).0
    };
    let (r8, r32) = (residual(8), residual(32));
    assert!((2.5..6.0).contains(&(r8 / r32)), "residual {r8:e} (8 substeps) vs {r32:e} (32): not first order");
}

#[test]
fn same_job_gives_bit_identical_recordings() {
    let r = robot(6);
    let cfg = SimConfig::default();
    let tour = waypoints(&r, 5, &cfg.trajectory).unwrap();
    let mv = Move::of_tour(&r.model, &tour, 3, &cfg.trajectory);
    let a = simulate_tour(&r, &mv, &cfg);
    let b = simulate_tour(&r, &mv, &cfg);
    assert_eq!(a, b);
}

#[test]
fn rapier_free_swing_drift_is_first_order_in_the_substep() {
    // Semi-implicit Euler is first order: doubling the substeps must about halve the drift (ratio in [1.5, 3]).
    let model = frictionless(&robot(2));
    let coarse = swing_drift(&model, RapierEngine::new(&model, 1e-3, 4), 1e-3, 2.0);
    let fine = swing_drift(&model, RapierEngine::new(&model, 1e-3, 8), 1e-3, 2.0);
    let ratio = coarse / fine;
    assert!((1.5..3.0).contains(&ratio), "drift {coarse:e} (4 substeps) / {fine:e} (8 substeps) = {ratio}");
}

#[test]
fn engines_agree_within_rapiers_first_order_error() {
    // The same free swing in both engines: native RK4's error is ~1e-9 here, so the difference is rapier's own
    // O(h) error, which must shrink about 2x when its substeps double, and be small in absolute terms.
    let model = frictionless(&robot(2));
    let run = |mut engine: Box<dyn Engine>| -> Vec<Vec<f64>> {
        engine.reset(&Q0, &QD0);
        (0..500)
            .map(|_| {
                engine.step(&[0.0; 6]);
                engine.q().to_vec()
            })
            .collect()
    };
    let native = run(Box::new(NativeEngine::new(&model, 1e-3)));
    let gap = |substeps: usize| {
        let r = run(Box::new(RapierEngine::new(&model, 1e-3, substeps)));
        r.iter().zip(&native).flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs())).fold(0.0, f64::max)
    };
    let (g8, g16) = (gap(8), gap(16));
    assert!(g8 < 5e-3, "max |q_rapier - q_native| over 0.5 s = {g8}");
    assert!((1.5..3.0).contains(&(g8 / g16)), "gap {g8:e} (8 substeps) vs {g16:e} (16): not first order");
}
