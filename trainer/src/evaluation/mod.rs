//! Scoring a model the way the paper reports it — R2 and RMSE per target (`metrics`) laid out as its three tables
//! (`report`) — and past it: scores of per-robot estimates (all of a robot's windows averaged, as a user with
//! several logs of one robot would), the torque check (`torque`), and physics beside the network
//! (`identification`).

pub mod identification;
pub mod plots;
pub mod report;
pub mod torque;

use std::collections::BTreeMap;
use std::path::Path;

use dynforge_identify::TorqueError;
use dynforge_proto::NUM_LABELS;
use dynforge_recording::dataset::{dataset_robot, list_shards, shard_dir};
use dynforge_recording::read;
use dynforge_robot::parameters::dynamic_parameters;
use serde::{Deserialize, Serialize};

use crate::checkpoint::Checkpoint;
use crate::data::cache::load_or_build;
use crate::data::features::JacobianFeatures;
use crate::data::physics::{self, PhysicsSet};
use crate::data::split::{Split, split_of};
use crate::inference::{InferenceError, Predictor, normal_equations, physical_parameters};
use crate::metrics::{Scores, score};
use crate::training::Examples;
use crate::training::physics::per_robot;
use crate::training::session::Inputs;
use identification::IdentificationCheck;
use torque::TorqueRow;

/// Torque NRMSE on the validation recordings of: the network's estimate (from the recording itself), the true
/// parameters, the training-mean parameters.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TorqueCheck {
    pub recordings: usize,
    pub rows: Vec<TorqueRow>,
    /// Projections applied to make estimates physical, summed over recordings.
    pub projections: usize,
}

/// Everything `evaluate` reports.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Report {
    pub checkpoint: String,
    pub epoch: usize,
    /// Per validation window (the paper's protocol).
    pub windows: Scores,
    /// Per validation robot, its windows' predictions averaged.
    pub robots: Scores,
    pub torque: Option<TorqueCheck>,
    pub identification: Option<IdentificationCheck>,
}

impl Report {
    pub fn markdown(&self) -> String {
        let mut out = format!(
            "# Validation of {} (epoch {})\n\nPer window (the paper's protocol; RMSE in standardised units):\n\n",
            self.checkpoint, self.epoch
        );
        out.push_str(&report::tables(&self.windows, "Overall"));
        let groups: Vec<String> = report::group_r2(&self.windows).iter().map(|(g, r)| format!("{g} {r:.4}")).collect();
        out.push_str(&format!("\nMean R2 per group: {}\n", groups.join(", ")));
        out.push_str(&format!(
            "\nPer robot ({} validation robots, each estimated from all its recordings: the transformer averages their \
             windows, the physics estimator sums their evidence):\n\n",
            self.robots.count
        ));
        out.push_str(&report::tables(&self.robots, "Overall per robot"));
        let groups: Vec<String> = report::group_r2(&self.robots).iter().map(|(g, r)| format!("{g} {r:.4}")).collect();
        out.push_str(&format!("\nMean R2 per group: {}\n", groups.join(", ")));
        if let Some(t) = &self.torque {
            out.push_str(&format!(
                "\n**Torque check** ({} validation recordings; inverse dynamics vs recorded torque, NRMSE per joint)\n\n",
                t.recordings
            ));
            out.push_str(&torque::table(&t.rows));
            if t.projections > 0 {
                out.push_str(&format!("\n{} estimated values were projected to physical ones.\n", t.projections));
            }
        }
        if let Some(i) = &self.identification {
            out.push_str(&i.markdown());
        }
        out
    }
}

/// Writes `report.md` and `report.json` into the checkpoint directory `dir`, atomically: `report.json` also feeds
/// `estimate` (the refinement's prior spread), so it is never half written.
pub fn write(dir: &Path, report: &Report) -> std::io::Result<()> {
    dynforge_proto::run_dir::write_atomic(&dir.join("report.md"), report.markdown().as_bytes())?;
    let json = serde_json::to_string_pretty(report).map_err(std::io::Error::other)?;
    dynforge_proto::run_dir::write_atomic(&dir.join("report.json"), json.as_bytes())
}

/// Averages predictions per robot: robot ids, predictions, truths (in robot order).
fn per_robot_mean(
    robots: &[u64],
    predicted: &[[f64; NUM_LABELS]],
    truth: &[[f64; NUM_LABELS]],
) -> (Vec<u64>, Vec<[f64; NUM_LABELS]>, Vec<[f64; NUM_LABELS]>) {
    let mut acc: BTreeMap<u64, ([f64; NUM_LABELS], usize, [f64; NUM_LABELS])> = BTreeMap::new();
    for ((r, p), t) in robots.iter().zip(predicted).zip(truth) {
        let e = acc.entry(*r).or_insert(([0.0; NUM_LABELS], 0, *t));
        for (s, v) in e.0.iter_mut().zip(p) {
            *s += v;
        }
        e.1 += 1;
    }
    let ids = acc.keys().copied().collect();
    let (p, t) = acc.values().map(|(s, n, t)| (std::array::from_fn(|k| s[k] / *n as f64), *t)).unzip();
    (ids, p, t)
}

/// Mean and standard deviation of the labels over the training robots (one sample per robot: the distribution the
/// generator drew them from).
fn training_distribution(
    robots: &[u64],
    labels: &[[f64; NUM_LABELS]],
    c: &Checkpoint,
) -> ([f64; NUM_LABELS], [f64; NUM_LABELS]) {
    let robots: BTreeMap<u64, [f64; NUM_LABELS]> = robots
        .iter()
        .zip(labels)
        .filter(|(r, _)| split_of(c.split_seed, **r, c.validation_fraction) == Split::Train)
        .map(|(r, y)| (*r, *y))
        .collect();
    let n = robots.len().max(1) as f64;
    let mean: [f64; NUM_LABELS] = std::array::from_fn(|k| robots.values().map(|y| y[k]).sum::<f64>() / n);
    let std = std::array::from_fn(|k| (robots.values().map(|y| (y[k] - mean[k]).powi(2)).sum::<f64>() / n).sqrt());
    (mean, std)
}

/// Predictions on the validation split, both protocols.
struct Validation {
    /// Per window: labels of every window of the training robots too (for the training distribution), and the
    /// validation windows' predictions and truths.
    robots: Vec<u64>,
    labels: Vec<[f64; NUM_LABELS]>,
    window_robots: Vec<u64>,
    window_predicted: Vec<[f64; NUM_LABELS]>,
    window_truth: Vec<[f64; NUM_LABELS]>,
    /// Per robot: ids, predictions (the transformer's windows averaged; the physics estimator's from all the
    /// robot's recordings' evidence), truths.
    robot_ids: Vec<u64>,
    robot_predicted: Vec<[f64; NUM_LABELS]>,
    robot_truth: Vec<[f64; NUM_LABELS]>,
}

fn validate(
    predictor: &Predictor,
    data: &Path,
    inputs: Option<Inputs>,
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<Validation, InferenceError> {
    let c = &predictor.checkpoint;
    let spec = c.window_spec();
    let validation = |r: u64| split_of(c.split_seed, r, c.validation_fraction) == Split::Validation;
    let inputs = match inputs {
        Some(i) => i,
        None => match c.parameter_prior() {
            Some(prior) => Inputs::Physics(
                physics::load_or_build(data, &spec, &prior, |k, n| {
                    progress("physics", k, n);
                    true
                })
                .map_err(|e| InferenceError::Recording { file: data.display().to_string(), problem: e.to_string() })?
                .0,
            ),
            None => {
                let features = JacobianFeatures::new(&dataset_robot(data)?);
                Inputs::Windows(
                    load_or_build(data, &spec, &features, |k, n| {
                        progress("windows", k, n);
                        true
                    })?
                    .0,
                )
            }
        },
    };
    progress("validation", 0, 1);
    let v = match inputs {
        Inputs::Windows(w) => {
            let s = c.standardizer();
            let ids: Vec<usize> = (0..w.count()).filter(|&i| validation(w.robots[i])).collect();
            let corpus = crate::training::Corpus { windows: w, train: Vec::new(), validation: ids, standardizer: s };
            let (x, truth) = corpus.validation();
            let predicted: Vec<[f64; NUM_LABELS]> = {
                let pred = crate::training::predict(
                    predictor.model(),
                    &x,
                    truth.len(),
                    corpus.shape(),
                    &burn::tensor::Device::default(),
                );
                pred.iter().map(|p| corpus.standardizer.labels(p)).collect()
            };
            let window_robots: Vec<u64> = corpus.validation.iter().map(|&i| corpus.windows.robots[i]).collect();
            let (robot_ids, robot_predicted, robot_truth) = per_robot_mean(&window_robots, &predicted, &truth);
            Validation {
                robots: corpus.windows.robots.clone(),
                labels: corpus.windows.labels.clone(),
                window_robots,
                window_predicted: predicted,
                window_truth: truth,
                robot_ids,
                robot_predicted,
                robot_truth,
            }
        }
        Inputs::Physics(set) => validate_physics(predictor, &set, validation)?,
    };
    progress("validation", 1, 1);
    Ok(v)
}

fn validate_physics(
    predictor: &Predictor,
    set: &PhysicsSet,
    validation: impl Fn(u64) -> bool,
) -> Result<Validation, InferenceError> {
    let w = &set.windows;
    let ids: Vec<usize> = (0..w.len()).filter(|&i| validation(w.robots[i])).collect();
    let window_predicted = predictor.predict_evidence(&ids.iter().map(|&i| w.get(i)).collect::<Vec<_>>())?;
    let robots = per_robot(&set.recordings, &validation);
    let robot_predicted = predictor.predict_evidence(&robots.iter().map(|(_, _, e)| e.clone()).collect::<Vec<_>>())?;
    Ok(Validation {
        robots: w.robots.clone(),
        labels: w.labels.clone(),
        window_robots: ids.iter().map(|&i| w.robots[i]).collect(),
        window_predicted,
        window_truth: ids.iter().map(|&i| w.labels[i]).collect(),
        robot_ids: robots.iter().map(|(r, _, _)| *r).collect(),
        robot_predicted,
        robot_truth: robots.iter().map(|(_, y, _)| *y).collect(),
    })
}

/// Evaluates the checkpoint in `dir` on the validation robots of its dataset `data` (its windows or physics in
/// `inputs` when the caller has them) and, for up to `torque_recordings` validation shards, runs the torque check,
/// and for up to `identify_robots` validation robots the identification check.
pub fn evaluate_checkpoint(
    dir: &Path,
    data: &Path,
    inputs: Option<Inputs>,
    torque_recordings: usize,
    identify_robots: usize,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<Report, InferenceError> {
    let predictor = Predictor::load(dir)?;
    let c: &Checkpoint = &predictor.checkpoint;
    let standardizer = c.standardizer();
    let v = validate(&predictor, data, inputs, &mut progress)?;
    let scores = score(&v.window_predicted, &v.window_truth, &standardizer.label_std);
    let robot_scores = score(&v.robot_predicted, &v.robot_truth, &standardizer.label_std);
    let (predicted, truth, ids, rp, rt) =
        (&v.window_predicted, &v.window_truth, &v.robot_ids, &v.robot_predicted, &v.robot_truth);
    let _ = &v.window_robots;
    let plot_error = |e: String| InferenceError::Recording { file: dir.display().to_string(), problem: e };
    plots::predicted_vs_true(
        &dir.join("predicted_vs_true.png"),
        predicted,
        truth,
        &standardizer.label_mean,
        &standardizer.label_std,
    )
    .map_err(plot_error)?;
    let history: Option<Vec<crate::training::EpochMetrics>> =
        std::fs::read(dir.join("metrics.json")).ok().and_then(|b| serde_json::from_slice(&b).ok());
    if let Some(h) = history.filter(|h| !h.is_empty()) {
        plots::learning_curves(&dir.join("learning_curves.png"), &h).map_err(plot_error)?;
    }

    let torque = if torque_recordings > 0 {
        let shards = list_shards(&shard_dir(data)).unwrap_or_default();
        let mut chosen = Vec::new();
        // Shard names carry the robot: skip training robots' shards without reading them.
        let named_robot = |p: &std::path::Path| {
            p.file_name().and_then(|n| n.to_str()).and_then(dynforge_proto::shard::robot_of_file_name)
        };
        for p in shards {
            if chosen.len() >= torque_recordings {
                break;
            }
            if named_robot(&p).is_some_and(|r| split_of(c.split_seed, r, c.validation_fraction) != Split::Validation) {
                continue;
            }
            let Ok(prep) = read(&p, None) else { continue };
            if prep.robot.is_some_and(|r| split_of(c.split_seed, r, c.validation_fraction) == Split::Validation) {
                chosen.push(prep);
            }
        }
        let (mut est, mut tru, mut mean) = (TorqueError::default(), TorqueError::default(), TorqueError::default());
        let mut projections = 0;
        for (k, prep) in chosen.iter().enumerate() {
            progress("torque check", k, chosen.len());
            let e = predictor.estimate(dir, &[prep])?;
            let ne = normal_equations(prep)?;
            let (pi_est, notes) = physical_parameters(prep, &prep.model, &e.labels)?;
            projections += notes;
            est.add(&ne, &pi_est);
            tru.add(&ne, &dynamic_parameters(&prep.model));
            mean.add(&ne, &physical_parameters(prep, &prep.model, &standardizer.label_mean)?.0);
        }
        progress("torque check", chosen.len(), chosen.len());
        (!chosen.is_empty()).then(|| TorqueCheck {
            recordings: chosen.len(),
            rows: vec![
                TorqueRow::new("estimated", &est),
                TorqueRow::new("true", &tru),
                TorqueRow::new("training mean", &mean),
            ],
            projections,
        })
    } else {
        None
    };
    let identification = if identify_robots > 0 {
        let errors: BTreeMap<u64, [f64; NUM_LABELS]> = ids
            .iter()
            .zip(rp.iter().zip(rt.iter()))
            .map(|(&r, (p, t))| (r, std::array::from_fn(|k| p[k] - t[k])))
            .collect();
        let (mean, std) = training_distribution(&v.robots, &v.labels, c);
        let training = dynforge_identify::Prior::new(mean, &std).map_err(|e| InferenceError::Recording {
            file: data.display().to_string(),
            problem: format!("the training robots' labels: {e}"),
        })?;
        identification::check(&predictor, dir, data, identify_robots, &training, &errors, &mut progress)?
    } else {
        None
    };
    Ok(Report {
        checkpoint: dir.display().to_string(),
        epoch: c.epoch,
        windows: scores,
        robots: robot_scores,
        torque,
        identification,
    })
}
