//! Whether the spreads `estimate` reports are standard deviations: on robots the estimator never saw (a dataset of
//! another seed), each label's error over its reported spread, `z = (value - truth) / spread`, should fall within 1
//! about 68 % of the time and within 2 about 95 %. Measured for the estimator alone (its spread: the evidence's
//! posterior as `report.json`'s calibration puts it, or the validation RMSE without one) and refined by the log's torques (the posterior spread, what `estimate`
//! prints), from one log and from all of a robot's logs.
//!
//! Usage: dynforge-bench-coverage CHECKPOINT DATA [--robots N] [--dump FILE.tsv] [--noise LEVEL]
//!
//! `--dump` writes every label of every robot under both protocols: truth, the estimator's value and spread, the
//! refined value and standard deviation, the family's spread, the evidence's own spread (NaN for the transformer),
//! the logs' measured noise (the median over moving joints of each one's torque NRMSE, below the floor too), their
//! batch scatter (`BatchScatter::ratio`) and the evidence's deviation from the estimate (what the calibration scales).
//! `--noise` adds white noise of that fraction of each joint's torque RMS to every recorded torque (a real robot's
//! effort sensing; the logs' noise is then measured above the floor, and the calibration's part for that noise
//! applies). Streams differ from `evaluate`'s validation noise, and so do the robots.

use anyhow::{Context, Result, bail};
use dynforge_evaluation::spread::{Noise, add_effort_noise};
use dynforge_proto::{LABELS, LabelKind, NUM_LABELS};
use dynforge_recording::Recording;
use dynforge_trainer::inference::Predictor;
use std::collections::BTreeMap;

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Each label's `z` for one robot under one protocol: the estimator's and the refined one, and the rows of `--dump`.
struct Zs {
    estimator: [f64; NUM_LABELS],
    refined: [f64; NUM_LABELS],
    rows: String,
}

fn zs(predictor: &Predictor, recs: &[&Recording], truth: &[f64; NUM_LABELS], robot: u64) -> Result<Zs> {
    let e = predictor.estimate(recs)?;
    let r = predictor.refine(recs, &e)?;
    let noise = match Noise::of(false, &e.noise) {
        Noise::Measured(level) => level,
        Noise::Floor => f64::NAN,
    };
    let rows = LABELS
        .iter()
        .enumerate()
        .map(|(k, l)| {
            format!(
                "{}\t{robot}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\n",
                recs.len(),
                l.name,
                truth[k],
                e.labels[k],
                e.spread[k],
                r.labels[k],
                r.std[k],
                e.family[k],
                e.posterior.map_or(f64::NAN, |p| p[k]),
                e.plug_in.map_or(f64::NAN, |p| p[k]),
                noise,
                e.scatter.unwrap_or(f64::NAN),
                e.deviation.map_or(f64::NAN, |p| p[k])
            )
        })
        .collect();
    Ok(Zs {
        estimator: std::array::from_fn(|k| (e.labels[k] - truth[k]) / e.spread[k]),
        refined: std::array::from_fn(|k| (r.labels[k] - truth[k]) / r.std[k]),
        rows,
    })
}

/// The label kinds as the table groups them.
fn group(kind: LabelKind) -> &'static str {
    match kind {
        LabelKind::Coulomb | LabelKind::Viscous => "friction",
        LabelKind::Mass => "mass",
        LabelKind::Com => "com",
        _ => "inertia",
    }
}

/// Rows of the table: per group, the fraction within 1 and 2 spreads, the median and largest |z|, and how many lie
/// beyond 4 spreads.
fn table(name: &str, per_robot: &[[f64; NUM_LABELS]]) {
    let mut groups: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
    for z in per_robot {
        for (k, l) in LABELS.iter().enumerate() {
            groups.entry(group(l.kind)).or_default().push(z[k].abs());
            groups.entry("all").or_default().push(z[k].abs());
        }
    }
    for (g, mut v) in groups {
        v.sort_by(f64::total_cmp);
        let within = |c: f64| 100.0 * v.iter().filter(|&&z| z < c).count() as f64 / v.len() as f64;
        println!(
            "| {name} | {g} | {} | {:.0} % | {:.0} % | {:.2} | {:.1} | {} |",
            v.len(),
            within(1.0),
            within(2.0),
            v[v.len() / 2],
            v[v.len() - 1],
            v.iter().filter(|&&z| z > 4.0).count()
        );
    }
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let (mut positional, mut robots, mut dump, mut noise) = (Vec::new(), usize::MAX, None, 0.0);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--robots" => robots = args.next().context("--robots needs a value")?.parse()?,
            "--dump" => dump = Some(args.next().context("--dump needs a file")?),
            "--noise" => noise = args.next().context("--noise needs a level")?.parse()?,
            _ if a.starts_with("--") => bail!("unknown option {a}"),
            _ => positional.push(a),
        }
    }
    let [ckpt, data] = positional.as_slice() else { bail!("usage: dynforge-bench-coverage CHECKPOINT DATA") };
    let predictor = Predictor::load(std::path::Path::new(ckpt))?;
    let by_robot = dynforge_recording::dataset::shards_by_robot(std::path::Path::new(data))?;
    let chosen: Vec<(u64, Vec<std::path::PathBuf>)> = by_robot.into_iter().take(robots).collect();
    eprintln!("{} robots of {data}", chosen.len());
    let results = dynforge_proto::parallel::map_in_order(&chosen, |(robot, paths)| -> Result<(Zs, Zs, usize)> {
        let mut recs: Vec<Recording> =
            paths.iter().map(|p| dynforge_recording::read(p, None)).collect::<Result<_, _>>()?;
        for (t, rec) in recs.iter_mut().enumerate() {
            add_effort_noise(rec, noise, &mut dynforge_robot::rng::Rng::stream(*robot, &[t as u64]));
        }
        let truth = recs[0].labels.with_context(|| format!("robot {robot}: no labels"))?;
        let refs: Vec<&Recording> = recs.iter().collect();
        Ok((zs(&predictor, &refs[..1], &truth, *robot)?, zs(&predictor, &refs, &truth, *robot)?, recs.len()))
    });
    let (mut rows, mut failed) = (Vec::new(), 0);
    for r in results {
        match r {
            Ok(r) => rows.push(r),
            Err(e) => {
                failed += 1;
                eprintln!("skipped: {e:#}");
            }
        }
    }
    if let Some(file) = &dump {
        let mut text = String::from(
            "logs\trobot\tlabel\ttruth\testimator\testimator_spread\trefined\trefined_std\tfamily\tevidence\tplug_in\tnoise\tscatter\tdeviation\n",
        );
        for r in &rows {
            text.push_str(&r.0.rows);
            text.push_str(&r.1.rows);
        }
        std::fs::write(file, text).with_context(|| format!("writing {file}"))?;
    }
    let logs = rows.first().map_or(0, |r| r.2);
    println!("{} robots ({failed} skipped), {logs} logs each; z = (value - truth) / spread\n", rows.len());
    println!("| estimate | labels | n | abs(z) < 1 | abs(z) < 2 | median abs(z) | largest | beyond 4 |");
    println!("|---|---|---|---|---|---|---|---|");
    type Row = (Zs, Zs, usize);
    let pick = |f: fn(&Row) -> [f64; NUM_LABELS]| rows.iter().map(f).collect::<Vec<_>>();
    table("estimator, 1 log", &pick(|r| r.0.estimator));
    table("refined, 1 log", &pick(|r| r.0.refined));
    table(&format!("estimator, {logs} logs"), &pick(|r| r.1.estimator));
    table(&format!("refined, {logs} logs"), &pick(|r| r.1.refined));
    Ok(())
}
