//! Scoring a model the way the paper reports it — R2 and RMSE per target (`metrics`) laid out as its three tables
//! (`report`) — and past it: scores of per-robot estimates (all of a robot's windows averaged, as a user with
//! several logs of one robot would), the torque check (`torque`), and physics beside the network
//! (`identification`).

pub mod identification;
pub mod metrics;
pub mod plots;
pub mod report;
pub mod torque;

use std::collections::BTreeMap;
use std::path::Path;

use burn::tensor::Device;
use dynforge_identify::TorqueError;
use dynforge_proto::NUM_LABELS;
use dynforge_robot::parameters::dynamic_parameters;
use serde::{Deserialize, Serialize};

use crate::checkpoint::Checkpoint;
use crate::data::cache::CachedWindows;
use dynforge_recording::dataset::{list_shards, shard_dir};
use dynforge_recording::read;
use crate::data::split::{Split, split_of};
use crate::inference::{InferenceError, Predictor};
use crate::training::evaluate;
use identification::IdentificationCheck;
use metrics::{Scores, score};
use torque::{TorqueRow, normal_equations, physical_parameters};

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
        out.push_str(&report::tables(&self.windows));
        let groups: Vec<String> = report::group_r2(&self.windows).iter().map(|(g, r)| format!("{g} {r:.4}")).collect();
        out.push_str(&format!("\nMean R2 per group: {}\n", groups.join(", ")));
        out.push_str(&format!(
            "\nPer robot ({} robots, each the mean of its windows): R2 = {:.4}, RMSE = {:.4}\n",
            self.robots.count, self.robots.r2, self.robots.rmse
        ));
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

/// Averages predictions per robot: robot ids, predictions, truths (in robot order).
fn per_robot(
    robots: &[u64],
    predicted: &[[f64; NUM_LABELS]],
    truth: &[[f64; NUM_LABELS]],
) -> (Vec<u64>, Vec<[f64; NUM_LABELS]>, Vec<[f64; NUM_LABELS]>) {
    let mut acc: BTreeMap<u64, ([f64; NUM_LABELS], usize, [f64; NUM_LABELS])> = BTreeMap::new();
    for ((r, p), t) in robots.iter().zip(predicted).zip(truth) {
        let e = acc.entry(*r).or_insert(([0.0; NUM_LABELS], 0, *t));
        for k in 0..NUM_LABELS {
            e.0[k] += p[k];
        }
        e.1 += 1;
    }
    let ids = acc.keys().copied().collect();
    let (p, t) = acc.values().map(|(s, n, t)| (std::array::from_fn(|k| s[k] / *n as f64), *t)).unzip();
    (ids, p, t)
}

/// Mean and standard deviation of the labels over the training robots of `windows` (one sample per robot: the
/// distribution the generator drew them from).
fn training_distribution(windows: &CachedWindows, c: &Checkpoint) -> ([f64; NUM_LABELS], [f64; NUM_LABELS]) {
    let robots: BTreeMap<u64, [f64; NUM_LABELS]> = (0..windows.count())
        .filter(|&i| split_of(c.split_seed, windows.robots[i], c.validation_fraction) == Split::Train)
        .map(|i| (windows.robots[i], windows.labels[i]))
        .collect();
    let n = robots.len().max(1) as f64;
    let mean: [f64; NUM_LABELS] = std::array::from_fn(|k| robots.values().map(|y| y[k]).sum::<f64>() / n);
    let std = std::array::from_fn(|k| (robots.values().map(|y| (y[k] - mean[k]).powi(2)).sum::<f64>() / n).sqrt());
    (mean, std)
}

/// Evaluates the checkpoint in `dir` on the validation robots of `windows` (the windows of its dataset) and, for
/// up to `torque_recordings` validation shards of `data`, runs the torque check, and for up to
/// `identify_robots` validation robots the identification check.
pub fn evaluate_checkpoint(
    dir: &Path,
    windows: &CachedWindows,
    data: &Path,
    torque_recordings: usize,
    identify_robots: usize,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<Report, InferenceError> {
    let predictor = Predictor::load(dir)?;
    let c: &Checkpoint = &predictor.checkpoint;
    let standardizer = c.standardizer();
    let validation: Vec<usize> = (0..windows.count())
        .filter(|&i| split_of(c.split_seed, windows.robots[i], c.validation_fraction) == Split::Validation)
        .collect();
    progress("windows", 0, 1);
    let (scores, predicted, _) = evaluate(predictor.model(), windows, &standardizer, &validation, &Device::default());
    progress("windows", 1, 1);
    let truth: Vec<[f64; NUM_LABELS]> = validation.iter().map(|&i| windows.labels[i]).collect();
    let robots: Vec<u64> = validation.iter().map(|&i| windows.robots[i]).collect();
    let (ids, rp, rt) = per_robot(&robots, &predicted, &truth);
    let robot_scores = score(&rp, &rt, &standardizer.label_std);
    let plot_error = |e: String| InferenceError::Recording { file: dir.display().to_string(), problem: e };
    plots::predicted_vs_true(
        &dir.join("predicted_vs_true.png"),
        &predicted,
        &truth,
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
            let e = predictor.estimate_prepared(dir, prep)?;
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
        let errors: BTreeMap<u64, [f64; NUM_LABELS]> =
            ids.iter().zip(rp.iter().zip(&rt)).map(|(&r, (p, t))| (r, std::array::from_fn(|k| p[k] - t[k]))).collect();
        let (mean, std) = training_distribution(windows, c);
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
