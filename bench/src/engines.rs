//! Engine speed and fidelity on one generated robot with its friction removed: steps per second of a torque-free
//! swing at 1 ms, and the energy drift over the run (relative to the peak kinetic energy).
//!
//! Usage: dynforge-bench-engines OUT.urdf [SECONDS=10] [SEED=1] [ID=7]
//! Writes the frictionless robot's URDF to OUT.urdf, so `bench/simulation.sh` can run MuJoCo on the same file, and
//! prints one JSON line per engine configuration.

use std::time::Instant;

use anyhow::{Context, Result};
use dynforge_robot::generator::{GeneratorConfig, generate};
use dynforge_robot::model::Friction;
use dynforge_robot::{Data, Model, energy};
use dynforge_worker::engine::{Engine, NativeEngine, RapierEngine};

/// The swing's initial state (also used by bench/mujoco_engine.py).
const Q0: [f64; 6] = [0.3, 0.9, -0.7, 1.1, 0.4, -0.8];
const QD0: [f64; 6] = [0.5, -0.3, 0.8, -1.0, 2.0, 1.5];
const DT: f64 = 1e-3;

#[allow(clippy::needless_lifetimes)] // the engines borrow the model for 'm
fn measure<'m>(name: &str, model: &'m Model, steps: usize, make: &dyn Fn() -> Box<dyn Engine + 'm>) {
    let mut engine = make();
    engine.reset(&Q0, &QD0);
    let start = Instant::now();
    for _ in 0..steps {
        engine.step(&[0.0; 6]);
    }
    let seconds = start.elapsed().as_secs_f64();
    let final_q = *engine.q();
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
    assert_eq!(final_q, *engine.q(), "{name}: the timed and the checked runs must be the same run");
    println!(
        "{{\"engine\": \"{name}\", \"steps\": {steps}, \"steps_per_s\": {:.0}, \"us_per_step\": {:.3}, \"energy_drift\": {:.3e}}}",
        steps as f64 / seconds,
        seconds * 1e6 / steps as f64,
        drift / peak
    );
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let out = args.next().context("usage: dynforge-bench-engines OUT.urdf [SECONDS] [SEED] [ID]")?;
    let seconds: f64 = args.next().map(|s| s.parse()).transpose().context("SECONDS")?.unwrap_or(10.0);
    let seed: u64 = args.next().map(|s| s.parse()).transpose().context("SEED")?.unwrap_or(1);
    let id: u64 = args.next().map(|s| s.parse()).transpose().context("ID")?.unwrap_or(7);
    let robot = generate(&GeneratorConfig::default(), seed, id)?;
    let inertials: Vec<_> = robot.model.links().iter().map(|l| l.inertial).collect();
    let model = robot.model.with_dynamics(&inertials, &[Friction::default(); 6])?;
    std::fs::write(&out, dynforge_robot::urdf::to_string(&model, &robot.base))
        .with_context(|| format!("writing {out}"))?;
    let steps = (seconds / DT).round() as usize;
    measure("native_rk4", &model, steps, &|| Box::new(NativeEngine::new(&model, DT)));
    for substeps in [4, 8] {
        measure(&format!("rapier_{substeps}_substeps"), &model, steps, &|| {
            Box::new(RapierEngine::new(&model, DT, substeps))
        });
    }
    Ok(())
}
