//! How the physics estimator's per-robot accuracy falls with torque noise that the simulated data do not have, and
//! how much of it comes back when the evidence is weighted by the true noise. A sim-to-real question answered
//! without simulating: evidence is `H = sum A^T A / s^2`, `b = sum A^T tau / s^2` at the noise floor `s`, so white
//! torque noise of `k s` adds `N(0, k^2 H)` to `b` exactly (the regressor's own inputs stay exact). The
//! noise-aware variant divides both by `1 + k^2`, the weights of the true noise.
//!
//! Usage: dynforge-bench-noise CHECKPOINT DATA [--levels 0,1e-4,1e-3,1e-2] [--logs N]
//! (levels in units of each joint's torque RMS; --logs: recordings per robot summed, all when 0).

use anyhow::{Context, Result, bail};
use dynforge_dataset::cache::evidence::PhysicsSet;
use dynforge_dataset::evidence::NOISE_FLOOR;
use dynforge_dataset::metrics::score;
use dynforge_dataset::split::{Split, split_of};
use dynforge_identify::Evidence;
use dynforge_proto::{LABELS, LabelKind, NUM_LABELS};
use dynforge_robot::rng::Rng;
use dynforge_trainer::inference::Predictor;

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn weighted(e: &Evidence, w: f64) -> Evidence {
    Evidence { rank: e.rank, h: e.h.iter().map(|x| x * w).collect(), b: e.b.iter().map(|x| x * w).collect() }
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let (mut positional, mut levels, mut logs) = (Vec::new(), vec![0.0, 1e-4, 1e-3, 1e-2], 0usize);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--levels" => {
                let v = args.next().context("--levels needs a value")?;
                levels = v.split(',').map(|s| s.parse::<f64>()).collect::<Result<_, _>>()?;
            }
            "--logs" => logs = args.next().context("--logs needs a value")?.parse()?,
            _ if a.starts_with("--") => bail!("unknown option {a}"),
            _ => positional.push(a),
        }
    }
    let [ckpt, data] = positional.as_slice() else { bail!("usage: dynforge-bench-noise CHECKPOINT DATA") };
    let predictor = Predictor::load(ckpt.as_ref())?;
    let c = &predictor.checkpoint;
    let prior = c.parameter_prior().context("not a physics checkpoint")?;
    let (set, _) = PhysicsSet::load_or_build(data.as_ref(), &c.window_spec(), &prior, |_, _| true)?;
    let validation = |r: u64| split_of(c.split_seed, r, c.validation_fraction) == Split::Validation;
    let mut robots: std::collections::BTreeMap<u64, (Evidence, [f64; NUM_LABELS], usize)> = Default::default();
    for i in (0..set.recordings.len()).filter(|&i| validation(set.recordings.robots[i])) {
        let e = set.recordings.get(i);
        let entry = robots.entry(set.recordings.robots[i]).or_insert((
            Evidence { h: vec![0.0; e.h.len()], b: vec![0.0; e.b.len()], ..e.clone() },
            set.recordings.labels[i],
            0,
        ));
        if logs == 0 || entry.2 < logs {
            entry.0.add(&e);
            entry.2 += 1;
        }
    }
    let truth: Vec<[f64; NUM_LABELS]> = robots.values().map(|(_, y, _)| *y).collect();
    let scale = c.standardizer().label_std;
    let group = |s: &dynforge_dataset::metrics::Scores, kinds: &[LabelKind]| {
        let v: Vec<f64> =
            (0..NUM_LABELS).filter(|&k| kinds.contains(&LABELS[k].kind)).map(|k| s.targets[k].r2).collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    println!(
        "{} validation robots, {} logs each; noise in units of each joint's torque RMS (floor {NOISE_FLOOR:e})",
        truth.len(),
        if logs == 0 { "all".into() } else { logs.to_string() }
    );
    println!("| noise | weighting | R2 overall | friction | mass | com | inertia |");
    println!("|---:|---|---:|---:|---:|---:|---:|");
    for &level in &levels {
        let k = level / NOISE_FLOOR;
        // Weighted by the true noise; the floor's evidence is the same times 1 + k^2.
        let evidence: Vec<Evidence> = robots
            .iter()
            .map(|(r, (e, _, _))| {
                let mut rng = Rng::stream(7, &[*r, level.to_bits()]);
                let xi: Vec<f64> = (0..e.rank).map(|_| rng.normal()).collect();
                e.with_noise(k, &xi)
            })
            .collect();
        for (name, w) in [("floor (as trained)", 1.0 + k * k), ("true noise", 1.0)] {
            if level == 0.0 && name == "true noise" {
                continue;
            }
            let input: Vec<Evidence> = evidence.iter().map(|e| weighted(e, w)).collect();
            let s = score(&predictor.predict_evidence(&input)?, &truth, &scale);
            println!(
                "| {level:e} | {name} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} |",
                s.r2,
                group(&s, &[LabelKind::Coulomb, LabelKind::Viscous]),
                group(&s, &[LabelKind::Mass]),
                group(&s, &[LabelKind::Com]),
                group(&s, &[LabelKind::Ixx, LabelKind::Iyy, LabelKind::Izz])
            );
        }
    }
    Ok(())
}
