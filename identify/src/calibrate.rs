//! Calibrating a robot description to its recordings by physics alone, without a trained network.

use std::path::{Path, PathBuf};

use dynforge_proto::{LABELS, LabelKind, NUM_LABELS};
use dynforge_recording::{ReadError, read};
use dynforge_robot::Model;
use dynforge_robot::parameters::{dynamic_parameters, labels_of, model_with_labels};

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
    let before = labels_of(model).map_err(|_| IdentifyError::Dof(model.dof(), 6))?;
    let std: [f64; NUM_LABELS] = std::array::from_fn(|k| (spread * before[k].abs()).max(spread_floor(LABELS[k].kind)));
    let ls = least_squares(ne)?;
    let refined = refine(ne, model, &Prior::new(before, &std)?, ls.sigma)?;
    let (calibrated, projections) =
        model_with_labels(model, &refined.labels).map_err(|_| IdentifyError::Dof(model.dof(), 6))?;
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

/// Why log files could not be calibrated to.
#[derive(Debug, thiserror::Error)]
pub enum CalibrateFilesError {
    #[error("no log given")]
    NoLogs,
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("{file}: {source}")]
    Identify { file: String, source: IdentifyError },
    #[error(
        "{file} is a log of another robot than {first} (its /robot_description differs): calibrate one robot at a \
         time, or give --urdf if they are the same robot described differently"
    )]
    OtherRobot { file: String, first: String },
}

/// A description calibrated to log files (shards or ROS 2 bags) of one robot.
pub struct FileCalibration {
    pub logs: Vec<PathBuf>,
    /// Torque rows (moving joint samples) the logs gave.
    pub rows: usize,
    pub calibration: Calibration,
}

/// Calibrates `model` (default: the first log's `/robot_description`) to the logs, each read by joint name; see
/// [`calibrate`].
pub fn calibrate_files(
    logs: &[PathBuf],
    mut model: Option<Model>,
    spread: f64,
) -> Result<FileCalibration, CalibrateFilesError> {
    let mut ne: Option<NormalEquations> = None;
    let fail = |file: &Path| {
        let file = file.display().to_string();
        move |source| CalibrateFilesError::Identify { file, source }
    };
    // Each log read with the URDF given, or else with its own description, which must be the first log's: the sums
    // of two robots' logs identify neither, and a URDF of that mixture is no robot.
    let given = model.clone();
    for log in logs {
        let p = read(log, given.as_ref())?;
        if let Some(first) = &model
            && *first != p.model
        {
            return Err(CalibrateFilesError::OtherRobot {
                file: log.display().to_string(),
                first: logs[0].display().to_string(),
            });
        }
        let this = NormalEquations::of(&p.model, &p.trajectory).map_err(fail(log))?;
        match &mut ne {
            Some(sum) => sum.merge(&this),
            None => ne = Some(this),
        }
        model.get_or_insert(p.model);
    }
    let (Some(model), Some(ne)) = (model, ne) else { return Err(CalibrateFilesError::NoLogs) };
    let calibration = calibrate(&model, &ne, spread).map_err(fail(&logs[0]))?;
    Ok(FileCalibration { logs: logs.to_vec(), rows: ne.rows(), calibration })
}

impl FileCalibration {
    /// The calibration as JSON, with the URDF it was written to.
    pub fn json(&self, urdf: &Path) -> serde_json::Value {
        let c = &self.calibration;
        let parameters: serde_json::Map<String, serde_json::Value> = LABELS
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let v = serde_json::json!({"value": c.labels[k], "urdf": c.before[k], "unit": l.kind.unit()});
                (l.name.to_string(), v)
            })
            .collect();
        serde_json::json!({
            "logs": self.logs, "torque_rows": self.rows, "identifiable": c.rank, "parameters": parameters,
            "torque_nrmse": {"urdf": c.nrmse_before, "least_squares": c.nrmse_least_squares, "calibrated": c.nrmse_after},
            "projections": c.projections, "urdf": urdf,
        })
    }
}

/// `N log(s), R torque rows, ` and the calibration.
impl std::fmt::Display for FileCalibration {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} log(s), {} torque rows, {}", self.logs.len(), self.rows, self.calibration)
    }
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
        if self.nrmse_after > self.nrmse_before {
            writeln!(
                f,
                "warning: the calibrated robot predicts these logs' torques worse than the URDF as given; the logs \
                 may be too short or too slow to excite it, or sampled too coarsely for the accelerations (1 kHz is \
                 what identification is built for): keep the URDF, or record richer motion"
            )?;
        }
        for n in &self.projections {
            writeln!(f, "projected: {n}")?;
        }
        Ok(())
    }
}
