//! `dynforge estimate` as one call: a recording's estimate, refined by physics, written into the robot's URDF, and
//! what to tell the user about it.

use std::path::{Path, PathBuf};

use dynforge_evaluation::recording::recording_error;
use dynforge_evaluation::spread::Noise;
use dynforge_proto::{LABELS, NUM_LABELS};
use dynforge_recording::Recording;
use dynforge_robot::{parameters, urdf};

use super::{Estimate, InferenceError, Predictor, Refinement};

/// What `estimate` found and wrote.
pub struct EstimateReport {
    pub log: PathBuf,
    /// The labels the URDF carries (the estimate after any projection into physics) [SI].
    pub values: [f64; NUM_LABELS],
    /// The estimator's own output and spread.
    pub estimate: Estimate,
    /// The refinement by the log's torques (`None` if not asked for, or if the log cannot refine: then `warning`).
    pub refinement: Option<Refinement>,
    pub warning: Option<String>,
    /// The checkpoint's spread calibration could not be read (the spreads are then the validation RMSE).
    pub calibration_warning: Option<String>,
    pub projections: Vec<String>,
    /// What writing into the user's URDF could not do as asked (a welded tool heavier than the estimate).
    pub notes: Vec<String>,
    pub urdf: PathBuf,
}

/// Estimates the robot of the recording `log` with the checkpoint in `dir`, the robot being that of the URDF
/// `document` (its text and name), refines it by the log's torques if `refine`, and writes the document with the
/// result to `out` (atomically; only the moving links' `<inertial>` and joints' `<dynamics>` change). A log whose
/// torques cannot refine (no joint moves) keeps the estimator's output, with a warning.
pub fn estimate_to_urdf(
    dir: &Path,
    log: &Path,
    document: (&str, &str),
    out: &Path,
    refine: bool,
) -> Result<EstimateReport, InferenceError> {
    let predictor = Predictor::load(dir)?;
    let model = urdf::parse(document.0, document.1)?;
    let (rec, estimate) = predictor.estimate_file(log, Some(&model))?;
    let (refinement, warning) = match refine {
        false => (None, None),
        true => match predictor.refine(&[&rec], &estimate) {
            Ok(r) => (Some(r), None),
            Err(e) => (None, Some(format!("the estimate is not refined by physics: {e}"))),
        },
    };
    if let Some(r) = &refinement {
        predictive_check(dir, &rec, r)?;
    }
    let wanted = refinement.as_ref().map_or(estimate.labels, |r| r.labels);
    let (robot, projections) =
        parameters::model_with_labels(&rec.model, &wanted).map_err(|e| recording_error(&rec, e))?;
    // What is reported is what the URDF carries: the labels after any projection into physics.
    let values = parameters::labels_of(&robot).map_err(|e| recording_error(&rec, e))?;
    let (text, notes) = urdf::patch(document.0, document.1, &robot)?;
    dynforge_proto::run_dir::write_atomic(out, text.as_bytes())
        .map_err(|source| InferenceError::Write { file: out.display().to_string(), source })?;
    let urdf = out.into();
    let calibration_warning = predictor.calibration_problem().map(str::to_string);
    Ok(EstimateReport {
        log: log.to_path_buf(),
        values,
        estimate,
        refinement,
        warning,
        calibration_warning,
        projections,
        notes,
        urdf,
    })
}

/// Refined torque NRMSE on the log over its measured noise at which the robot is taken not to be one of the
/// family: a robot of it is explained to its noise; one whose dynamics the family's parameters cannot take is not.
pub const PREDICTIVE_RATIO: f64 = 20.0;

/// A refined torque NRMSE under this is explained whatever the measured noise.
pub const EXPLAINED_NRMSE: f64 = 0.05;

/// The posterior predictive check: an error when the refined estimate leaves the log's torques far above their
/// noise (measured without a model, from the efforts' scatter between samples: the residual would absorb what the
/// model misses), i.e. the robot's dynamics are not those of the family the model was trained on (its kinematics
/// already passed).
fn predictive_check(dir: &Path, rec: &Recording, r: &Refinement) -> Result<(), InferenceError> {
    let noise = dynforge_identify::signals::effort_scatter(&[&rec.trajectory]).into_iter().fold(0.0f64, f64::max);
    if r.nrmse_refined > EXPLAINED_NRMSE && r.nrmse_refined > PREDICTIVE_RATIO * noise {
        return Err(InferenceError::Checkpoint(crate::checkpoint::CheckpointError::OtherFamily {
            checkpoint: dir.display().to_string(),
            problem: format!(
                "{}: the family's best parameters leave {:.3} of the torques' spread unexplained, where their noise \
                 is {noise:.1e}",
                rec.path.display(),
                r.nrmse_refined
            ),
        }));
    }
    Ok(())
}

impl EstimateReport {
    /// Each label's standard deviation as reported: the refinement's posterior, else the estimator's spread.
    pub fn spread(&self) -> [f64; NUM_LABELS] {
        self.refinement.as_ref().map_or(self.estimate.spread, |r| r.std)
    }

    /// Whether the log decided label `k`: its spread under half the family's (else the value is about what any
    /// robot of the family has).
    pub fn from_log(&self, k: usize) -> bool {
        self.spread()[k] < 0.5 * self.estimate.family[k]
    }

    pub fn json(&self) -> serde_json::Value {
        let e = &self.estimate;
        let parameters: serde_json::Map<String, serde_json::Value> = LABELS
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let decided = if self.from_log(k) { "log" } else { "family" };
                let v = serde_json::json!({
                    "value": self.values[k], "estimator": e.labels[k], "spread": self.spread()[k],
                    "estimator_spread": e.spread[k], "evidence_spread": e.posterior.map(|p| p[k]),
                    "posterior_deviation": e.deviation.map(|p| p[k]), "family_spread": e.family[k],
                    "refined_posterior": self.refinement.as_ref().map(|r| r.posterior[k]),
                    "decided": decided, "unit": l.kind.unit()
                });
                (l.name.to_string(), v)
            })
            .collect();
        let refined = self.refinement.as_ref().map(|r| {
            serde_json::json!({
                "identifiable": r.identifiable, "calibration_robots": r.calibration_robots,
                "calibration_fresh": r.calibration_fresh,
                "torque_nrmse_estimator": r.nrmse_network, "torque_nrmse_refined": r.nrmse_refined,
            })
        });
        serde_json::json!({
            "windows": e.windows, "torque_noise": e.noise, "parameters": parameters, "refinement": refined,
            "noise_level": match e.assumed_noise() { Noise::Floor => None, Noise::Measured(level) => Some(level) },
            "projections": self.projections, "notes": self.notes, "urdf": self.urdf,
        })
    }
}

impl std::fmt::Display for EstimateReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let e = &self.estimate;
        writeln!(f, "{}: {} windows", self.log.display(), e.windows)?;
        if !e.noise.is_empty() {
            let joints: Vec<String> = e.noise.iter().map(|n| format!("{n:.1e}")).collect();
            writeln!(
                f,
                "torque noise per joint (NRMSE, from the log's residual; the evidence is weighted by it): {}",
                joints.join(" ")
            )?;
        }
        writeln!(
            f,
            "{:<12} {:>12} {:>12} {:>12}  unit   (spread: standard deviation; * the log cannot tell it from the family's \
             spread)",
            "parameter", "estimate", "estimator", "spread"
        )?;
        let spread = self.spread();
        for (k, l) in LABELS.iter().enumerate() {
            let mark = if self.from_log(k) { " " } else { "*" };
            let (v, est, unit) = (self.values[k], e.labels[k], l.kind.unit());
            writeln!(f, "{:<12} {v:>12.6} {est:>12.6} {:>12.2e}{mark} {unit}", l.name, spread[k])?;
        }
        let source = if e.spread_from_validation { "the checkpoint's report.json" } else { "the training labels" };
        match (&self.refinement, &self.warning) {
            (Some(r), _) => {
                let robots =
                    if r.calibration_fresh { "robots drawn fresh from the generator" } else { "validation robots" };
                let widened = match (r.calibration_robots, e.assumed_noise()) {
                    (Some(n), Noise::Floor) => {
                        format!("; spreads calibrated on {n} {robots}, for a log at the noise floor")
                    }
                    (Some(n), Noise::Measured(level)) => {
                        format!("; spreads calibrated on {n} {robots}, at this log's noise (median NRMSE {level:.1e})")
                    }
                    (None, _) => String::new(),
                };
                writeln!(
                    f,
                    "refined by physics ({} identifiable parameter combinations; the estimator's spread from \
                     {source}{widened}): torque NRMSE on this log {:.4} (estimator alone {:.4})",
                    r.identifiable, r.nrmse_refined, r.nrmse_network
                )?
            }
            (None, Some(_)) => writeln!(f, "estimator output only (not refined: see the warning above)")?,
            (None, None) => writeln!(f, "estimator output only (--no-refine)")?,
        }
        for n in &self.projections {
            writeln!(f, "projected: {n}")?;
        }
        for n in &self.notes {
            writeln!(f, "note: {n}")?;
        }
        writeln!(f, "URDF with the estimated parameters: {}", self.urdf.display())
    }
}
