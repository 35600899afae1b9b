//! The physics of one recording as inference and evaluation use it: its normal equations, and labels put on its
//! robot as the physical robot the written URDF becomes.

use dynforge_identify::NormalEquations;
use dynforge_proto::NUM_LABELS;
use dynforge_recording::Recording;
use dynforge_robot::Model;
use dynforge_robot::parameters::{dynamic_parameters, model_with_labels};

/// A recording that an estimator or its physics cannot take (too short, no moving joint, labels that make no robot).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}: {problem}")]
pub struct RecordingError {
    pub file: String,
    pub problem: String,
}

/// An error about the recording `p`.
pub fn recording_error(p: &Recording, problem: impl std::fmt::Display) -> RecordingError {
    RecordingError { file: p.path.display().to_string(), problem: problem.to_string() }
}

/// The normal equations of a prepared recording (joints in model order, on the 1 kHz grid).
pub fn normal_equations(p: &Recording) -> Result<NormalEquations, RecordingError> {
    NormalEquations::of(&p.model, &p.trajectory).map_err(|e| recording_error(p, e))
}

/// The parameter vector of `labels` put on `model` (projected to a physical robot, as the written URDF is), and the
/// number of projections that took.
pub fn physical_parameters(
    p: &Recording,
    model: &Model,
    labels: &[f64; NUM_LABELS],
) -> Result<(Vec<f64>, usize), RecordingError> {
    let (m, notes) = model_with_labels(model, labels).map_err(|e| recording_error(p, e))?;
    Ok((dynamic_parameters(&m), notes.len()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynforge_proto::generator::GeneratorConfig;
    use dynforge_recording::GRID_DT;
    use dynforge_robot::generator::generate;
    use dynforge_robot::parameters::labels_of;

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
            trajectory_index: None,
        };
        let ne = normal_equations(&p).unwrap();
        // Central differences of qd err by w^2 dt^2 / 6 relative to qdd (w <= 2.5 rad/s): below 1e-6.
        assert!(ne.mean_nrmse(&dynamic_parameters(&truth)) < 1e-5, "{:?}", ne.nrmse(&dynamic_parameters(&truth)));
        let (wrong, _) = physical_parameters(&p, &truth, &labels_of(&other).unwrap()).unwrap();
        assert!(ne.mean_nrmse(&wrong) > 1e-2, "{:?}", ne.nrmse(&wrong));
    }
}
