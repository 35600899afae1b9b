//! A calibration carried to its file: the URDF patched, written whole or not at all, read back, and the report made
//! of what the file holds, so that what is printed is what is written to the last digit.

use std::path::{Path, PathBuf};

use dynforge_proto::run_dir::write_atomic;
use dynforge_recording::check_not_an_input;
use dynforge_recording::log::Log;
use dynforge_robot::urdf;

use super::{CalibrateError, Identification, Options, held_out, identify_logs, nominal};

/// The torque error of the URDF as given, of the calibrated robot (its URDF and its drives) and of least squares on
/// logs the calibration did not see.
#[derive(Debug, Clone, serde::Serialize)]
pub struct HeldOut {
    pub logs: Vec<PathBuf>,
    /// Mean over joints of the torque RMSE over the torque's spread, with the URDF as given.
    pub nrmse_urdf: f64,
    /// The same with the calibrated robot.
    pub nrmse_calibrated: f64,
    /// The same with the least-squares estimate of the same logs (base parameters, same conditioning): the classical
    /// reference, which fits torques with no regard for physics.
    pub nrmse_least_squares: f64,
    /// The three over every joint's rows together ([`crate::NormalEquations::pooled_nrmse`]).
    pub pooled: Pooled,
}

/// Pooled torque NRMSE of each parameter set.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Pooled {
    pub urdf: f64,
    pub calibrated: f64,
    pub least_squares: f64,
}

/// A calibration written to a URDF.
#[derive(Debug, Clone)]
pub struct Calibrated {
    /// As the written URDF holds it.
    pub id: Identification,
    pub urdf: PathBuf,
    /// The MuJoCo model written beside it, if asked ([`Calibrated::write_mjcf`]).
    pub mjcf: Option<PathBuf>,
    pub held_out: Option<HeldOut>,
}

/// Calibrates `document` (text, source; default: the first log's `/robot_description`) to `logs`, writes the
/// calibrated URDF to `out` (atomically; never over an input), and compares both URDFs on `holdout` if any.
pub fn calibrate_to_urdf(
    logs: &[PathBuf],
    document: Option<(&str, &str)>,
    options: &Options,
    holdout: &[PathBuf],
    out: &Path,
) -> Result<Calibrated, CalibrateError> {
    check_output(logs, document, holdout, out)?;
    let (id, read) = identify_logs(logs, document, options)?;
    write_calibrated(id, &read, document, options, holdout, out)
}

/// An error if `out` is one of the inputs (a log, a held-out log, the URDF), or a held-out log is also one the
/// calibration is made from (its score would be of data the fit saw, and read as a test).
pub fn check_output(
    logs: &[PathBuf],
    document: Option<(&str, &str)>,
    holdout: &[PathBuf],
    out: &Path,
) -> Result<(), CalibrateError> {
    use dynforge_proto::run_dir::resolve;
    for held in holdout {
        if let Some(log) = logs.iter().find(|l| resolve(l) == resolve(held)) {
            return Err(CalibrateError::Read(dynforge_recording::ReadError::Content {
                file: held.display().to_string(),
                problem: format!(
                    "held out and also calibrated from (as {}): a held-out score is of motion the fit did not see",
                    log.display()
                ),
            }));
        }
    }
    let inputs: Vec<PathBuf> = logs.iter().chain(holdout).cloned().chain(document.map(|(_, s)| s.into())).collect();
    Ok(check_not_an_input(out, &inputs)?)
}

/// Writes the calibrated robot of `id` (identified from the logs `read`) into the URDF `out`, reports the values the
/// file holds, and compares both URDFs on `holdout` if any.
pub fn write_calibrated(
    mut id: Identification,
    read: &[Log],
    document: Option<(&str, &str)>,
    options: &Options,
    holdout: &[PathBuf],
    out: &Path,
) -> Result<Calibrated, CalibrateError> {
    if !id.converged && !options.accept_unconverged {
        return Err(CalibrateError::NotConverged { out: out.display().to_string(), iterations: id.iterations });
    }
    let log = &read[0];
    let (text, notes) =
        urdf::patch_welded(&log.document, &log.source, &id.model, &log.welds, urdf::Unsplit::KeepWelded)?;
    id.notes.extend(notes);
    write_atomic(out, text.as_bytes())
        .map_err(|source| CalibrateError::Write { file: out.display().to_string(), source })?;
    let written = urdf::parse_welded(&text, &out.display().to_string(), &log.welds)?;
    id.report_values_of(&written);
    let held_out = match holdout.is_empty() {
        true => None,
        false => {
            let ne = held_out(holdout, document, options, &id)?;
            match ne.rows() {
                // A log with no joint in motion has no torque error to speak of (not a perfect one).
                0 => {
                    id.notes.push("the held-out log(s) hold no motion: no torques to compare the URDFs on".into());
                    None
                }
                _ => {
                    let (urdf, calibrated) = (nominal(&log.model), id.identified());
                    Some(HeldOut {
                        logs: holdout.to_vec(),
                        nrmse_urdf: ne.mean_nrmse(&urdf),
                        nrmse_calibrated: ne.mean_nrmse(&calibrated),
                        nrmse_least_squares: ne.mean_nrmse(&id.least_squares),
                        pooled: Pooled {
                            urdf: ne.pooled_nrmse(&urdf),
                            calibrated: ne.pooled_nrmse(&calibrated),
                            least_squares: ne.pooled_nrmse(&id.least_squares),
                        },
                    })
                }
            }
        }
    };
    Ok(Calibrated { id, urdf: out.to_path_buf(), mjcf: None, held_out })
}

impl Calibrated {
    /// Writes the calibrated robot as a MuJoCo model to `path` (atomically; check it with [`check_output`] before the
    /// calibration): the URDF's bodies and friction with each joint's rotor inertia as its `armature`, and the
    /// joints' torque offsets, which a MuJoCo joint cannot hold, as the numeric `offset` (one per joint, in order).
    pub fn write_mjcf(&mut self, path: &Path) -> Result<(), CalibrateError> {
        let drives = self.id.drives();
        let armature: Vec<f64> = drives.iter().map(|d| d.armature).collect();
        let offsets = ("offset".to_string(), drives.iter().map(|d| d.offset).collect());
        let text = dynforge_robot::mjcf::to_mjcf(&self.id.model, &armature, &[offsets]);
        write_atomic(path, text.as_bytes())
            .map_err(|source| CalibrateError::Write { file: path.display().to_string(), source })?;
        self.mjcf = Some(path.to_path_buf());
        Ok(())
    }

    /// The identification as JSON, with the written files and the held-out comparison.
    pub fn json(&self) -> serde_json::Result<serde_json::Value> {
        let mut v = serde_json::to_value(&self.id)?;
        v["urdf"] = serde_json::json!(self.urdf);
        if let Some(m) = &self.mjcf {
            v["mjcf"] = serde_json::json!(m);
        }
        if let Some(h) = &self.held_out {
            v["held_out"] = serde_json::json!(h);
        }
        Ok(v)
    }
}

impl std::fmt::Display for Calibrated {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.id)?;
        if let Some(h) = &self.held_out {
            writeln!(
                f,
                "torque NRMSE on {} held-out log(s), mean over joints / pooled: calibrated {:.4} / {:.4}, URDF as \
                 given {:.4} / {:.4}, least squares {:.4} / {:.4}",
                h.logs.len(),
                h.nrmse_calibrated,
                h.pooled.calibrated,
                h.nrmse_urdf,
                h.pooled.urdf,
                h.nrmse_least_squares,
                h.pooled.least_squares
            )?;
        }
        writeln!(f, "calibrated URDF: {}", self.urdf.display())?;
        if let Some(m) = &self.mjcf {
            writeln!(f, "calibrated MuJoCo model: {} (rotor inertia as armature)", m.display())?;
        }
        Ok(())
    }
}
