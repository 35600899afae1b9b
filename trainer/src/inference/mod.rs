//! Estimating the parameters of one recording (a dataset shard or a user's ROS 2 bag) with a checkpoint: every
//! window of the recording is predicted and the predictions are averaged, and their spread reported.

use std::path::Path;

use burn::tensor::Device;
use dynforge_identify::{Prior, least_squares, refine};
use dynforge_proto::NUM_LABELS;
use dynforge_robot::Model;

use crate::checkpoint::{Checkpoint, CheckpointError};
use crate::data::cache::CachedWindows;
use dynforge_recording::{GRID_DT, ReadError, Recording, read};

use crate::data::dataset::{row_width, windows};
use crate::data::features::JacobianFeatures;
use crate::evaluation::torque::{normal_equations, physical_parameters, recording_error};
use crate::model::Estimator;
use crate::training::predict;

#[derive(Debug, thiserror::Error)]
pub enum InferenceError {
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("{file}: {problem}")]
    Recording { file: String, problem: String },
}

/// A recording's estimate.
#[derive(Debug, Clone)]
pub struct Estimate {
    /// Mean over windows of the predicted labels [SI].
    pub labels: [f64; NUM_LABELS],
    /// Standard deviation over windows [SI] (0 with one window).
    pub spread: [f64; NUM_LABELS],
    pub windows: usize,
}

/// An estimate refined by physics.
#[derive(Debug, Clone)]
pub struct Refinement {
    pub labels: [f64; NUM_LABELS],
    /// Identifiable parameter combinations in the recording.
    pub identifiable: usize,
    /// Whether the prior's spread came from an evaluation (`report.json`) rather than the training labels.
    pub prior_from_validation: bool,
    /// Torque NRMSE on the recording itself, of the network's estimate and of the refined labels (each as the
    /// physical robot the URDF gets).
    pub nrmse_network: f64,
    pub nrmse_refined: f64,
}

/// The network's per-robot validation RMSE per label [SI], from the `report.json` that `evaluate` leaves in `dir`.
fn validation_rmse(dir: &Path) -> Option<[f64; NUM_LABELS]> {
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("report.json")).ok()?).ok()?;
    let targets = report.get("robots")?.get("targets")?.as_array()?;
    let values: Vec<f64> = targets.iter().filter_map(|t| t.get("rmse_si")?.as_f64()).collect();
    let rmse: [f64; NUM_LABELS] = values.try_into().ok()?;
    rmse.iter().all(|&x| x > 0.0 && x.is_finite()).then_some(rmse)
}

/// A loaded checkpoint, ready to estimate recordings.
pub struct Predictor {
    pub checkpoint: Checkpoint,
    model: Estimator,
    device: Device,
}

impl Predictor {
    pub fn load(dir: &Path) -> Result<Self, InferenceError> {
        let device = Device::default();
        let (checkpoint, model) = Checkpoint::load(dir, &device)?;
        Ok(Predictor { checkpoint, model, device })
    }

    /// The network (evaluation mode).
    pub fn model(&self) -> &Estimator {
        &self.model
    }

    /// Estimate of a prepared recording, checked against the checkpoint's joints and features.
    pub fn estimate_prepared(&self, dir: &Path, p: &Recording) -> Result<Estimate, InferenceError> {
        let features = JacobianFeatures::new(&p.model);
        let joints: Vec<String> = p.model.joints().iter().map(|j| j.name.clone()).collect();
        self.checkpoint.check_fits(dir, &joints, &features)?;
        let spec = self.checkpoint.window_spec();
        let (count, data) = windows(p, &spec, &features);
        if count == 0 {
            let seconds = p.trajectory.len() as f64 * GRID_DT;
            return Err(InferenceError::Recording {
                file: p.path.display().to_string(),
                problem: format!(
                    "{seconds:.3} s of motion is shorter than one window ({:.3} s = {} samples x {} ms)",
                    spec.span(GRID_DT),
                    spec.len,
                    spec.stride
                ),
            });
        }
        let w = CachedWindows {
            spec,
            width: row_width(&p.model, &features),
            data,
            labels: vec![[0.0; NUM_LABELS]; count],
            robots: vec![0; count],
            hit: false,
        };
        let s = self.checkpoint.standardizer();
        let x: Vec<f32> = (0..count).flat_map(|i| s.inputs(&w, i)).collect();
        let per_window: Vec<[f64; NUM_LABELS]> =
            predict(&self.model, &x, count, spec.len, s.columns.len(), &self.device)
                .iter()
                .map(|t| s.labels(t))
                .collect();
        let n = count as f64;
        let labels: [f64; NUM_LABELS] = std::array::from_fn(|k| per_window.iter().map(|y| y[k]).sum::<f64>() / n);
        let spread =
            std::array::from_fn(|k| (per_window.iter().map(|y| (y[k] - labels[k]).powi(2)).sum::<f64>() / n).sqrt());
        Ok(Estimate { labels, spread, windows: count })
    }

    /// The network's estimate `e` of the recording `p` refined by physics: the labels that best explain the
    /// recording's torques (least squares on the regressor) with the estimate as prior. The prior's spread per label
    /// is the network's per-robot validation RMSE from `report.json` in the checkpoint directory (written by
    /// `evaluate`), or the training labels' spread when there is none.
    pub fn refine(&self, dir: &Path, p: &Recording, e: &Estimate) -> Result<Refinement, InferenceError> {
        let ne = normal_equations(p)?;
        let ls = least_squares(&ne).map_err(|err| recording_error(p, err))?;
        let validated = validation_rmse(dir);
        let std = validated.unwrap_or_else(|| std::array::from_fn(|k| self.checkpoint.label_std[k]));
        let prior = Prior::new(e.labels, &std).map_err(|err| recording_error(p, err))?;
        let refined = refine(&ne, &p.model, &prior, ls.sigma).map_err(|err| recording_error(p, err))?;
        // Scored as the written URDF will be: projected to a physical robot.
        let nrmse = |y| physical_parameters(p, &p.model, y).map(|(pi, _)| ne.mean_nrmse(&pi));
        Ok(Refinement {
            labels: refined.labels,
            identifiable: ls.rank,
            prior_from_validation: validated.is_some(),
            nrmse_network: nrmse(&e.labels)?,
            nrmse_refined: nrmse(&refined.labels)?,
        })
    }

    /// Reads and estimates the recording `path`; its robot comes from its `/robot_description` unless `urdf` is
    /// given.
    pub fn estimate(
        &self,
        dir: &Path,
        path: &Path,
        urdf: Option<&Model>,
    ) -> Result<(Recording, Estimate), InferenceError> {
        let p = read(path, urdf)?;
        let e = self.estimate_prepared(dir, &p)?;
        Ok((p, e))
    }
}
