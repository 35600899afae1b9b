//! The torque check: how well parameter sets predict recordings' torques by inverse dynamics.
//!
//! For every sample, `tau_hat = Y(q, qd, qdd) pi` (RNEA plus friction) with `qdd` by central differences of `qd` on
//! the 1 kHz grid, against the recorded (applied) torque; a joint's samples at rest are left out (static Coulomb
//! friction takes any value in `[-mu_c, mu_c]`). NRMSE per joint = RMSE / standard deviation of the recorded torque
//! over the same samples; the overall value is the mean over joints. The sums live in `dynforge_identify`'s normal
//! equations, so one pass over a recording scores any number of parameter sets.

use dynforge_identify::{NormalEquations, TorqueError};
use dynforge_proto::NUM_LABELS;
use dynforge_robot::Model;
use dynforge_robot::parameters::{dynamic_parameters, with_labels};
use serde::{Deserialize, Serialize};

use dynforge_recording::Recording;
use crate::inference::InferenceError;

/// Held-out torque NRMSE of one parameter set.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TorqueRow {
    pub parameters: String,
    /// Per joint (NaN for a joint that never moved).
    pub per_joint: Vec<f64>,
    pub overall: f64,
}

impl TorqueRow {
    pub(crate) fn new(parameters: &str, e: &TorqueError) -> Self {
        TorqueRow { parameters: parameters.into(), per_joint: e.per_joint(), overall: e.overall() }
    }
}

/// Markdown table of torque rows.
pub(crate) fn table(rows: &[TorqueRow]) -> String {
    let joints = rows.first().map_or(0, |r| r.per_joint.len());
    let mut out = format!(
        "| parameters |{} overall |\n|---|{}---:|\n",
        (0..joints).map(|j| format!(" J{j} |")).collect::<String>(),
        "---:|".repeat(joints)
    );
    for r in rows {
        out.push_str(&format!(
            "| {} |{} {:.4} |\n",
            r.parameters,
            r.per_joint.iter().map(|x| format!(" {x:.4} |")).collect::<String>(),
            r.overall
        ));
    }
    out
}

/// An error about the recording `p`.
pub(crate) fn recording_error(p: &Recording, problem: impl std::fmt::Display) -> InferenceError {
    InferenceError::Recording { file: p.path.display().to_string(), problem: problem.to_string() }
}

/// The normal equations of a prepared recording (joints in model order, on the 1 kHz grid).
pub(crate) fn normal_equations(p: &Recording) -> Result<NormalEquations, InferenceError> {
    NormalEquations::of(&p.model, &p.trajectory).map_err(|e| recording_error(p, e))
}

/// The parameter vector of `labels` put on `model` (projected to a physical robot, as the written URDF is), and the
/// number of projections that took.
pub(crate) fn physical_parameters(
    p: &Recording,
    model: &Model,
    labels: &[f64; NUM_LABELS],
) -> Result<(Vec<f64>, usize), InferenceError> {
    let (m, notes) = with_labels(model, labels).map_err(|e| recording_error(p, e))?;
    Ok((dynamic_parameters(&m), notes.len()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynforge_recording::GRID_DT;
    use dynforge_robot::generator::{GeneratorConfig, generate};
    use dynforge_robot::parameters::labels;

    #[test]
    fn true_parameters_predict_the_torques_to_the_finite_difference_error_and_wrong_ones_do_not() {
        let cfg = GeneratorConfig::default();
        let truth = generate(&cfg, 1, 0).unwrap().model;
        let other = generate(&cfg, 1, 1).unwrap().model;
        let p = Recording {
            path: "sinusoids".into(),
            model: truth.clone(),
            trajectory: dynforge_testkit::sinusoid_recording(&truth, 0, GRID_DT, 4000),
            labels: None,
            robot: None,
        };
        let ne = normal_equations(&p).unwrap();
        // Central differences of qd err by w^2 dt^2 / 6 relative to qdd (w <= 2.5 rad/s): below 1e-6.
        assert!(ne.mean_nrmse(&dynamic_parameters(&truth)) < 1e-5, "{:?}", ne.nrmse(&dynamic_parameters(&truth)));
        let (wrong, _) = physical_parameters(&p, &truth, &labels(&other).unwrap()).unwrap();
        assert!(ne.mean_nrmse(&wrong) > 1e-2, "{:?}", ne.nrmse(&wrong));
    }
}
