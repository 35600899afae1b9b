//! Microseconds per call of RNEA, ABA, CRBA and the regressor on a URDF, over a fixed set of random states.
//!
//! Usage: dynforge-bench-dynamics ROBOT.urdf [CALLS]. Prints one JSON object. `bench/dynamics.sh` runs it beside
//! Pinocchio on the same file and reports the ratios.

use std::hint::black_box;
use std::time::Instant;

use anyhow::{Context, Result};
use dynforge_robot::rng::Rng;
use dynforge_robot::{Data, aba, crba, regressor, rnea, urdf};

const STATES: usize = 1000;
const REPEATS: usize = 7;

/// Median over `REPEATS` runs of the mean time per call of `f` over the states, in microseconds.
fn time_per_call(calls: usize, mut f: impl FnMut(usize)) -> f64 {
    let mut runs: Vec<f64> = (0..REPEATS)
        .map(|_| {
            let start = Instant::now();
            for k in 0..calls {
                f(k % STATES);
            }
            start.elapsed().as_secs_f64() * 1e6 / calls as f64
        })
        .collect();
    runs.sort_by(f64::total_cmp);
    runs[REPEATS / 2]
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let path = args.next().context("usage: dynforge-bench-dynamics ROBOT.urdf [CALLS]")?;
    let calls: usize = args.next().map(|s| s.parse()).transpose().context("CALLS must be a number")?.unwrap_or(200_000);
    let model = urdf::load(&path)?;
    let n = model.dof();
    let mut rng = Rng::stream(0, &[]);
    let mut draw = |lo: f64, hi: f64| {
        (0..STATES).map(|_| (0..n).map(|_| rng.uniform(lo, hi)).collect::<Vec<_>>()).collect::<Vec<_>>()
    };
    let (q, qd, qdd, tau) = (draw(-3.0, 3.0), draw(-2.0, 2.0), draw(-5.0, 5.0), draw(-20.0, 20.0));
    let mut data = Data::new(&model);
    let rnea_us = time_per_call(calls, |k| {
        black_box(rnea(&model, &mut data, &q[k], &qd[k], &qdd[k])[0]);
    });
    let aba_us = time_per_call(calls, |k| {
        black_box(aba(&model, &mut data, &q[k], &qd[k], &tau[k])[0]);
    });
    let crba_us = time_per_call(calls, |k| {
        black_box(crba(&model, &mut data, &q[k])[(0, 0)]);
    });
    // Identification's inner loop (friction columns included; Pinocchio's has the 10 n inertial ones only).
    let regressor_us = time_per_call(calls, |k| {
        black_box(regressor(&model, &mut data, &q[k], &qd[k], &qdd[k])[(0, 0)]);
    });
    println!(
        "{{\"dof\": {n}, \"calls\": {calls}, \"rnea_us\": {rnea_us:.4}, \"aba_us\": {aba_us:.4}, \"crba_us\": {crba_us:.4}, \"regressor_us\": {regressor_us:.4}}}"
    );
    Ok(())
}
