//! Scoring an estimator the way the paper reports it (R2 and RMSE per label, `dynforge_dataset::metrics`, laid out as its three
//! tables, [`tables`]) and past it: scores of per-robot estimates (a robot's windows averaged, or its recordings'
//! evidence summed, as a user with several logs of one robot would), the torque check ([`torque`]), and physics
//! beside the network ([`identification`]). Everything here works through [`Estimator`], so evaluation needs no ML
//! framework; `dynforge_trainer::evaluation` makes the predictions and calls [`report`].

pub mod identification;
pub mod recording;
pub mod spread;
pub mod sweep;
pub mod tables;
pub mod torque;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dynforge_identify::{Prior, TorqueError};
use dynforge_proto::NUM_LABELS;
use dynforge_recording::dataset::{list_shards, shard_dir};
use dynforge_recording::{Recording, read};
use dynforge_robot::parameters::dynamic_parameters;
use serde::{Deserialize, Serialize};

use dynforge_dataset::metrics::{Scores, score};
use dynforge_dataset::split::{HoldOut, SplitRule};
use dynforge_dataset::window::WindowSpec;
use identification::IdentificationCheck;
use recording::{RecordingError, normal_equations, physical_parameters};
use spread::ValidationSpreads;
use torque::TorqueRow;

/// An estimate of one robot, with what its evidence says of its spread.
#[derive(Debug, Clone)]
pub struct Estimated {
    pub labels: Labels,
    /// The standard deviation per label [SI] the evidence implies (`None`: the estimator reads no evidence).
    pub posterior: Option<Labels>,
    /// The noise that posterior assumed: the floor on every joint (a simulated log), or the log's measured noise.
    pub noise: spread::Noise,
    /// How far each label [SI] of the posterior lies from the estimate (the spread whose intervals about it hold the
    /// posterior's central 68 and 95 %); at the noise floor, of the posterior the logs' own residual supports.
    /// `None`: as `posterior`.
    pub deviation: Option<Labels>,
}

impl Estimated {
    /// The evidence's spread of label `k` about the estimate, as the calibration reads it: its deviation where the
    /// estimator gives one, else its posterior's standard deviation (0 without either).
    pub fn deviation(&self, k: usize) -> f64 {
        self.deviation.or(self.posterior).map_or(0.0, |p| p[k])
    }
}

/// An estimator's own failure, as it reports it.
pub type EstimatorError = Box<dyn std::error::Error + Send + Sync>;

/// What the checks need of an estimator.
pub trait Estimator: Sync {
    /// The split it was trained with.
    fn split(&self) -> SplitRule;
    /// Its window geometry: a recording shorter than one window cannot be estimated.
    fn window_spec(&self) -> WindowSpec;
    /// Mean and standard deviation of the labels it was trained with [SI].
    fn label_statistics(&self) -> ([f64; NUM_LABELS], [f64; NUM_LABELS]);
    /// Its labels [SI] for one robot, from that robot's recordings.
    fn estimate(&self, recordings: &[&Recording]) -> Result<[f64; NUM_LABELS], EstimatorError>;

    /// [`Estimator::estimate`] with the standard deviation per label [SI] its evidence implies for this robot, when
    /// it reads one (the physics estimator: the posterior of the prior coordinates), before what the network adds.
    fn estimate_with_spread(&self, recordings: &[&Recording]) -> Result<Estimated, EstimatorError> {
        Ok(Estimated {
            labels: self.estimate(recordings)?,
            posterior: None,
            noise: spread::Noise::Floor,
            deviation: None,
        })
    }

    /// Whether `robot` was held out of its training whole (never under a split by trajectory or window).
    fn holds_out_robot(&self, robot: u64) -> bool {
        self.split().holds_out_robot(robot)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum EvaluationError {
    #[error(transparent)]
    Estimator(EstimatorError),
    #[error(transparent)]
    Recording(#[from] RecordingError),
    #[error("{dataset}: the training robots' labels: {source}")]
    TrainingLabels { dataset: String, source: dynforge_identify::IdentifyError },
}

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
    /// What was held out for validation, and the split in words; reports before splits were chosen held out robots.
    #[serde(default)]
    pub held_out: HoldOut,
    #[serde(default)]
    pub split: String,
    /// Per validation window (the paper's protocol).
    pub windows: Scores,
    /// Per validation robot, its windows' predictions averaged.
    pub robots: Scores,
    /// Per validation recording (one log of a robot), and the mean number of recordings per validation robot:
    /// the error of an estimate from one log and from all of a robot's, which `estimate` takes as its prior spread
    /// (the physics estimator; `None` for the transformer).
    #[serde(default)]
    pub recordings: Option<Scores>,
    #[serde(default)]
    pub logs_per_robot: f64,
    pub torque: Option<TorqueCheck>,
    pub identification: Option<IdentificationCheck>,
    /// How the spreads `estimate` prints are calibrated to hold (`None` when not measured: too few validation robots,
    /// or not asked for).
    #[serde(default)]
    pub spread_calibration: Option<ValidationSpreads>,
}

impl Report {
    pub fn markdown(&self) -> String {
        let mut out = format!(
            "# Validation of {} (epoch {})\n\nSplit: {}.\n\nPer window (the paper's protocol; RMSE in standardised \
             units):\n\n",
            self.checkpoint, self.epoch, self.split
        );
        out.push_str(&tables::tables(&self.windows, "Overall"));
        let groups: Vec<String> = tables::group_r2(&self.windows).iter().map(|(g, r)| format!("{g} {r:.4}")).collect();
        out.push_str(&format!("\nMean R2 per group: {}\n", groups.join(", ")));
        out.push_str(&format!(
            "\nPer robot ({} validation robots, each estimated from all its recordings: the transformer averages their \
             windows, the physics estimator sums their evidence):\n\n",
            self.robots.count
        ));
        out.push_str(&tables::tables(&self.robots, "Overall per robot"));
        let groups: Vec<String> = tables::group_r2(&self.robots).iter().map(|(g, r)| format!("{g} {r:.4}")).collect();
        out.push_str(&format!("\nMean R2 per group: {}\n", groups.join(", ")));
        if let Some(r) = &self.recordings {
            out.push_str(&format!(
                "\nPer recording (each validation log alone, {} logs): R2 {:.4}, RMSE {:.4}\n",
                r.count, r.r2, r.rmse
            ));
        }
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
        if let Some(s) = &self.spread_calibration {
            out.push_str(&s.markdown());
        }
        if self.held_out != HoldOut::Robots {
            out.push_str(
                "\nThe torque and identification checks run on robots never seen in training: none under this split.\n",
            );
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

/// Predictions on the validation split, both protocols.
pub struct Validation {
    /// Per window: labels of every window of the training robots too (for the training distribution), and the
    /// validation windows' predictions and truths.
    pub robots: Vec<u64>,
    pub labels: Vec<[f64; NUM_LABELS]>,
    pub window_predicted: Vec<[f64; NUM_LABELS]>,
    pub window_truth: Vec<[f64; NUM_LABELS]>,
    /// Per robot: ids, predictions (the transformer's windows averaged; the physics estimator's from all the
    /// robot's recordings' evidence), truths.
    pub robot_ids: Vec<u64>,
    pub robot_predicted: Vec<[f64; NUM_LABELS]>,
    pub robot_truth: Vec<[f64; NUM_LABELS]>,
    /// Per recording (one log each), when the estimator reads recordings whole: predictions and truths.
    pub recordings: Option<(Vec<Labels>, Vec<Labels>)>,
}

type Labels = [f64; NUM_LABELS];

/// How much of the validation split each check beyond the scores takes (0: skip the check).
#[derive(Debug, Clone)]
pub struct Checks {
    /// Validation shards whose torques the estimate predicts.
    pub torque_recordings: usize,
    /// Validation robots identified by physics from half their recordings.
    pub identify_robots: usize,
    /// Robots estimated and refined from 1, 2, 4, ... of their logs, to calibrate the spreads.
    pub spread_robots: usize,
    /// Where those robots come from: every robot of this dataset (drawn fresh from the training data's generator,
    /// so that none was trained on), else the validation robots.
    pub spread_data: Option<PathBuf>,
}

impl Checks {
    /// The scores alone.
    pub const NONE: Checks = Checks { torque_recordings: 0, identify_robots: 0, spread_robots: 0, spread_data: None };
}

/// The report of `estimator` (its checkpoint `name` at `epoch`) from its predictions on the validation split
/// `v` of the dataset `data`: the scores of both protocols and the `checks`.
pub fn report(
    estimator: &impl Estimator,
    (name, epoch): (&str, usize),
    v: &Validation,
    data: &Path,
    checks: Checks,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<Report, EvaluationError> {
    let (_, label_std) = estimator.label_statistics();
    let windows = score(&v.window_predicted, &v.window_truth, &label_std);
    let robots = score(&v.robot_predicted, &v.robot_truth, &label_std);
    let torque = match checks.torque_recordings {
        0 => None,
        n => torque_check(estimator, data, n, &mut progress)?,
    };
    let identification = match checks.identify_robots {
        0 => None,
        n => {
            let errors: BTreeMap<u64, [f64; NUM_LABELS]> = v
                .robot_ids
                .iter()
                .zip(v.robot_predicted.iter().zip(&v.robot_truth))
                .map(|(&r, (p, t))| (r, std::array::from_fn(|k| p[k] - t[k])))
                .collect();
            let (mean, std) = training_distribution(&v.robots, &v.labels, estimator);
            let training = Prior::new(mean, &std)
                .map_err(|source| EvaluationError::TrainingLabels { dataset: data.display().to_string(), source })?;
            identification::check(estimator, data, n, &training, &errors, &mut progress)?
        }
    };
    let recordings = v.recordings.as_ref().map(|(p, t)| score(p, t, &label_std));
    let logs_per_robot = v.recordings.as_ref().map_or(0.0, |(p, _)| p.len() as f64 / v.robot_ids.len().max(1) as f64);
    let spread_calibration = match (checks.spread_robots, &checks.spread_data) {
        (0, _) => None,
        (n, Some(fresh)) => spread::fit(estimator, spread::Robots::Fresh(fresh), n, &mut progress)?,
        (n, None) => spread::fit(estimator, spread::Robots::Validation(data), n, &mut progress)?,
    };
    Ok(Report {
        checkpoint: name.to_string(),
        epoch,
        held_out: estimator.split().by,
        split: estimator.split().to_string(),
        windows,
        robots,
        recordings,
        logs_per_robot,
        torque,
        identification,
        spread_calibration,
    })
}

/// Averages predictions per robot: robot ids, predictions, truths (in robot order).
pub fn per_robot_mean(
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
    estimator: &impl Estimator,
) -> ([f64; NUM_LABELS], [f64; NUM_LABELS]) {
    let robots: BTreeMap<u64, [f64; NUM_LABELS]> =
        robots.iter().zip(labels).filter(|(r, _)| !estimator.holds_out_robot(**r)).map(|(r, y)| (*r, *y)).collect();
    let n = robots.len().max(1) as f64;
    let mean: [f64; NUM_LABELS] = std::array::from_fn(|k| robots.values().map(|y| y[k]).sum::<f64>() / n);
    let std = std::array::from_fn(|k| (robots.values().map(|y| (y[k] - mean[k]).powi(2)).sum::<f64>() / n).sqrt());
    (mean, std)
}

/// Up to `max` readable validation shards of `data`, in name order.
fn validation_recordings(estimator: &impl Estimator, data: &Path, max: usize) -> Vec<Recording> {
    let validation = |r: u64| estimator.holds_out_robot(r);
    // Shard names carry the robot: skip training robots' shards without reading them.
    let named_robot =
        |p: &Path| p.file_name().and_then(|n| n.to_str()).and_then(dynforge_proto::shard::robot_of_file_name);
    let mut chosen = Vec::new();
    for p in list_shards(&shard_dir(data)).unwrap_or_default() {
        if chosen.len() >= max {
            break;
        }
        if named_robot(&p).is_some_and(|r| !validation(r)) {
            continue;
        }
        let Ok(rec) = read(&p, None) else { continue };
        if rec.robot.is_some_and(validation) {
            chosen.push(rec);
        }
    }
    chosen
}

/// The torque check on up to `max` validation recordings: the estimate from each recording, the true and the
/// training-mean parameters predicting its torques.
fn torque_check(
    estimator: &impl Estimator,
    data: &Path,
    max: usize,
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<Option<TorqueCheck>, EvaluationError> {
    let chosen = validation_recordings(estimator, data, max);
    let (label_mean, _) = estimator.label_statistics();
    let (mut est, mut tru, mut mean) = (TorqueError::default(), TorqueError::default(), TorqueError::default());
    let mut projections = 0;
    for (k, rec) in chosen.iter().enumerate() {
        progress("torque check", k, chosen.len());
        let labels = estimator.estimate(&[rec]).map_err(EvaluationError::Estimator)?;
        let ne = normal_equations(rec)?;
        let (pi_est, notes) = physical_parameters(rec, &rec.model, &labels)?;
        projections += notes;
        est.add(&ne, &pi_est);
        tru.add(&ne, &dynamic_parameters(&rec.model));
        mean.add(&ne, &physical_parameters(rec, &rec.model, &label_mean)?.0);
    }
    progress("torque check", chosen.len(), chosen.len());
    Ok((!chosen.is_empty()).then(|| TorqueCheck {
        recordings: chosen.len(),
        rows: vec![
            TorqueRow::new("estimated", &est),
            TorqueRow::new("true", &tru),
            TorqueRow::new("training mean", &mean),
        ],
        projections,
    }))
}
