//! Scoring a model the way the paper reports it — R2 and RMSE per target (`metrics`) laid out as its three tables
//! (`report`) — and past it: scores of per-robot estimates (all of a robot's windows averaged, as a user with
//! several logs of one robot would) and the torque check (`torque`).

pub mod metrics;
pub mod plots;
pub mod report;
pub mod torque;

use std::collections::BTreeMap;
use std::path::Path;

use burn::tensor::Device;
use dynforge_proto::NUM_LABELS;
use dynforge_robot::parameters::with_labels;
use serde::{Deserialize, Serialize};

use crate::checkpoint::Checkpoint;
use crate::data::cache::CachedWindows;
use crate::data::dataset::{GRID_DT, prepare};
use crate::data::follow::{list_shards, shard_dir};
use crate::data::split::{Split, split_of};
use crate::inference::{InferenceError, Predictor};
use crate::training::evaluate;
use metrics::{Scores, score};
use torque::TorqueResidual;

/// Torque NRMSE of three parameter sets on the validation recordings.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TorqueCheck {
    pub recordings: usize,
    /// Per joint, then overall, for: the network's estimate, the true parameters, the training-mean parameters.
    pub estimated: Vec<f64>,
    pub truth: Vec<f64>,
    pub mean: Vec<f64>,
    pub estimated_overall: f64,
    pub truth_overall: f64,
    pub mean_overall: f64,
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
            let joints = t.estimated.len();
            out.push_str(&format!(
                "| parameters |{} overall |\n|---|{}---:|\n",
                (0..joints).map(|j| format!(" J{j} |")).collect::<String>(),
                "---:|".repeat(joints)
            ));
            for (name, v, o) in [
                ("estimated", &t.estimated, t.estimated_overall),
                ("true", &t.truth, t.truth_overall),
                ("training mean", &t.mean, t.mean_overall),
            ] {
                out.push_str(&format!(
                    "| {name} |{} {o:.4} |\n",
                    v.iter().map(|x| format!(" {x:.4} |")).collect::<String>()
                ));
            }
            if t.projections > 0 {
                out.push_str(&format!("\n{} estimated values were projected to physical ones.\n", t.projections));
            }
        }
        out
    }
}

/// Averages predictions per robot.
fn per_robot(
    robots: &[u64],
    predicted: &[[f64; NUM_LABELS]],
    truth: &[[f64; NUM_LABELS]],
) -> (Vec<[f64; NUM_LABELS]>, Vec<[f64; NUM_LABELS]>) {
    let mut acc: BTreeMap<u64, ([f64; NUM_LABELS], usize, [f64; NUM_LABELS])> = BTreeMap::new();
    for ((r, p), t) in robots.iter().zip(predicted).zip(truth) {
        let e = acc.entry(*r).or_insert(([0.0; NUM_LABELS], 0, *t));
        for k in 0..NUM_LABELS {
            e.0[k] += p[k];
        }
        e.1 += 1;
    }
    acc.values().map(|(s, n, t)| (std::array::from_fn(|k| s[k] / *n as f64), *t)).unzip()
}

/// Evaluates the checkpoint in `dir` on the validation robots of `windows` (the windows of its dataset) and, for
/// up to `torque_recordings` validation shards of `data`, runs the torque check.
pub fn evaluate_checkpoint(
    dir: &Path,
    windows: &CachedWindows,
    data: &Path,
    torque_recordings: usize,
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
    let (rp, rt) = per_robot(&robots, &predicted, &truth);
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
            let Ok(prep) = prepare(&p, None) else { continue };
            if prep.robot.is_some_and(|r| split_of(c.split_seed, r, c.validation_fraction) == Split::Validation) {
                chosen.push(prep);
            }
        }
        let (mut est, mut tru, mut mean) =
            (TorqueResidual::default(), TorqueResidual::default(), TorqueResidual::default());
        let mut projections = 0;
        let mean_labels: [f64; NUM_LABELS] = standardizer.label_mean;
        for (k, prep) in chosen.iter().enumerate() {
            progress("torque check", k, chosen.len());
            let e = predictor.estimate_prepared(dir, prep)?;
            let bad = |e: dynforge_robot::ModelError| InferenceError::Recording {
                file: prep.path.display().to_string(),
                problem: e.to_string(),
            };
            let (m_est, notes) = with_labels(&prep.model, &e.labels).map_err(bad)?;
            let (m_mean, _) = with_labels(&prep.model, &mean_labels).map_err(bad)?;
            projections += notes.len();
            est.add(&m_est, &prep.trajectory, GRID_DT);
            tru.add(&prep.model, &prep.trajectory, GRID_DT);
            mean.add(&m_mean, &prep.trajectory, GRID_DT);
        }
        progress("torque check", chosen.len(), chosen.len());
        (!chosen.is_empty()).then(|| TorqueCheck {
            recordings: chosen.len(),
            estimated: est.per_joint(),
            truth: tru.per_joint(),
            mean: mean.per_joint(),
            estimated_overall: est.overall(),
            truth_overall: tru.overall(),
            mean_overall: mean.overall(),
            projections,
        })
    } else {
        None
    };
    Ok(Report { checkpoint: dir.display().to_string(), epoch: c.epoch, windows: scores, robots: robot_scores, torque })
}
