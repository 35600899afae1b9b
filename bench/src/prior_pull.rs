//! How a noise-free log's posterior errs. With the prior `z ~ N(0, I)` in its own coordinates and exact torques,
//! the evidence is `b = H z` and the posterior mean `(I + H)^-1 H z = z - P^-1 z` (`P = I + H`): the truth less the
//! prior's pull. What is left over is the model's error (the pairing's discretization). The pull maps to a label
//! through the labels' own map, which is not linear (a centre of mass is a first moment over a mass; a moment about
//! it subtracts `m c^2`), so a label can sit further from its plug-in than the linear pull says.
//!
//! Usage: dynforge-bench-prior-pull CHECKPOINT DATA [--robot ID] [--tails N]
//!
//! Per robot (its first log): the truth's mean square and largest coordinate, how far the posterior mean lies from
//! `z - P^-1 z` (the largest over coordinates, in posterior standard deviations), and the label whose plug-in lies
//! furthest from the truth in posterior spreads, with its linear pull in the same units. `--robot` prints every
//! label of one robot: the plug-in's error, the linear pull, and both against the posterior spread and against the
//! pull's own spread (`sqrt(g^T P^-2 g)`: the spread of the error over robots drawn from the prior). `--tails` draws
//! N robots from the generator (default configuration, a seed of their own) and prints each prior coordinate's
//! variance, excess kurtosis and fractions beyond 3 and 4: how Gaussian the family the prior stands for is.

use anyhow::{Context, Result, bail};
use dynforge_identify::{ParameterPrior, labels_of_parameters};
use dynforge_proto::{LABELS, NUM_LABELS};
use dynforge_trainer::inference::Predictor;

/// A posterior's covariance applied to vectors of its coordinates.
struct Covariance(Vec<Vec<f64>>);

impl Covariance {
    fn apply(&self, v: &[f64]) -> Vec<f64> {
        self.0.iter().map(|row| row.iter().zip(v).map(|(a, b)| a * b).sum()).collect()
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The gradient of label `k` in the prior's coordinates at `z`, by central differences.
fn gradient(prior: &ParameterPrior, z: &[f64], k: usize) -> Vec<f64> {
    let h = 1e-5;
    (0..z.len())
        .map(|i| {
            let at = |d: f64| {
                let mut zz = z.to_vec();
                zz[i] += d;
                labels_of_parameters(&prior.parameters(&zz))[k]
            };
            (at(h) - at(-h)) / (2.0 * h)
        })
        .collect()
}

/// One label of one robot: the plug-in's error, the linear pull, the posterior's spread and the pull's spread.
struct Pull {
    error: f64,
    linear: f64,
    posterior: f64,
    spread: f64,
}

fn pulls(prior: &ParameterPrior, mean: &[f64], cov: &Covariance, z: &[f64], truth: &[f64; NUM_LABELS]) -> Vec<Pull> {
    let plug = labels_of_parameters(&prior.parameters(mean));
    let pull = cov.apply(z);
    (0..NUM_LABELS)
        .map(|k| {
            let g = gradient(prior, mean, k);
            let pg = cov.apply(&g);
            Pull {
                error: plug[k] - truth[k],
                linear: -dot(&g, &pull),
                posterior: dot(&g, &pg).max(0.0).sqrt(),
                spread: dot(&pg, &pg).sqrt(),
            }
        })
        .collect()
}

fn tails(prior: &ParameterPrior, n: u64) -> Result<()> {
    let cfg = dynforge_proto::generator::GeneratorConfig::default();
    let ids: Vec<u64> = (0..n).collect();
    let zs = dynforge_proto::parallel::map_in_order(&ids, |&id| {
        dynforge_robot::generator::generate(&cfg, 0x7461_696c, id)
            .map(|r| prior.coordinates(&dynforge_robot::parameters::dynamic_parameters(&r.model)))
    })
    .into_iter()
    .collect::<Result<Vec<_>, _>>()?;
    println!("coordinate\tvariance\texcess kurtosis\tbeyond 3\tbeyond 4\tlargest");
    for i in 0..prior.rank() {
        let v: Vec<f64> = zs.iter().map(|z| z[i]).collect();
        let moment = |p: i32| v.iter().map(|x| x.powi(p)).sum::<f64>() / n as f64;
        let beyond = |t: f64| v.iter().filter(|x| x.abs() > t).count() as f64 / n as f64;
        let largest = v.iter().fold(0.0f64, |a, x| a.max(x.abs()));
        let (m2, m4) = (moment(2), moment(4));
        println!("{i}\t{m2:.3}\t{:.2}\t{:.4}\t{:.5}\t{largest:.2}", m4 / (m2 * m2) - 3.0, beyond(3.0), beyond(4.0));
    }
    Ok(())
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let (mut positional, mut robot, mut draws) = (Vec::new(), None, None);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--robot" => robot = Some(args.next().context("--robot needs an id")?.parse::<u64>()?),
            "--tails" => draws = Some(args.next().context("--tails needs a count")?.parse::<u64>()?),
            _ if a.starts_with("--") => bail!("unknown option {a}"),
            _ => positional.push(a),
        }
    }
    let [ckpt, data] = positional.as_slice() else { bail!("usage: dynforge-bench-prior-pull CHECKPOINT DATA") };
    let predictor = Predictor::load(std::path::Path::new(ckpt))?;
    let prior = predictor.checkpoint.parameter_prior().context("not a physics checkpoint: it has no prior")?;
    if let Some(n) = draws {
        return tails(&prior, n);
    }
    let r = prior.rank();
    println!("robot\tmean z^2\tlargest z\tmean off z - P^-1 z\tworst label\tplug-in error / posterior\tlinear pull");
    for (id, paths) in dynforge_recording::dataset::shards_by_robot(std::path::Path::new(data))? {
        if robot.is_some_and(|r| r != id) {
            continue;
        }
        let path = paths.first().with_context(|| format!("robot {id}: no recordings"))?;
        let rec = dynforge_recording::read(path, None)?;
        let truth = rec.labels.with_context(|| format!("{}: no labels", path.display()))?;
        let z = prior.coordinates(&dynforge_robot::parameters::dynamic_parameters(&rec.model));
        let (e, _, _) = predictor.windows(&rec)?.1.context("no evidence: not a physics checkpoint")?;
        let post = e.posterior()?;
        let c = post.covariance();
        let cov = Covariance((0..r).map(|i| (0..r).map(|j| c[(i, j)]).collect()).collect());
        let pull = cov.apply(&z);
        let off = (0..r).map(|i| (z[i] - pull[i] - post.mean[i]).abs() / post.variance[i].sqrt()).fold(0.0, f64::max);
        let p = pulls(&prior, &post.mean, &cov, &z, &truth);
        let worst = (0..NUM_LABELS)
            .max_by(|&a, &b| (p[a].error / p[a].posterior).abs().total_cmp(&(p[b].error / p[b].posterior).abs()))
            .unwrap_or(0);
        let w = &p[worst];
        println!(
            "{id}\t{:.2}\t{:.2}\t{off:.3}\t{}\t{:.2}\t{:.2}",
            dot(&z, &z) / r as f64,
            z.iter().fold(0.0f64, |a, v| a.max(v.abs())),
            LABELS[worst].name,
            w.error / w.posterior,
            w.linear / w.posterior
        );
        if robot.is_some() {
            println!("\nlabel\terror\tlinear pull\terror / posterior\tlinear / posterior\terror / pull spread");
            for (l, q) in LABELS.iter().zip(&p) {
                println!(
                    "{}\t{:.3e}\t{:.3e}\t{:.2}\t{:.2}\t{:.2}",
                    l.name,
                    q.error,
                    q.linear,
                    q.error / q.posterior,
                    q.linear / q.posterior,
                    q.error / q.spread
                );
            }
        }
    }
    Ok(())
}
