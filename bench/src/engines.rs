//! Engine speed and fidelity on generated robots with their friction removed: the cost of a torque-free swing per
//! simulated millisecond, and the energy drift over the run (relative to the peak kinetic energy), for each engine at
//! several step sizes, so that engines can be compared at equal accuracy rather than at equal step size (the drift
//! of a chaotic swing varies by orders of magnitude from robot to robot).
//!
//! Usage: dynforge-bench-engines OUT_DIR [SECONDS=10] [SEED=1] [IDS=1,2,...,8]
//! Writes each frictionless robot's URDF to OUT_DIR/swing_ID.urdf, so `bench/simulation.sh` can run MuJoCo on the
//! same files, and prints one JSON line per robot and engine configuration.

use std::time::Instant;

use anyhow::{Context, Result};
use dynforge_proto::generator::GeneratorConfig;
use dynforge_robot::generator::generate;
use dynforge_robot::model::Friction;
use dynforge_robot::{Data, Model, energy};
use dynforge_worker::engine::{Engine, NativeEngine, RapierEngine};

/// The swing's initial state (also used by bench/mujoco_engine.py).
const Q0: [f64; 6] = [0.3, 0.9, -0.7, 1.1, 0.4, -0.8];
const QD0: [f64; 6] = [0.5, -0.3, 0.8, -1.0, 2.0, 1.5];
const DT: f64 = 1e-3;

#[allow(clippy::needless_lifetimes)] // the engines borrow the model for 'm
fn measure<'m>(
    robot: u64,
    name: &str,
    h_ms: f64,
    model: &'m Model,
    steps: usize,
    make: &dyn Fn() -> Box<dyn Engine + 'm>,
) {
    let mut engine = make();
    engine.reset(&Q0, &QD0);
    let start = Instant::now();
    for _ in 0..steps {
        engine.step(&[0.0; 6]);
    }
    let seconds = start.elapsed().as_secs_f64();
    let final_q = engine.q().to_vec();
    let mut engine = make();
    engine.reset(&Q0, &QD0);
    let mut data = Data::new(model);
    let e0 = energy(model, &mut data, &Q0, &QD0).total();
    let (mut drift, mut peak) = (0.0f64, 0.0f64);
    for _ in 0..steps {
        engine.step(&[0.0; 6]);
        let e = energy(model, &mut data, engine.q(), engine.qd());
        drift = drift.max((e.total() - e0).abs());
        peak = peak.max(e.kinetic);
    }
    assert_eq!(final_q, engine.q(), "{name}: the timed and the checked runs must be the same run");
    println!(
        "{{\"robot\": {robot}, \"engine\": \"{name}\", \"h_ms\": {h_ms}, \"us_per_ms\": {:.3}, \"energy_drift\": {:.3e}}}",
        seconds * 1e6 / (steps as f64 * DT * 1e3),
        drift / peak
    );
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let out = args.next().context("usage: dynforge-bench-engines OUT_DIR [SECONDS] [SEED] [IDS]")?;
    let seconds: f64 = args.next().map(|s| s.parse()).transpose().context("SECONDS")?.unwrap_or(10.0);
    let seed: u64 = args.next().map(|s| s.parse()).transpose().context("SEED")?.unwrap_or(1);
    let ids: Vec<u64> = match args.next() {
        Some(list) => list.split(',').map(|s| s.parse()).collect::<Result<_, _>>().context("IDS")?,
        None => (1..=8).collect(),
    };
    let steps = (seconds / DT).round() as usize;
    for id in ids {
        let robot = generate(&GeneratorConfig::default(), seed, id)?;
        let inertials: Vec<_> = robot.model.links().iter().map(|l| l.inertial).collect();
        let model = robot.model.with_dynamics(&inertials, &[Friction::default(); 6])?;
        let path = std::path::Path::new(&out).join(format!("swing_{id}.urdf"));
        std::fs::write(&path, dynforge_robot::urdf::to_string(&model, &robot.base))
            .with_context(|| format!("writing {}", path.display()))?;
        for substeps in [1, 2, 4] {
            measure(id, "native_rk4", 1.0 / substeps as f64, &model, steps, &|| {
                Box::new(NativeEngine::new(&model, DT).with_min_substeps(substeps))
            });
        }
        for substeps in [4, 8] {
            measure(id, "rapier", 1.0 / substeps as f64, &model, steps, &|| {
                Box::new(RapierEngine::new(&model, DT, substeps))
            });
        }
    }
    Ok(())
}
