//! `estimate` end to end on logs noisier than the simulation: one shard of each validation robot is rewritten with
//! white noise on its efforts (each joint at a fraction of its effort RMS), read back as a user's log would be, and
//! estimated three ways: the network on evidence at the noise floor (as if the log's noise were not measured), on
//! evidence weighted by the measured noise (what `estimate` does), and refined by the log's torques (what the URDF
//! gets).
//!
//! Usage: dynforge-bench-noisy-logs CHECKPOINT DATA [--levels 0,1e-3,1e-2] [--robots N]

use anyhow::{Context, Result, bail};
use dynforge_dataset::evidence::recording_evidence;
use dynforge_dataset::metrics::score;
use dynforge_dataset::split::{Split, split_of};
use dynforge_proto::NUM_LABELS;
use dynforge_robot::rng::Rng;
use dynforge_trainer::inference::Predictor;

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// A copy of the shard `from` at `to` with white noise of `level` times each joint's effort RMS on every effort.
fn noisy_copy(from: &std::path::Path, to: &std::path::Path, level: f64, seed: u64) -> Result<()> {
    let mut bag = dynforge_shard::read(from)?;
    let dof = bag.joint_states.first().map_or(0, |m| m.effort.len());
    let n = bag.joint_states.len().max(1) as f64;
    let rms: Vec<f64> =
        (0..dof).map(|j| (bag.joint_states.iter().map(|m| m.effort[j].powi(2)).sum::<f64>() / n).sqrt()).collect();
    let mut rng = Rng::stream(seed, &[level.to_bits()]);
    for m in &mut bag.joint_states {
        for (e, r) in m.effort.iter_mut().zip(&rms) {
            *e += level * r * rng.normal();
        }
    }
    let urdf = bag.robot_description.context("the shard has no robot description")?;
    let content =
        dynforge_shard::ShardContent { urdf: &urdf, joint_states: &bag.joint_states, metadata: &bag.metadata };
    dynforge_shard::write(to, &content)?;
    Ok(())
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let (mut positional, mut levels, mut robots) = (Vec::new(), vec![0.0, 1e-3, 1e-2], usize::MAX);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--levels" => {
                let v = args.next().context("--levels needs a value")?;
                levels = v.split(',').map(|s| s.parse::<f64>()).collect::<Result<_, _>>()?;
            }
            "--robots" => robots = args.next().context("--robots needs a value")?.parse()?,
            _ if a.starts_with("--") => bail!("unknown option {a}"),
            _ => positional.push(a),
        }
    }
    let [ckpt, data] = positional.as_slice() else { bail!("usage: dynforge-bench-noisy-logs CHECKPOINT DATA") };
    let dir = std::path::Path::new(ckpt);
    let predictor = Predictor::load(dir)?;
    let c = &predictor.checkpoint;
    let prior = c.parameter_prior().context("not a physics checkpoint")?;
    let mut shards: Vec<_> = std::fs::read_dir(std::path::Path::new(data).join("shards"))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.contains("-t00")))
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
            dynforge_proto::shard::robot_of_file_name(name)
                .is_some_and(|r| split_of(c.split_seed, r, c.validation_fraction) == Split::Validation)
        })
        .collect();
    shards.sort();
    shards.truncate(robots);
    if shards.is_empty() {
        bail!("{data}: no first trajectory (t00) of a validation robot of {ckpt}");
    }
    let tmp = std::env::temp_dir().join(format!("dynforge-noisy-logs-{}", std::process::id()));
    std::fs::create_dir_all(&tmp)?;
    let scale = c.standardizer().label_std;
    println!("{} validation robots, one log (t00) each; per-robot R2 against the shard's labels", shards.len());
    println!(
        "| effort noise (of RMS) | network, floor | network, measured noise | refined (URDF) | measured noise (NRMSE, median joint) |"
    );
    println!("|---:|---:|---:|---:|---:|");
    for &level in &levels {
        let (mut truth, mut floor, mut weighted, mut refined, mut noise) = (vec![], vec![], vec![], vec![], vec![]);
        for (k, shard) in shards.iter().enumerate() {
            let path = tmp.join(format!("r{k}.mcap"));
            noisy_copy(shard, &path, level, k as u64)?;
            let rec = dynforge_recording::read(&path, None)?;
            truth.push(rec.labels.context("the shard has no labels")?);
            let (_, whole) = recording_evidence(&rec, &prior, &c.window_spec())?;
            floor.push(predictor.predict_evidence(&[whole])?[0]);
            let e = predictor.estimate(&[&rec])?;
            let mut n = e.noise.clone();
            n.sort_by(f64::total_cmp);
            noise.push(n[n.len() / 2]);
            weighted.push(e.labels);
            refined.push(predictor.refine(&[&rec], &e)?.labels);
        }
        let r2 = |p: &[[f64; NUM_LABELS]]| score(p, &truth, &scale).r2;
        noise.sort_by(f64::total_cmp);
        println!(
            "| {level:e} | {:.4} | {:.4} | {:.4} | {:.1e} |",
            r2(&floor),
            r2(&weighted),
            r2(&refined),
            noise[noise.len() / 2]
        );
    }
    std::fs::remove_dir_all(&tmp)?;
    Ok(())
}
