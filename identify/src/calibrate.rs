//! Calibrating a robot description to its recordings by physics alone, without a trained network.

use dynforge_proto::{LABELS, LabelKind, NUM_LABELS};
use dynforge_robot::Model;
use dynforge_robot::parameters::{dynamic_parameters, labels, with_labels};

use crate::IdentifyError;
use crate::normal::NormalEquations;
use crate::refine::{Prior, refine};
use crate::solve::least_squares;

/// Smallest prior spread per label kind, for descriptions that leave a value at zero (friction, most often):
/// 0.1 N m (Coulomb), 0.1 N m s/rad (viscous), 0.1 kg, 1 cm, 1e-4 kg m^2.
fn spread_floor(kind: LabelKind) -> f64 {
    match kind {
        LabelKind::Coulomb | LabelKind::Viscous | LabelKind::Mass => 0.1,
        LabelKind::Com => 0.01,
        _ => 1e-4,
    }
}

/// A description calibrated to recordings.
#[derive(Debug, Clone)]
pub struct Calibration {
    /// The description's labels and the calibrated ones.
    pub before: [f64; NUM_LABELS],
    pub labels: [f64; NUM_LABELS],
    /// Identifiable parameter combinations in the recordings.
    pub rank: usize,
    /// Torque NRMSE on the recordings of the description as given, of least squares (base parameters) and of the
    /// calibrated model.
    pub nrmse_before: f64,
    pub nrmse_least_squares: f64,
    pub nrmse_after: f64,
    /// The calibrated model (labels projected to physics where needed, each projection described).
    pub model: Model,
    pub projections: Vec<String>,
}

/// The 38 labels of the 6-joint `model` that best explain the recordings summed in `ne`, with the description's
/// own values as prior: each label believed to within `spread` of its value (relative; see the floors above).
pub fn calibrate(model: &Model, ne: &NormalEquations, spread: f64) -> Result<Calibration, IdentifyError> {
    let before = labels(model).map_err(|_| IdentifyError::Dof(model.dof(), 6))?;
    let std: [f64; NUM_LABELS] = std::array::from_fn(|k| (spread * before[k].abs()).max(spread_floor(LABELS[k].kind)));
    let ls = least_squares(ne)?;
    let refined = refine(ne, model, &Prior::new(before, &std)?, ls.sigma)?;
    let (calibrated, projections) =
        with_labels(model, &refined.labels).map_err(|_| IdentifyError::Dof(model.dof(), 6))?;
    Ok(Calibration {
        before,
        labels: refined.labels,
        rank: ls.rank,
        nrmse_before: ne.mean_nrmse(&dynamic_parameters(model)),
        nrmse_least_squares: ne.mean_nrmse(&ls.pi),
        nrmse_after: ne.mean_nrmse(&dynamic_parameters(&calibrated)),
        model: calibrated,
        projections,
    })
}

/// `N identifiable parameter combinations`, the labels calibrated beside the description's, the torque NRMSE of
/// each, and the projections.
impl std::fmt::Display for Calibration {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "{} identifiable parameter combinations", self.rank)?;
        writeln!(f, "{:<12} {:>12} {:>12}  unit", "parameter", "calibrated", "urdf")?;
        for (k, l) in LABELS.iter().enumerate() {
            writeln!(f, "{:<12} {:>12.6} {:>12.6}  {}", l.name, self.labels[k], self.before[k], l.kind.unit())?;
        }
        writeln!(
            f,
            "torque NRMSE on the logs: calibrated {:.4}, URDF as given {:.4}, least squares (base parameters) {:.4}",
            self.nrmse_after, self.nrmse_before, self.nrmse_least_squares
        )?;
        for n in &self.projections {
            writeln!(f, "projected: {n}")?;
        }
        Ok(())
    }
}
