//! `dynforge estimate` as one call: a recording's estimate, refined by physics, written into the robot's URDF, and
//! what to tell the user about it.

use std::path::{Path, PathBuf};

use dynforge_dataset::evaluation::recording::recording_error;
use dynforge_proto::{LABELS, NUM_LABELS};
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
        true => match predictor.refine(&rec, &estimate) {
            Ok(r) => (Some(r), None),
            Err(e) => (None, Some(format!("the estimate is not refined by physics: {e}"))),
        },
    };
    let wanted = refinement.as_ref().map_or(estimate.labels, |r| r.labels);
    let (robot, projections) =
        parameters::model_with_labels(&rec.model, &wanted).map_err(|e| recording_error(&rec, e))?;
    // What is reported is what the URDF carries: the labels after any projection into physics.
    let values = parameters::labels_of(&robot).map_err(|e| recording_error(&rec, e))?;
    let (text, notes) = urdf::patch(document.0, document.1, &robot)?;
    dynforge_proto::run_dir::write_atomic(out, text.as_bytes())
        .map_err(|source| InferenceError::Write { file: out.display().to_string(), source })?;
    let urdf = out.into();
    Ok(EstimateReport { log: log.to_path_buf(), values, estimate, refinement, warning, projections, notes, urdf })
}

impl EstimateReport {
    pub fn json(&self) -> serde_json::Value {
        let e = &self.estimate;
        let parameters: serde_json::Map<String, serde_json::Value> = LABELS
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let v = serde_json::json!({
                    "value": self.values[k], "estimator": e.labels[k], "spread": e.spread[k], "unit": l.kind.unit()
                });
                (l.name.to_string(), v)
            })
            .collect();
        let refined = self.refinement.as_ref().map(|r| {
            serde_json::json!({
                "identifiable": r.identifiable, "prior_from_validation": r.prior_from_validation,
                "torque_nrmse_estimator": r.nrmse_network, "torque_nrmse_refined": r.nrmse_refined,
            })
        });
        serde_json::json!({
            "windows": e.windows, "torque_noise": e.noise, "parameters": parameters, "refinement": refined,
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
        writeln!(f, "{:<12} {:>12} {:>12} {:>12}  unit", "parameter", "estimate", "estimator", "spread")?;
        for (k, l) in LABELS.iter().enumerate() {
            writeln!(
                f,
                "{:<12} {:>12.6} {:>12.6} {:>12.6}  {}",
                l.name,
                self.values[k],
                e.labels[k],
                e.spread[k],
                l.kind.unit()
            )?;
        }
        match (&self.refinement, &self.warning) {
            (Some(r), _) => writeln!(
                f,
                "refined by physics ({} identifiable parameter combinations; prior spread from {}): torque NRMSE on \
                 this log {:.4} (estimator alone {:.4})",
                r.identifiable,
                if r.prior_from_validation { "the checkpoint's report.json" } else { "the training labels" },
                r.nrmse_refined,
                r.nrmse_network
            )?,
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
