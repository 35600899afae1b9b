//! How a noise-free log's posterior errs. With the prior `z ~ N(0, I)` in its own coordinates and exact torques,
//! the evidence is `b = H z` and the posterior mean `(I + H)^-1 H z = z - P^-1 z` (`P = I + H`): the truth less the
//! prior's pull. What is left over is the model's error (the pairing's discretization). The pull maps to a label
//! through the labels' own map, which is not linear (a centre of mass is a first moment over a mass; a moment about
//! it subtracts `m c^2`), so a label can sit further from its plug-in than the linear pull says.
//!
//! Usage: dynforge-bench-prior-pull CHECKPOINT DATA [--robot ID] | CHECKPOINT --tails N
//!
//! Per robot (its first log): the truth's mean square and largest coordinate, how far the posterior mean lies from
//! `z - P^-1 z` (the largest over coordinates, in posterior standard deviations), and the label whose plug-in lies
//! furthest from the truth in posterior spreads, with its linear pull in the same units. `--robot` prints every
//! label of one robot: the plug-in's error, the linear pull, and both against the posterior spread and against the
//! pull's own spread (`sqrt(g^T P^-2 g)`: the spread of the error over robots drawn from the prior). `--tails` draws
//! N robots from the generator (default configuration, a seed of their own) and prints each prior coordinate's
//! variance, excess kurtosis and fractions beyond 3 and 4: how Gaussian the family the prior stands for is.

use anyhow::{Context, Result, bail};
use dynforge_dataset::evidence::{label_gradient, label_posterior};
use dynforge_identify::{ParameterPrior, Posterior};
use dynforge_proto::{LABELS, NUM_LABELS};
use dynforge_trainer::inference::Predictor;
use nalgebra::DVector;

/// One label of one robot: the plug-in's error, the linear pull, the posterior's spread and the pull's spread.
struct Pull {
    error: f64,
    linear: f64,
    posterior: f64,
    spread: f64,
}

/// Each label's [`Pull`] for the truth at coordinates `z` (`pull`: `P^-1 z`).
fn pulls(prior: &ParameterPrior, post: &Posterior, pull: &DVector<f64>, truth: &[f64; NUM_LABELS]) -> Vec<Pull> {
    let (plug, posterior) = label_posterior(prior, post);
    let grad = label_gradient(prior, &post.mean);
    let cov = post.covariance();
    (0..NUM_LABELS)
        .map(|k| {
            let g = DVector::from_iterator(grad.len(), grad.iter().map(|row| row[k]));
            Pull {
                error: plug[k] - truth[k],
                linear: -g.dot(pull),
                posterior: posterior[k],
                spread: (&cov * &g).norm(),
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
    let (ckpt, data) = match positional.as_slice() {
        [ckpt] if draws.is_some() => (ckpt, None),
        [ckpt, data] => (ckpt, Some(data)),
        _ => bail!("usage: dynforge-bench-prior-pull CHECKPOINT DATA [--robot ID] | CHECKPOINT --tails N"),
    };
    let predictor = Predictor::load(std::path::Path::new(ckpt))?;
    let prior = predictor.checkpoint.parameter_prior().context("not a physics checkpoint: it has no prior")?;
    let (Some(data), None) = (data, draws) else { return tails(&prior, draws.unwrap_or_default()) };
    let r = prior.rank();
    let by_robot = dynforge_recording::dataset::shards_by_robot(std::path::Path::new(data))
        .with_context(|| format!("listing the recordings of {data}"))?;
    println!(
        "robot\tmean z^2\tlargest z\tposterior mean off z - P^-1 z\tworst label\tplug-in error / posterior\tlinear pull"
    );
    for (id, paths) in by_robot {
        if robot.is_some_and(|r| r != id) {
            continue;
        }
        let path = paths.first().with_context(|| format!("robot {id}: no recordings"))?;
        let rec = dynforge_recording::read(path, None)?;
        let truth = rec.labels.with_context(|| format!("{}: no labels", path.display()))?;
        let z = DVector::from_vec(prior.coordinates(&dynforge_robot::parameters::dynamic_parameters(&rec.model)));
        let (e, _, _) = predictor.windows(&rec)?.1.context("no evidence: not a physics checkpoint")?;
        let post = e.posterior()?;
        let pull = post.covariance() * &z;
        let off = (0..r).map(|i| (z[i] - pull[i] - post.mean[i]).abs() / post.variance[i].sqrt()).fold(0.0, f64::max);
        let p = pulls(&prior, &post, &pull, &truth);
        let worst = (0..NUM_LABELS)
            .max_by(|&a, &b| (p[a].error / p[a].posterior).abs().total_cmp(&(p[b].error / p[b].posterior).abs()))
            .unwrap_or(0);
        let w = &p[worst];
        println!(
            "{id}\t{:.2}\t{:.2}\t{off:.3}\t{}\t{:.2}\t{:.2}",
            z.norm_squared() / r as f64,
            z.amax(),
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
