//! Estimating a robot's parameters from its recordings (dataset shards or a user's ROS 2 bags) with a checkpoint.
//! The transformer predicts every window and averages; the physics estimator reads the evidence of the recordings
//! whole (more data is sharper evidence, not more votes). Both report the spread of their per-window predictions.

mod report;

use std::path::{Path, PathBuf};

use burn::tensor::Device;
use dynforge_identify::{BatchScatter, Evidence, ParameterPrior};
use dynforge_proto::NUM_LABELS;
use dynforge_recording::{GRID_DT, ReadError, Recording, read};
use dynforge_robot::Model;

use dynforge_dataset::cache::CacheError;
use dynforge_dataset::cache::windows::CachedWindows;
use dynforge_dataset::evidence::{
    COHERENCE, EvidenceError, NOISE_FLOOR, features, label_deviation, label_posterior, measured_evidence,
};
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::windows::{row_width, windows};
use dynforge_evaluation::recording::{RecordingError, physical_parameters};
use dynforge_evaluation::spread::{
    Calibration, Noise, ValidationSpreads, at_least, between_log_counts, estimator_spread, refine_recordings,
    refined_noise,
};
use dynforge_evaluation::{Estimated, EvaluationError};

use crate::checkpoint::{Checkpoint, CheckpointError};
use crate::evaluation::plots::PlotError;
use crate::model::Network;
use crate::training::predict_with;
pub use report::{EstimateReport, estimate_to_urdf};

#[derive(Debug, thiserror::Error)]
pub enum InferenceError {
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error(transparent)]
    Cache(#[from] CacheError),
    #[error(transparent)]
    Evidence(#[from] EvidenceError),
    #[error(transparent)]
    Plot(#[from] PlotError),
    #[error(transparent)]
    Urdf(#[from] dynforge_robot::ModelError),
    #[error("{file}: {source}")]
    Write { file: String, source: std::io::Error },
    #[error(transparent)]
    Recording(#[from] RecordingError),
    #[error(transparent)]
    Evaluation(#[from] EvaluationError),
    #[error("no recording to estimate from")]
    NoRecording,
}

/// An estimate from one robot's recordings.
#[derive(Debug, Clone)]
pub struct Estimate {
    /// The estimated labels [SI].
    pub labels: [f64; NUM_LABELS],
    /// The estimator's standard deviation per label [SI], and the prior the refinement by the log's torques starts
    /// from. Where `evaluate` calibrated the spreads on validation robots (its `report.json`): the evidence's
    /// posterior for this robot as calibrated for this many logs. Else its validation RMSE for this many logs, else
    /// the training labels' spread.
    pub spread: [f64; NUM_LABELS],
    /// Whether `spread` came from an evaluation rather than the training labels.
    pub spread_from_validation: bool,
    /// The family's spread per label [SI] (the training labels' standard deviation): what is known of a robot
    /// from its family alone, against which a log's information is measured.
    pub family: [f64; NUM_LABELS],
    pub windows: usize,
    /// Physics estimator: each joint's torque noise as an NRMSE, as the logs' residuals show it (the largest over
    /// the logs; the evidence is weighted by it). Empty for the transformer.
    pub noise: Vec<f64>,
    /// Physics estimator: the standard deviation per label [SI] that the evidence alone implies for this robot.
    pub posterior: Option<[f64; NUM_LABELS]>,
    /// Physics estimator: the labels [SI] at the evidence's posterior mean (with the family as prior).
    pub plug_in: Option<[f64; NUM_LABELS]>,
    /// Physics estimator: how the logs' scores scatter between quarter seconds against the noise the evidence
    /// assumed (`BatchScatter::ratio`).
    pub scatter: Option<f64>,
    /// Physics estimator: how far each label [SI] of the posterior lies from the estimate (`label_deviation`: the
    /// spread whose intervals about it hold the posterior's central 68 and 95 %); for a simulated log, of the
    /// posterior its residual supports (the sandwich at `COHERENCE` times its scatter). What the calibration scales.
    pub deviation: Option<[f64; NUM_LABELS]>,
}

impl Estimate {
    /// The noise the evidence assumed: the floor on every joint (a simulated log's), or the logs' measured noise.
    /// The transformer reads no evidence: the floor, where its calibration has its one part.
    pub fn assumed_noise(&self) -> Noise {
        match self.posterior {
            Some(_) => Noise::of(at_noise_floor(&self.noise), &self.noise),
            None => Noise::Floor,
        }
    }

    /// What the spreads' calibration reads of this estimate.
    pub fn evidence(&self) -> Estimated {
        Estimated {
            labels: self.labels,
            posterior: self.posterior,
            noise: self.assumed_noise(),
            deviation: self.deviation,
        }
    }
}

/// Whether every joint's torque noise (NRMSE) is the evidence's floor, as on a simulated log: its posterior is then
/// as wide as the floor, not as the data.
fn at_noise_floor(noise: &[f64]) -> bool {
    noise.iter().all(|&n| n <= NOISE_FLOOR * (1.0 + 1e-6))
}

/// The evidence of a whole recording, each joint's torque noise (NRMSE) it was weighted by, and how its scores
/// scatter against that noise.
pub type WholeRecording = (Evidence, Vec<f64>, BatchScatter);

/// An estimate refined by physics.
#[derive(Debug, Clone)]
pub struct Refinement {
    pub labels: [f64; NUM_LABELS],
    /// Standard deviation per label [SI]: the refinement's posterior as calibrated, for a calibrated physics estimator
    /// on a noisy log never under the estimate's own spread (its evidence already read these torques); the
    /// estimate's spread where the torques cannot tell the label.
    pub std: [f64; NUM_LABELS],
    /// The refinement's posterior as it came [SI] (before the calibration).
    pub posterior: [f64; NUM_LABELS],
    /// Identifiable parameter combinations in the recording.
    pub identifiable: usize,
    /// Robots on which the spreads were calibrated (`None`: the posterior as it comes, when `evaluate` calibrated
    /// none).
    pub calibration_robots: Option<usize>,
    /// Whether those robots were drawn fresh from the generator (else: the validation robots).
    pub calibration_fresh: bool,
    /// Torque NRMSE on the recording itself, of the network's estimate and of the refined labels (each as the
    /// physical robot the URDF gets).
    pub nrmse_network: f64,
    pub nrmse_refined: f64,
}

/// What `evaluate` measured of the estimator's errors on its validation robots (its `report.json`): the RMSE per
/// label [SI] from one log and from all of a robot's (`per_robot` logs), and the spreads' calibration.
#[derive(Debug, Clone)]
struct Validated {
    one: [f64; NUM_LABELS],
    all: [f64; NUM_LABELS],
    per_robot: f64,
    calibration: Option<ValidationSpreads>,
    /// Why `report.json`'s calibration was not used, when it is there and does not read.
    calibration_problem: Option<String>,
}

impl Validated {
    /// Reads `report.json` in `dir`; `None` when absent, unreadable, or with an RMSE that is not positive.
    fn read(dir: &Path) -> Option<Validated> {
        let report: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("report.json")).ok()?).ok()?;
        let rmse = |protocol: &str| -> Option<[f64; NUM_LABELS]> {
            let targets = report.get(protocol)?.get("targets")?.as_array()?;
            let values: Vec<f64> = targets.iter().filter_map(|t| t.get("rmse_si")?.as_f64()).collect();
            let rmse: [f64; NUM_LABELS] = values.try_into().ok()?;
            rmse.iter().all(|&x| x > 0.0 && x.is_finite()).then_some(rmse)
        };
        let all = rmse("robots")?;
        // A calibration that does not read is said, not dropped in silence: the spreads fall back to the RMSE.
        let (calibration, calibration_problem) = match report.get("spread_calibration").filter(|v| !v.is_null()) {
            None => (None, None),
            Some(v) => match serde_json::from_value(v.clone()) {
                Ok(c) => (Some(c), None),
                Err(e) => (
                    None,
                    Some(format!(
                        "{}: spread_calibration does not read ({e}); the spreads are the validation RMSE (run \
                         `dynforge evaluate` again to measure it)",
                        dir.join("report.json").display()
                    )),
                ),
            },
        };
        Some(match rmse("recordings") {
            Some(one) => Validated {
                one,
                all,
                per_robot: report.get("logs_per_robot").and_then(|v| v.as_f64()).unwrap_or(1.0),
                calibration,
                calibration_problem,
            },
            None => Validated { one: all, all, per_robot: 1.0, calibration, calibration_problem },
        })
    }

    /// The estimator's error per label for an estimate from `logs` logs.
    fn rmse(&self, logs: usize) -> [f64; NUM_LABELS] {
        between_log_counts(&self.one, &self.all, self.per_robot, logs)
    }
}

/// A loaded checkpoint, ready to estimate recordings.
pub struct Predictor {
    /// The checkpoint directory (its `report.json`, when `evaluate` left one, sets the refinement's prior spread).
    pub dir: PathBuf,
    pub checkpoint: Checkpoint,
    model: Network,
    prior: Option<ParameterPrior>,
    validated: Option<Validated>,
    device: Device,
}

impl Predictor {
    pub fn load(dir: &Path) -> Result<Self, InferenceError> {
        let device = Device::default();
        let (checkpoint, model) = Checkpoint::load(dir, &device)?;
        let prior = checkpoint.parameter_prior();
        let validated = Validated::read(dir);
        Ok(Predictor { dir: dir.to_path_buf(), checkpoint, model, prior, validated, device })
    }

    /// The network (evaluation mode).
    pub fn model(&self) -> &Network {
        &self.model
    }

    /// Why the checkpoint's spread calibration is not used although `evaluate` wrote one (it does not read).
    pub fn calibration_problem(&self) -> Option<&str> {
        self.validated.as_ref()?.calibration_problem.as_deref()
    }

    /// Whether this is the physics estimator.
    pub fn is_physics(&self) -> bool {
        self.prior.is_some()
    }

    /// Predictions [SI] of standardised inputs (`count` examples of the model's input shape).
    pub(crate) fn predict_standardised(&self, x: &[f32], count: usize) -> Vec<[f64; NUM_LABELS]> {
        let per = self.checkpoint.model.input_shape().iter().product::<usize>();
        self.predict_standardised_with(count, |r| x[r.start * per..r.end * per].to_vec())
    }

    /// [`Self::predict_standardised`] of inputs made a batch at a time by `inputs(range)`.
    pub(crate) fn predict_standardised_with(
        &self,
        count: usize,
        inputs: impl Fn(std::ops::Range<usize>) -> Vec<f32> + Sync,
    ) -> Vec<[f64; NUM_LABELS]> {
        let s = self.checkpoint.standardizer();
        predict_with(&self.model, count, self.checkpoint.model.input_shape(), &self.device, inputs)
            .iter()
            .map(|t| s.labels(t))
            .collect()
    }

    /// The physics estimator's predictions [SI] of pieces of evidence (e.g. windows', or robots' summed).
    pub fn predict_evidence(&self, evidence: &[Evidence]) -> Result<Vec<[f64; NUM_LABELS]>, InferenceError> {
        let prior = self.prior.as_ref().ok_or_else(|| RecordingError {
            file: self.checkpoint.dataset.clone(),
            problem: "not a physics checkpoint".into(),
        })?;
        let s = self.checkpoint.standardizer();
        let mut x = Vec::new();
        for e in evidence {
            let f = features(prior, e, &s.label_mean, &s.label_std)
                .map_err(|err| RecordingError { file: self.checkpoint.dataset.clone(), problem: err.to_string() })?;
            x.extend(s.row(&f));
        }
        Ok(self.predict_standardised(&x, evidence.len()))
    }

    /// Checks that `rec` fits the checkpoint and has a window at least.
    fn check(&self, rec: &Recording) -> Result<JacobianFeatures, InferenceError> {
        let features = JacobianFeatures::new(&rec.model);
        self.checkpoint.check_fits(&self.dir, &rec.model, &features)?;
        let spec = self.checkpoint.window_spec();
        if spec.windows(rec.trajectory.len()).is_empty() {
            return Err(InferenceError::Recording(RecordingError {
                file: rec.path.display().to_string(),
                problem: format!(
                    "{:.3} s of motion is shorter than one window ({:.3} s = {} samples x {} ms)",
                    rec.seconds(),
                    spec.span(GRID_DT),
                    spec.len,
                    spec.stride
                ),
            }));
        }
        Ok(features)
    }

    /// Per-window predictions [SI] of a recording (windows in `WindowSpec::windows` order), and for the physics
    /// estimator the evidence of the whole recording and each joint's torque noise (NRMSE).
    pub fn windows(&self, rec: &Recording) -> Result<(Vec<[f64; NUM_LABELS]>, Option<WholeRecording>), InferenceError> {
        let features = self.check(rec)?;
        let spec = self.checkpoint.window_spec();
        if let Some(prior) = &self.prior {
            let m = measured_evidence(rec, prior, &spec)?;
            return Ok((self.predict_evidence(&m.windows)?, Some((m.whole, m.noise, m.scatter))));
        }
        let (count, data) = windows(rec, &spec, &features);
        let w = CachedWindows {
            spec,
            width: row_width(&rec.model, &features),
            data,
            labels: vec![[0.0; NUM_LABELS]; count],
            robots: vec![0; count],
            trajectories: vec![0; count],
            hit: false,
        };
        let s = self.checkpoint.standardizer();
        let x: Vec<f32> = (0..count).flat_map(|i| s.inputs(&w, i)).collect();
        Ok((self.predict_standardised(&x, count), None))
    }

    /// The estimate of one robot from its recordings `recs` (all of the same robot), checked against the
    /// checkpoint's joints (and, for the transformer, features).
    pub fn estimate(&self, recs: &[&Recording]) -> Result<Estimate, InferenceError> {
        let mut per_window = Vec::new();
        let mut whole: Option<Evidence> = None;
        let mut noise: Vec<f64> = Vec::new();
        let mut scatter = BatchScatter::default();
        for rec in recs {
            let (w, e) = self.windows(rec)?;
            per_window.extend(w);
            if let Some((e, n, s)) = e {
                scatter.add(&s);
                noise.resize(n.len(), 0.0);
                noise.iter_mut().zip(&n).for_each(|(a, b)| *a = a.max(*b));
                match &mut whole {
                    Some(sum) => sum.add(&e),
                    None => whole = Some(e),
                }
            }
        }
        let n = per_window.len() as f64;
        let mean: [f64; NUM_LABELS] = std::array::from_fn(|k| per_window.iter().map(|y| y[k]).sum::<f64>() / n);
        let family: [f64; NUM_LABELS] = std::array::from_fn(|k| self.checkpoint.label_std[k]);
        let (labels, posterior, plug_in, deviation) = match (whole, &self.prior) {
            (Some(e), Some(prior)) => {
                let bad = |err: dynforge_identify::IdentifyError| RecordingError {
                    file: recs.first().map_or(String::new(), |r| r.path.display().to_string()),
                    problem: err.to_string(),
                };
                // Where the posterior has no answer (a link mass near zero) the family's spread stands.
                let finite =
                    |s: [f64; NUM_LABELS]| std::array::from_fn(|k| if s[k].is_finite() { s[k] } else { family[k] });
                let post = e.posterior().map_err(bad)?;
                let (plug_in, spread) = label_posterior(prior, &post);
                let labels = self.predict_evidence(std::slice::from_ref(&e))?[0];
                // A simulated log draws from what its residual supports; a noisier one from its own posterior.
                let drawn = match at_noise_floor(&noise) {
                    true => e.sandwich(COHERENCE * scatter.ratio()).map_err(bad)?,
                    false => post,
                };
                let deviation = label_deviation(prior, &drawn, &labels);
                (labels, Some(finite(spread)), Some(plug_in), Some(finite(deviation)))
            }
            _ => (mean, None, None, None),
        };
        let mut estimate = Estimate {
            labels,
            spread: family,
            spread_from_validation: false,
            family,
            windows: per_window.len(),
            noise,
            posterior,
            plug_in,
            scatter: posterior.map(|_| scatter.ratio()),
            deviation,
        };
        // The calibration's part for the noise the evidence assumed: at the floor (a simulated log) or at the log's.
        if let Some(v) = &self.validated {
            estimate.spread = match &v.calibration {
                Some(c) => estimator_spread(&estimate.evidence(), &c.at(recs.len()).0, &family),
                None => {
                    let rmse = v.rmse(recs.len());
                    std::array::from_fn(|k| at_least(rmse[k], family[k]))
                }
            };
            estimate.spread_from_validation = true;
        }
        Ok(estimate)
    }

    /// The estimate `e` of the robot of recordings `recs` refined by physics: the labels that best explain their
    /// torques (least squares on the regressor) with the estimate as prior, its spread as the prior's.
    pub fn refine(&self, recs: &[&Recording], e: &Estimate) -> Result<Refinement, InferenceError> {
        let p = recs.first().ok_or(InferenceError::NoRecording)?;
        let r = refine_recordings(recs, &e.labels, &e.spread)?;
        // The posterior as the validation robots calibrated it (`dynforge_evaluation::spread`).
        let calibration = self.validated.as_ref().and_then(|v| v.calibration.as_ref());
        let refined_calibration = calibration.map(|c| c.at(recs.len()).1);
        let noise = refined_noise(&r.refined, e.assumed_noise());
        let calibrated: [f64; NUM_LABELS] = match &refined_calibration {
            Some(c) => {
                let part = c.part(noise);
                std::array::from_fn(|k| part.apply(k, r.refined.std[k]))
            }
            None => r.refined.std,
        };
        // The physics estimator's evidence was these torques: the refinement makes the labels one physical robot
        // that fits them, but its posterior counts them a second time. On a noisy log its spread is never under the
        // estimate's (a calibrated posterior's: an RMSE is one number for all robots). Without that, held-out logs
        // below the lowest calibrated noise (0.1 %) put 34-69 % of labels within one; with a calibration measured on
        // noise-free logs only, 49-52 % of friction labels at 1 %. A log at the noise floor is what the refined
        // calibration was measured on, and there the rule only widened (73-83 % within one instead of 71-80); it
        // stays for a calibration from before the noisy logs were measured.
        let measured_at_floor = |c: &Calibration| noise == Noise::Floor && !c.noisy.is_empty();
        let std: [f64; NUM_LABELS] = match (e.posterior, &refined_calibration) {
            (Some(_), Some(c)) if !measured_at_floor(c) => std::array::from_fn(|k| calibrated[k].max(e.spread[k])),
            _ => calibrated,
        };
        // Never wider than the family's spread (what is known of the robot without its log), never narrower than
        // the estimate's numbers can be trusted.
        let std = std::array::from_fn(|k| at_least(std[k].min(e.family[k]), e.family[k]));
        // Scored as the written URDF will be: projected to a physical robot.
        let nrmse = |y| physical_parameters(p, &p.model, y).map(|(pi, _)| r.ne.mean_nrmse(&pi));
        Ok(Refinement {
            labels: r.refined.labels,
            std,
            posterior: r.refined.std,
            identifiable: r.least_squares.rank,
            calibration_robots: calibration.map(|c| c.robots),
            calibration_fresh: calibration.is_some_and(|c| c.fresh),
            nrmse_network: nrmse(&e.labels)?,
            nrmse_refined: nrmse(&r.refined.labels)?,
        })
    }

    /// Reads and estimates the recording `path`; its robot comes from its `/robot_description` unless `urdf` is
    /// given.
    pub fn estimate_file(&self, path: &Path, urdf: Option<&Model>) -> Result<(Recording, Estimate), InferenceError> {
        let p = read(path, urdf)?;
        let e = self.estimate(&[&p])?;
        Ok((p, e))
    }
}
