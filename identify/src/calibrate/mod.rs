//! Calibrating a robot's URDF to its logs by physics alone: `dynforge identify`.
//!
//! The logs are read on their own clock (`dynforge_recording::log`), their velocity and effort conditioned as their
//! driver wrote them (`crate::signals`), and every moving sample's regressor rows summed (`crate::rows`). The
//! effort convention is the one whose least-squares fit leaves the smaller residual, unless named. Each joint's
//! noise is measured from the residual and its correlation over time (the filter and the controller make neighbouring
//! samples alike), and weights its rows. The parameters are the physically consistent maximum a posteriori estimate
//! with the URDF's own values as prior (`crate::consistent`), and every reported parameter gets the posterior's
//! standard deviation, and says whether the torques or the prior decided it.
//!
//! A log that cannot support a calibration is an error naming the joint and the reason: a joint that never moves, a
//! residual far above the noise (the URDF's kinematics or the log's joints are not the robot's), no moving sample.

mod report;

pub use report::{Decided, Estimated, Identification, JointEstimate, LinkEstimate};

use std::path::PathBuf;

use dynforge_proto::params::friction_index;
use dynforge_recording::ReadError;
use dynforge_recording::log::{Log, read_logs, still_joints};
use dynforge_robot::Model;
use dynforge_robot::model::{Friction, Inertial};
use dynforge_robot::parameters::dynamic_parameters;
use dynforge_robot::spatial::Inertia;
use nalgebra::DVector;

use crate::IdentifyError;
use crate::consistent::{self, CoordinatePrior};
use crate::normal::NormalEquations;
use crate::rows::{RowSums, residuals};
use crate::signals::{
    Conditioning, EffortConvention, VelocityChoice, VelocitySource, choose_cutoff, choose_velocity, condition,
    noise_gain,
};
use crate::solve::least_squares;

/// What an identification is asked.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// How far the URDF's values are trusted (relative; see [`CoordinatePrior::of`]).
    pub spread: f64,
    pub conditioning: Conditioning,
    /// Joints welded at their mean logged position (e.g. a gripper's, still during the excitation).
    pub fixed: Vec<String>,
}

impl Default for Options {
    fn default() -> Self {
        Options { spread: 0.5, conditioning: Conditioning::default(), fixed: Vec::new() }
    }
}

/// Why logs could not be calibrated to.
#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    #[error("no log given")]
    NoLogs,
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("{file}: {source}")]
    Identify { file: String, source: IdentifyError },
    #[error(
        "{joints} never move in the logs (range {ranges}): their friction, and what only their motion shows, cannot be \
         identified; record motion of them, or weld them with --fix {fix}"
    )]
    StillJoints { joints: String, ranges: String, fix: String },
    #[error(
        "the URDF does not explain the torques of joint '{joint}': the calibrated robot leaves {residual:.3e} of its \
         torque's spread unexplained where the log's noise is {noise:.3e}; check that the URDF's kinematics are the \
         robot's, and that the log's joints, units and signs are the URDF's"
    )]
    Unexplained { joint: String, residual: f64, noise: f64 },
}

/// Fewest moving samples of a joint that identification takes: its friction alone has two unknowns, and a tenth
/// of a second of motion at 1 kHz is the least that tells them apart from the noise.
pub const MIN_ROWS: usize = 100;

/// Smallest torque noise assumed, as a fraction of a joint's torque RMS: below what any robot's torque sensing
/// resolves, above the ~1e-5 that the pairing of simulated samples leaves.
pub const NOISE_FLOOR: f64 = 1e-4;

/// Residual over the noise floor (both as fractions of a joint's torque spread) at which the model is taken not to
/// explain a joint: a right model leaves its noise and what the filter's smearing of friction adds (up to 7x the
/// floor on MuJoCo logs of the UR5 with 1 % effort noise); an upper arm 17 cm too long leaves 40x.
pub const UNEXPLAINED_RATIO: f64 = 20.0;

/// A residual this small (of the torque's spread) is explained whatever the noise estimate says.
pub const EXPLAINED_NRMSE: f64 = 0.05;

/// Calibrates the URDF `document` (text, source; default: the first log's `/robot_description`) to `logs` of one
/// robot.
pub fn identify_logs(
    paths: &[PathBuf],
    document: Option<(&str, &str)>,
    options: &Options,
) -> Result<(Identification, Vec<Log>), CalibrateError> {
    if paths.is_empty() {
        return Err(CalibrateError::NoLogs);
    }
    let logs = read_logs(paths, document, &options.fixed)?;
    let still = still_joints(&logs);
    if !still.is_empty() {
        let names: Vec<&String> = still.keys().collect();
        return Err(CalibrateError::StillJoints {
            joints: names.iter().map(|n| format!("'{n}'")).collect::<Vec<_>>().join(", "),
            ranges: still.values().map(|r| format!("{r:.1e}")).collect::<Vec<_>>().join(", "),
            fix: names.iter().map(|n| n.as_str()).collect::<Vec<_>>().join(" --fix "),
        });
    }
    let fail = |source| CalibrateError::Identify { file: logs[0].name(), source };
    let model = logs[0].model.clone();
    let (sums, velocity) = sum_rows(&logs, &options.conditioning).map_err(fail)?;
    let (convention, effort_reason) = choose_convention(&sums, options.conditioning.effort).map_err(fail)?;
    let ne = sums.equations(convention);
    let mut id = fit(&model, &ne, &logs, &velocity, convention, options).map_err(fail)?;
    id.velocity = velocity;
    id.effort_reason = effort_reason;
    id.notes.extend(logs.iter().flat_map(|l| l.notes.iter().map(|n| format!("{}: {n}", l.name()))));
    check_explained(&id, &model)?;
    Ok((id, logs))
}

/// The rows of every segment of `logs`, conditioned, summed; with the velocity decided (from the first log, the
/// cut-off over all).
fn sum_rows(logs: &[Log], conditioning: &Conditioning) -> Result<(RowSums, VelocityChoice), IdentifyError> {
    let first = &logs[0];
    let (source, reason) = choose_velocity(&first.segments[0], first.velocity_logged, conditioning.velocity);
    let cutoff = match source {
        VelocitySource::Logged => None,
        VelocitySource::Positions => Some(conditioning.cutoff.unwrap_or_else(|| {
            let all: Vec<_> = logs.iter().flat_map(|l| l.segments.iter().cloned()).collect();
            choose_cutoff(&all, first.dt)
        })),
    };
    let mut sums = RowSums::new(first.model.dof());
    for log in logs {
        for seg in &log.segments {
            sums.add(&first.model, &condition(seg, source, cutoff.unwrap_or(f64::MAX)))?;
        }
    }
    Ok((sums, VelocityChoice { source, cutoff, reason }))
}

/// The effort convention (`flag`'s, or the one whose least-squares fit explains the torques clearly better) and why.
/// When neither fits clearly better (filtered positions and effort noise blur the half-sample difference), the log
/// is taken as sampled, what most drivers publish (a measured torque), and the reason says so.
fn choose_convention(
    sums: &RowSums,
    flag: Option<EffortConvention>,
) -> Result<(EffortConvention, String), IdentifyError> {
    if let Some(c) = flag {
        return Ok((c, "as asked".into()));
    }
    let fits: Vec<f64> = EffortConvention::ALL
        .iter()
        .map(|&c| {
            let ne = sums.equations(c);
            least_squares(&ne).map(|ls| ne.mean_nrmse(&ls.pi))
        })
        .collect::<Result<_, _>>()?;
    let evidence = format!("least-squares torque NRMSE held {:.3e}, sampled {:.3e}", fits[0], fits[1]);
    if (fits[0] - fits[1]).abs() < CONVENTION_MARGIN * fits[0].min(fits[1]) {
        let why = format!("{evidence}: no clear difference, taken as sampled (most drivers); name it with --effort");
        return Ok((EffortConvention::Sampled, why));
    }
    let best = if fits[1] < fits[0] { EffortConvention::Sampled } else { EffortConvention::Held };
    Ok((best, evidence))
}

/// How much better one convention's fit must be (relative NRMSE) to be taken from the data: exact pairing of clean
/// logs separates them by a factor of two or more; 1 % effort noise behind a 20 Hz filter by under 1 %.
pub const CONVENTION_MARGIN: f64 = 0.1;

/// The joints' noise (standard deviation of the residual [N m or N]) and the integrated autocorrelation time of the
/// residual (in samples, at least 1) of parameters `pi` over the logs.
fn residual_noise(
    model: &Model,
    logs: &[Log],
    velocity: &VelocityChoice,
    convention: EffortConvention,
    pi: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let n = model.dof();
    let (mut sum2, mut count) = (vec![0.0; n], vec![0usize; n]);
    let (mut lag, mut lag_count) = (vec![vec![0.0; MAX_LAG + 1]; n], vec![vec![0usize; MAX_LAG + 1]; n]);
    for log in logs {
        for seg in &log.segments {
            let c = condition(seg, velocity.source, velocity.cutoff.unwrap_or(f64::MAX));
            for (j, series) in residuals(model, &c, pi, convention).iter().enumerate() {
                for (i, e) in series.iter().enumerate() {
                    let Some(e) = e else { continue };
                    sum2[j] += e * e;
                    count[j] += 1;
                    for k in 0..=MAX_LAG.min(series.len() - 1 - i) {
                        if let Some(f) = series[i + k] {
                            lag[j][k] += e * f;
                            lag_count[j][k] += 1;
                        }
                    }
                }
            }
        }
    }
    let mut sigma = vec![0.0; n];
    let mut tau = vec![1.0; n];
    for j in 0..n {
        sigma[j] = (sum2[j] / count[j].max(1) as f64).sqrt();
        let c0 = lag[j][0] / lag_count[j][0].max(1) as f64;
        if c0 <= 0.0 {
            continue;
        }
        // Sokal's window: sum the autocorrelation until the lag passes five times the running sum.
        let mut t = 1.0;
        for k in 1..=MAX_LAG {
            if lag_count[j][k] == 0 {
                break;
            }
            let rho = lag[j][k] / lag_count[j][k] as f64 / c0;
            t += 2.0 * rho;
            if k as f64 >= 5.0 * t {
                break;
            }
        }
        tau[j] = t.max(1.0);
    }
    (sigma, tau)
}

/// Longest lag of the residual's autocorrelation looked at [samples]: a filter at a few Hz correlates ~100 samples at
/// 1 kHz.
const MAX_LAG: usize = 400;

/// The identification proper: least squares (rank, first noise), then the consistent MAP with the noise and its
/// correlation measured from its own residual, twice.
fn fit(
    model: &Model,
    ne: &NormalEquations,
    logs: &[Log],
    velocity: &VelocityChoice,
    convention: EffortConvention,
    options: &Options,
) -> Result<Identification, IdentifyError> {
    let n = model.dof();
    if let Some(j) = (0..n).find(|&j| ne.joint(j).3 < MIN_ROWS) {
        return Err(IdentifyError::TooFewRows { joint: model.joints()[j].name.clone(), rows: ne.joint(j).3 });
    }
    let ls = least_squares(ne)?;
    let prior = CoordinatePrior::of(model, options.spread)?;
    // A joint's noise is taken as at least NOISE_FLOOR of its torque's RMS: exact simulated data would otherwise get
    // unbounded weights.
    let floor = |j: usize| NOISE_FLOOR * (ne.joint(j).2 / ne.joint(j).3 as f64).sqrt();
    let weight = |j: usize, variance: f64, correlation: f64| 1.0 / (variance.max(floor(j).powi(2)) * correlation);
    let mut weights: Vec<f64> =
        (0..n).map(|j| weight(j, ne_joint_rss(ne, j, &ls.pi) / ne.joint(j).3 as f64, 1.0)).collect();
    let mut solution = consistent::solve(ne, &weights, &prior, &prior.mean)?;
    let mut measured = (Vec::new(), Vec::new());
    for _ in 0..2 {
        let pi = consistent::parameters(n, &solution.x);
        measured = residual_noise(model, logs, velocity, convention, &pi);
        weights = (0..n).map(|j| weight(j, measured.0[j].powi(2), measured.1[j])).collect();
        solution = consistent::solve(ne, &weights, &prior, &solution.x)?;
    }
    let pi = consistent::parameters(n, &solution.x);
    let calibrated = model_with(model, &pi)?;
    let (noise, correlation) = measured;
    Ok(Identification::new(report::Fitted {
        model,
        calibrated,
        ne,
        ls: &ls,
        prior: &prior,
        solution: &solution,
        noise,
        correlation,
        convention,
        logs,
        noise_gain: noise_gain(velocity.source, velocity.cutoff, convention, logs[0].dt),
    }))
}

/// Residual sum of squares of `pi` on joint `j` of `ne`.
fn ne_joint_rss(ne: &NormalEquations, j: usize, pi: &[f64]) -> f64 {
    let (a, b, c, _) = ne.joint(j);
    let p = DVector::from_column_slice(pi);
    (p.dot(&(a * &p)) - 2.0 * b.dot(&p) + c).max(0.0)
}

/// `model` with the dynamic parameters `pi` (physical by construction: the consistent search's).
pub(crate) fn model_with(model: &Model, pi: &[f64]) -> Result<Model, IdentifyError> {
    let n = model.dof();
    let inertials: Vec<Inertial> = (0..n)
        .map(|l| {
            let p: [f64; 10] = pi[10 * l..10 * (l + 1)].try_into().expect("10 parameters per link");
            Inertial::from_spatial(&Inertia::from_params(&p))
        })
        .collect();
    let friction: Vec<Friction> = (0..n)
        .map(|j| {
            let at = friction_index(n, j);
            Friction { coulomb: pi[at], viscous: pi[at + 1] }
        })
        .collect();
    model.with_dynamics(&inertials, &friction).map_err(|e| IdentifyError::NotPhysical(e.to_string()))
}

/// An error when a joint's residual is far above its noise floor (a model that does not explain the log).
fn check_explained(id: &Identification, model: &Model) -> Result<(), CalibrateError> {
    for (j, joint) in id.joints.iter().enumerate() {
        let (residual, noise) = (joint.nrmse, joint.noise_floor);
        if residual > EXPLAINED_NRMSE && residual > UNEXPLAINED_RATIO * noise {
            return Err(CalibrateError::Unexplained { joint: model.joints()[j].name.clone(), residual, noise });
        }
    }
    Ok(())
}

/// The normal equations of logs held out of a calibration: the same robot and effort convention as `id`'s, each
/// log's velocity conditioned as its own data ask (a clean held-out log is read as it is): what the held-out torque
/// error of any parameter set is computed from.
pub fn held_out(
    paths: &[PathBuf],
    document: Option<(&str, &str)>,
    options: &Options,
    id: &Identification,
) -> Result<NormalEquations, CalibrateError> {
    let logs = read_logs(paths, document, &options.fixed)?;
    let model = &logs[0].model;
    let mut sums = RowSums::new(model.dof());
    for log in &logs {
        let names = |m: &Model| m.joints().iter().map(|j| j.name.clone()).collect::<Vec<_>>();
        if names(&log.model) != names(&id.model) {
            return Err(CalibrateError::Identify {
                file: log.name(),
                source: IdentifyError::Dof(log.model.dof(), id.model.dof()),
            });
        }
        let (velocity, _) = sum_rows(std::slice::from_ref(log), &options.conditioning)
            .map_err(|source| CalibrateError::Identify { file: log.name(), source })?;
        sums.merge(&velocity);
    }
    Ok(sums.equations(id.effort))
}

/// The nominal parameters of `model`, for comparisons.
pub fn nominal(model: &Model) -> Vec<f64> {
    dynamic_parameters(model)
}
