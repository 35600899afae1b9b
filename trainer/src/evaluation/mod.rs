//! `dynforge evaluate`: a checkpoint's predictions on its validation robots (both protocols: per window, and per
//! robot from all its recordings), its figures (`plots`), and the report of `dynforge_dataset::evaluation` (the
//! paper's tables, the torque check, the identification check) for which [`Predictor`] is the estimator.

pub mod plots;

use std::path::Path;

use dynforge_dataset::cache::evidence::PhysicsSet;
use dynforge_dataset::cache::windows::CachedWindows;
use dynforge_dataset::examples::Examples;
use dynforge_dataset::examples::corpus::Corpus;
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::normalize::Standardizer;
use dynforge_dataset::split::{Split, SplitRule};
use dynforge_dataset::window::WindowSpec;
use dynforge_evaluation::{Checks, Estimated, Estimator, EstimatorError, Report, Validation, per_robot_mean};
use dynforge_proto::NUM_LABELS;
use dynforge_recording::Recording;
use dynforge_recording::dataset::dataset_robot;

use crate::checkpoint::Checkpoint;
use crate::inference::{InferenceError, Predictor};
use crate::training::session::Inputs;
use dynforge_dataset::metrics::EpochMetrics;

impl Estimator for Predictor {
    fn split(&self) -> SplitRule {
        self.checkpoint.split_rule()
    }

    fn window_spec(&self) -> WindowSpec {
        self.checkpoint.window_spec()
    }

    fn label_statistics(&self) -> ([f64; NUM_LABELS], [f64; NUM_LABELS]) {
        let s = self.checkpoint.standardizer();
        (s.label_mean, s.label_std)
    }

    fn estimate(&self, recordings: &[&Recording]) -> Result<[f64; NUM_LABELS], EstimatorError> {
        Ok(Predictor::estimate(self, recordings)?.labels)
    }

    fn estimate_with_spread(&self, recordings: &[&Recording]) -> Result<Estimated, EstimatorError> {
        let e = Predictor::estimate(self, recordings)?;
        Ok(e.evidence())
    }
}

/// Evaluates the checkpoint in `dir` on the validation robots of its dataset `data` (its windows or physics in
/// `inputs` when the caller has them), with the `checks` beyond the scores; draws its figures into `dir`.
pub fn evaluate_checkpoint(
    dir: &Path,
    data: &Path,
    inputs: Option<Inputs>,
    checks: Checks,
    mut progress: impl FnMut(&str, usize, usize),
) -> Result<Report, InferenceError> {
    let predictor = Predictor::load(dir)?;
    let v = validate(&predictor, data, inputs, &mut progress)?;
    plot(dir, &v, &predictor.checkpoint.standardizer())?;
    let name = (dir.display().to_string(), predictor.checkpoint.epoch);
    let r = dynforge_evaluation::report(&predictor, (&name.0, name.1), &v, data, checks, progress)?;
    Ok(r)
}

fn validate(
    predictor: &Predictor,
    data: &Path,
    inputs: Option<Inputs>,
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<Validation, InferenceError> {
    let c = &predictor.checkpoint;
    let rule = c.split_rule();
    let inputs = match inputs {
        Some(i) => i,
        None => load_inputs(c, data, progress)?,
    };
    progress("validation", 0, 1);
    let v = match inputs {
        Inputs::Windows(w) => validate_windows(predictor, w, &rule),
        Inputs::Physics(set) => validate_physics(predictor, &set, &rule)?,
    };
    progress("validation", 1, 1);
    Ok(v)
}

/// The dataset's cache the checkpoint reads: its physics, or its windows.
fn load_inputs(
    c: &Checkpoint,
    data: &Path,
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<Inputs, InferenceError> {
    let spec = c.window_spec();
    Ok(match c.parameter_prior() {
        Some(prior) => {
            let loaded = PhysicsSet::load(data, &spec, &prior, None, |k, n| {
                progress("physics", k, n);
                true
            })?;
            Inputs::Physics(loaded.cache)
        }
        None => {
            let features = JacobianFeatures::new(&dataset_robot(data)?);
            let loaded = CachedWindows::load(data, &spec, &features, None, |k, n| {
                progress("windows", k, n);
                true
            })?;
            Inputs::Windows(loaded.cache)
        }
    })
}

/// The validation windows' predictions, and per robot the mean over its validation windows. Only back-to-back windows
/// are scored, whatever hop the model trained with: the same windows for every model.
fn validate_windows(predictor: &Predictor, w: CachedWindows, rule: &SplitRule) -> Validation {
    let (origins, scored) = (w.origins(), w.back_to_back());
    let ids: Vec<usize> = (0..w.count()).filter(|&i| scored[i] && rule.side(origins[i]) == Split::Validation).collect();
    let standardizer = predictor.checkpoint.standardizer();
    let corpus = Corpus { windows: w, train: Vec::new(), validation: ids, standardizer };
    let truth = corpus.validation_labels();
    let predicted = predictor.predict_standardised_with(truth.len(), |r| corpus.validation_inputs(r));
    let window_robots: Vec<u64> = corpus.validation.iter().map(|&i| corpus.windows.robots[i]).collect();
    let (robot_ids, robot_predicted, robot_truth) = per_robot_mean(&window_robots, &predicted, &truth);
    Validation {
        robots: corpus.windows.robots,
        labels: corpus.windows.labels,
        window_predicted: predicted,
        window_truth: truth,
        robot_ids,
        robot_predicted,
        robot_truth,
        recordings: None,
    }
}

fn validate_physics(predictor: &Predictor, set: &PhysicsSet, rule: &SplitRule) -> Result<Validation, InferenceError> {
    let (window_sides, recording_sides) = set.sides(rule);
    let validation = |i: usize| recording_sides[i] == Split::Validation;
    let w = &set.windows;
    let scored = w.back_to_back(&set.spec);
    let ids: Vec<usize> = (0..w.len()).filter(|&i| scored[i] && window_sides[i] == Split::Validation).collect();
    let window_predicted = predictor.predict_evidence(&ids.iter().map(|&i| w.get(i)).collect::<Vec<_>>())?;
    let robots = set.recordings.per_robot(validation);
    let robot_predicted = predictor.predict_evidence(&robots.iter().map(|(_, _, e)| e.clone()).collect::<Vec<_>>())?;
    let r = &set.recordings;
    let logs: Vec<usize> = (0..r.len()).filter(|&i| validation(i)).collect();
    let log_predicted = predictor.predict_evidence(&logs.iter().map(|&i| r.get(i)).collect::<Vec<_>>())?;
    Ok(Validation {
        robots: w.robots.clone(),
        labels: w.labels.clone(),
        window_predicted,
        window_truth: ids.iter().map(|&i| w.labels[i]).collect(),
        robot_ids: robots.iter().map(|(r, _, _)| *r).collect(),
        robot_predicted,
        robot_truth: robots.iter().map(|(_, y, _)| *y).collect(),
        recordings: Some((log_predicted, logs.iter().map(|&i| r.labels[i]).collect())),
    })
}

/// The predicted-vs-true plot of the validation windows and, if the run left its metrics, the learning curves.
fn plot(dir: &Path, v: &Validation, s: &Standardizer) -> Result<(), InferenceError> {
    let path = dir.join("predicted_vs_true.png");
    plots::predicted_vs_true(&path, &v.window_predicted, &v.window_truth, &s.label_mean, &s.label_std)?;
    let history: Option<Vec<EpochMetrics>> =
        std::fs::read(dir.join("metrics.json")).ok().and_then(|b| serde_json::from_slice(&b).ok());
    if let Some(h) = history.filter(|h| !h.is_empty()) {
        plots::learning_curves(&dir.join("learning_curves.png"), &h)?;
    }
    Ok(())
}
