//! Controller statistics over many generated robots: overshoot, settling, tracking error, torque saturation and
//! discards by reason, for the default worker configuration.
//!
//! Usage: dynforge-bench-controller [ROBOTS=100] [TRAJECTORIES_PER_ROBOT=4] [SEED=1] [ENGINE=native|rapier]
//! [SIM_CONFIG.toml] (a `SimConfig` overriding the defaults, e.g. `[gains]` to try a tuning)

use std::collections::BTreeMap;

use anyhow::{Context, Result};
use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::job::Job;
use dynforge_proto::sim::EngineKind;
use dynforge_proto::sim::SimConfig;
use dynforge_worker::job::Runner;
use dynforge_worker::trajectory::Reference;

fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn arg<T: std::str::FromStr>(k: usize, default: T) -> Result<T> {
    std::env::args().nth(k).map(|s| s.parse().ok().context("bad argument")).transpose().map(|v| v.unwrap_or(default))
}

fn main() -> Result<()> {
    let robots: u64 = arg(1, 100)?;
    let per_robot: u32 = arg(2, 4)?;
    let seed: u64 = arg(3, 1)?;
    let engine = match std::env::args().nth(4).as_deref() {
        Some("rapier") => EngineKind::Rapier,
        _ => EngineKind::Native,
    };
    let base = match std::env::args().nth(5) {
        Some(path) => toml::from_str(&std::fs::read_to_string(&path).with_context(|| format!("reading {path}"))?)
            .with_context(|| format!("parsing {path}"))?,
        None => SimConfig::default(),
    };
    let sim = SimConfig { engine, ..base };
    let mut runner = Runner::new(GeneratorConfig::default(), sim);
    let (mut overshoot, mut overshoot_abs, mut settling, mut tracking, mut saturation) =
        (vec![], vec![], vec![], vec![], vec![]);
    let mut reasons: BTreeMap<&'static str, usize> = BTreeMap::new();
    let start = std::time::Instant::now();
    let mut steps = 0usize;
    for robot in 0..robots {
        for trajectory in 0..per_robot {
            let job = Job { seed, robot, trajectory };
            let result = runner.simulate(&job)?.result;
            let (mv, rec) = match result {
                Ok(done) => done,
                Err(d) => {
                    eprintln!("robot {robot} trajectory {trajectory}: {d}");
                    *reasons.entry(d.code()).or_default() += 1;
                    continue;
                }
            };
            *reasons.entry("ok").or_default() += 1;
            steps += rec.len();
            saturation.push(100.0 * rec.saturated);
            // Overshoot: the furthest a joint goes past its goal, as a share of its move (moves > 0.05 rad).
            let (mut worst, mut worst_abs) = (0.0f64, 0.0f64);
            let mut err2 = 0.0;
            let mut settled_at = mv.duration;
            for (k, q) in rec.q.iter().enumerate() {
                let t = k as f64 * rec.dt;
                let [q_ref, _, _] = mv.at(t);
                for j in 0..6 {
                    let d = mv.goal[j] - mv.start[j];
                    let past = (q[j] - mv.goal[j]) * d.signum();
                    worst_abs = worst_abs.max(past);
                    if d.abs() > 0.05 {
                        worst = worst.max(past / d.abs());
                    }
                    err2 += (q[j] - q_ref[j]).powi(2);
                }
                // Settling: last time after the move's end that some joint is more than 0.01 rad from the goal.
                if t >= mv.duration && (0..6).any(|j| (q[j] - mv.goal[j]).abs() > 0.01) {
                    settled_at = t + rec.dt;
                }
            }
            overshoot.push(100.0 * worst.max(0.0));
            overshoot_abs.push(worst_abs.max(0.0));
            settling.push(settled_at - mv.duration);
            tracking.push((err2 / (6 * rec.len()) as f64).sqrt());
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let total: usize = reasons.values().sum();
    println!(
        "controller statistics: {robots} robots x {per_robot} trajectories, seed {seed}, engine {}",
        engine.name()
    );
    println!(
        "outcomes: {reasons:?} ({:.1} % kept)",
        100.0 * reasons.get("ok").copied().unwrap_or(0) as f64 / total as f64
    );
    println!("{:<34} {:>10} {:>10} {:>10}", "metric", "median", "p95", "max");
    for (name, v) in [
        ("overshoot [% of the move]", &mut overshoot),
        ("overshoot [rad]", &mut overshoot_abs),
        ("settling after the move [s]", &mut settling),
        ("tracking RMS error [rad]", &mut tracking),
        ("samples with torque saturated [%]", &mut saturation),
    ] {
        let max = v.iter().copied().fold(f64::NAN, f64::max);
        println!("{:<34} {:>10.4} {:>10.4} {:>10.4}", name, percentile(v, 0.5), percentile(v, 0.95), max);
    }
    println!(
        "simulated {steps} steps in {wall:.1} s: {:.2} us per step including control and checks",
        wall * 1e6 / steps as f64
    );
    Ok(())
}
