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

pub mod family;
mod ran;
mod readiness;
mod report;
mod written;

pub use ran::{RAN_TOLERANCE, Ran, check_ran};
pub use readiness::{Readiness, Refusal, TESTED_RATES};
pub use report::{
    Decided, Estimated, Identification, JointEstimate, Kind, LinkEstimate, Parameter, RUN_TO_RUN, RunToRun, Scale,
    measured_share,
};
pub use written::{Calibrated, HeldOut, calibrate_to_urdf, check_output, write_calibrated};

use std::path::PathBuf;

use dynforge_proto::params::friction_index;
use dynforge_proto::spread::Spread;
use dynforge_recording::Reading;
use dynforge_recording::log::{Log, read_logs, still_joints};
use dynforge_recording::{JointTrajectory, ReadError};
use dynforge_robot::Model;
use dynforge_robot::drive::{Drive, drive_index, drives, with_identified};
use dynforge_robot::parameters::dynamic_parameters;
use dynforge_robot::prior::{self as coordinates, CoordinatePrior};
use nalgebra::{DMatrix, DVector};

use crate::IdentifyError;
use crate::consistent;
use crate::normal::NormalEquations;
use crate::rows::{Residual, RowSums, residuals};
use crate::signals::{
    Conditioned, Conditioning, EffortConvention, VelocityChoice, VelocitySource, choose_signals, condition, noise_gain,
    row_step,
};
use crate::solve::least_squares;

/// What an identification is asked.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// How far the URDF's values are trusted (relative; see [`CoordinatePrior::of`]).
    pub spread: Spread,
    pub conditioning: Conditioning,
    /// How the logs are read: a table's columns, the drives' gains, joints welded at their mean logged position
    /// (e.g. a gripper's, still during the excitation).
    pub reading: Reading,
    /// Whether joints that move too little in the logs ([`idle_joints`]) are welded at their mean logged position,
    /// with a note, rather than refused: what a user's logs of an arm with a gripper held still want, and not what
    /// a family made for the robot as named wants (`dynforge calibrate`).
    pub weld_idle: bool,
    /// Whether a search that stopped before converging may still be written (its values are where it stopped, not
    /// the optimum, and its spreads are not the posterior's).
    pub accept_unconverged: bool,
    /// How far friction moves between runs of the arm, as a share of its value ([`report::RUN_TO_RUN`]), or
    /// measured over the logs: the friction's and offsets' spreads over runs ([`Identification::over_runs`]).
    pub run_to_run: RunToRun,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            spread: Spread::uniform(0.5),
            conditioning: Conditioning::default(),
            reading: Reading::default(),
            weld_idle: true,
            accept_unconverged: false,
            run_to_run: RunToRun::Share(report::RUN_TO_RUN),
        }
    }
}

/// Why logs could not be calibrated to.
#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    #[error("no log given")]
    NoLogs,
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error(transparent)]
    Model(#[from] dynforge_robot::ModelError),
    #[error("writing {file}: {source}")]
    Write { file: String, source: std::io::Error },
    #[error("{file}: {source}")]
    Identify { file: String, source: IdentifyError },
    #[error(
        "{joints} never move in the logs (range {ranges}): their friction, and what only their motion shows, cannot be \
         identified; record motion of them, or weld them with --fix {fix}"
    )]
    StillJoints { joints: String, ranges: String, fix: String },
    #[error(
        "the logged effort is not the joint torque the URDF predicts: {joints} (the effort over the URDF's torque, \
         friction taken out of both, where the URDF's torque has the effort's shape: partial correlation \
         {MIN_CORRELATION} or more; a torque's are positive, about 1 on most joints). If the log holds motor \
         currents, give --gains (joint torque per unit of effort, one per joint in the URDF's order; \
         these scales suggest about {suggested}); a negative scale is a joint whose sign differs between the log and \
         the URDF. Scales of every joint: {all}"
    )]
    EffortScale { joints: String, suggested: String, all: String },
    #[error("{0}")]
    NotRun(String),
    #[error(
        "{file}: the effort of {joints} is zero in every sample: the log holds no torque to calibrate from (does the \
         driver publish effort? a column map may name the wrong column)"
    )]
    NoEffort { file: String, joints: String },
    #[error(
        "{file}: --cutoff {cutoff} Hz is at or above the log's Nyquist frequency ({nyquist:.1} Hz): a low-pass filter \
         there passes everything; give a lower one, or none (chosen from the positions' noise)"
    )]
    Cutoff { file: String, cutoff: f64, nyquist: f64 },
    #[error(
        "{out}: not written: the search stopped after {iterations} iterations without converging, and its values are \
         not the optimum's. Record richer motion, check the URDF, or write it anyway with --accept-unconverged"
    )]
    NotConverged { out: String, iterations: usize },
}

/// Fewest moving samples of a joint that identification takes: its friction alone has two unknowns, and a tenth
/// of a second of motion at 1 kHz is the least that tells them apart from the noise.
pub const MIN_ROWS: usize = 100;

/// Smallest torque noise assumed, as a fraction of a joint's torque RMS: below what any robot's torque sensing
/// resolves, above the ~1e-5 that the pairing of simulated samples leaves.
pub const NOISE_FLOOR: f64 = 1e-4;

/// Residual over the noise floor (both as fractions of a joint's torque spread) at which a joint's residual is taken
/// to be a model's error: a right model leaves its noise and what the filter's smearing of friction adds (up to 7x
/// the floor on MuJoCo logs of the UR5 with 1 % effort noise).
pub const UNEXPLAINED_RATIO: f64 = 20.0;

/// A residual this small (of the torque's spread) is not called a model's error whatever the noise estimate says.
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
    let logs = read_logs(paths, document, &options.reading)?;
    let idle = idle_joints(&logs);
    // With every joint idle there is no arm left to weld them to: the refusal names them.
    if !options.weld_idle || idle.is_empty() || idle.len() == logs[0].model.dof() {
        return identify_read(logs, options);
    }
    let mut reading = options.reading.clone();
    reading.fixed.extend(idle.keys().cloned());
    let mut welded = read_logs(paths, document, &reading)?;
    let said: Vec<String> = idle.iter().map(|(name, moving)| format!("'{name}' ({moving})")).collect();
    welded[0].notes.push(format!(
        "joint(s) {} move too little in the logs (moving samples, under {MIN_ROWS}): welded at their mean logged \
         position; record motion of them to identify them, or name them with --fix",
        said.join(", ")
    ));
    identify_read(welded, options)
}

/// Joints that move in fewer than [`MIN_ROWS`] samples of `logs` (the central difference of their positions faster
/// than [`crate::REST_SPEED`]), by name with that count: too little motion to identify their friction, and rows that
/// would only add their noise.
pub fn idle_joints(logs: &[Log]) -> std::collections::BTreeMap<String, usize> {
    let Some(first) = logs.first() else { return Default::default() };
    let n = first.model.dof();
    (0..n)
        .map(|j| {
            let moving: usize = logs
                .iter()
                .flat_map(|log| log.segments.iter().map(move |s| (s, 2.0 * log.dt)))
                .map(|(s, span)| {
                    (1..s.len().saturating_sub(1))
                        .filter(|&i| ((s.q[(i + 1) * n + j] - s.q[(i - 1) * n + j]) / span).abs() > crate::REST_SPEED)
                        .count()
                })
                .sum();
            (first.model.joints()[j].name.clone(), moving)
        })
        .filter(|(_, moving)| *moving < MIN_ROWS)
        .collect()
}

/// Joints of `log` whose effort is exactly zero in every sample, by name: a driver that fills the field with zeros,
/// or a column map that points at the wrong column. No fit can take torques from them.
pub fn silent_joints(log: &Log) -> Vec<&str> {
    let n = log.model.dof();
    (0..n)
        .filter(|&j| log.segments.iter().all(|s| (0..s.len()).all(|i| s.tau[i * n + j] == 0.0)))
        .map(|j| log.model.joints()[j].name.as_str())
        .collect()
}

/// [`identify_logs`] of logs already read (and perhaps changed: a family's variants degraded as a bag is).
pub fn identify_read(logs: Vec<Log>, options: &Options) -> Result<(Identification, Vec<Log>), CalibrateError> {
    if logs.is_empty() {
        return Err(CalibrateError::NoLogs);
    }
    let still = still_joints(&logs);
    if !still.is_empty() {
        let names: Vec<&String> = still.keys().collect();
        return Err(CalibrateError::StillJoints {
            joints: names.iter().map(|n| format!("'{n}'")).collect::<Vec<_>>().join(", "),
            ranges: still.values().map(|r| format!("{r:.1e}")).collect::<Vec<_>>().join(", "),
            fix: names.iter().map(|n| n.as_str()).collect::<Vec<_>>().join(" --fix "),
        });
    }
    if let Some((log, joints)) = logs.iter().map(|l| (l, silent_joints(l))).find(|(_, j)| !j.is_empty()) {
        return Err(CalibrateError::NoEffort { file: log.name(), joints: joints.join(", ") });
    }
    let fail = |source| CalibrateError::Identify { file: logs[0].name(), source };
    let nyquist = 0.5 / logs[0].dt;
    if let Some(cutoff) = options.conditioning.cutoff.filter(|&c| c >= nyquist) {
        return Err(CalibrateError::Cutoff { file: logs[0].name(), cutoff, nyquist });
    }
    let model = logs[0].model.clone();
    let (sums, velocity) = sum_rows(&logs, &options.conditioning).map_err(fail)?;
    check_effort_scale(&sums.equations(EffortConvention::Sampled), &model)?;
    let (convention, effort_reason) = choose_convention(&sums, options.conditioning.effort).map_err(fail)?;
    let ne = sums.equations(convention);
    let mut id = fit(&model, &ne, &logs, &velocity, convention, options).map_err(fail)?;
    id.velocity = velocity;
    id.effort_reason = effort_reason;
    id.notes.extend(logs.iter().flat_map(|l| l.notes.iter().map(|n| format!("{}: {n}", l.name()))));
    id.warnings = model_errors(&id);
    let share = match options.run_to_run {
        RunToRun::Share(share) => share,
        RunToRun::Measured => {
            let (share, said) = run_to_run_of(&logs, options);
            id.notes.push(said);
            share
        }
    };
    id.over_runs(share, logs.len());
    Ok((id, logs))
}

/// The run-to-run share of `logs`, each identified alone ([`measured_share`]), and what to say of it; with one log,
/// or if a log cannot be identified alone, [`RUN_TO_RUN`].
fn run_to_run_of(logs: &[Log], options: &Options) -> (f64, String) {
    let default =
        |why: String| (RUN_TO_RUN, format!("{why}: friction's spreads over runs take {RUN_TO_RUN} of its value"));
    if logs.len() < 2 {
        return default("one log".into());
    }
    let alone = Options { run_to_run: RunToRun::Share(0.0), ..options.clone() };
    let mut runs = Vec::with_capacity(logs.len());
    for log in logs {
        match identify_read(vec![log.clone()], &alone) {
            Ok((id, _)) => runs.push(id),
            Err(e) => return default(format!("{} cannot be identified alone ({e})", log.name())),
        }
    }
    match measured_share(&runs) {
        Some(share) => (
            share,
            format!(
                "friction moves by {:.1} % of its value between the {} logs (each identified alone, beyond its own \
                 spreads): its spreads over runs take that",
                100.0 * share,
                logs.len()
            ),
        ),
        None => default("no friction to measure".into()),
    }
}

/// The rows of every segment of `logs`, conditioned, summed; with the velocity decided (from the first log, the
/// cut-off over all).
fn sum_rows(logs: &[Log], conditioning: &Conditioning) -> Result<(RowSums, VelocityChoice), IdentifyError> {
    let first = &logs[0];
    let all: Vec<&JointTrajectory> = logs.iter().flat_map(|l| &l.segments).collect();
    let (source, cutoff, reason) = choose_signals(&all, first.dt, first.velocity_logged, conditioning);
    let pieces: Vec<(&JointTrajectory, std::ops::Range<usize>)> = logs
        .iter()
        .flat_map(|l| &l.segments)
        .flat_map(|s| (0..s.len()).step_by(PIECE).map(move |a| (s, a..(a + PIECE).min(s.len()))))
        .collect();
    let pad = settling(source, cutoff, first.dt);
    let step = row_step(source, cutoff, first.dt);
    let parts = dynforge_proto::parallel::map_in_order(&pieces, |(seg, range)| {
        let (c, rows, lo) = condition_piece(seg, range, source, cutoff, pad);
        let mut sums = RowSums::new(first.model.dof());
        sums.add(&first.model, &c, rows, (step, lo)).map(|()| sums)
    });
    let mut sums = RowSums::new(first.model.dof());
    for part in parts {
        sums.merge(&part?);
    }
    Ok((sums, VelocityChoice { source, cutoff, step, reason }))
}

/// Samples of a segment conditioned and summed as one piece, on one core: fixed, so the sums (and their rounding)
/// do not depend on the number of cores; each piece is conditioned with [`settling`] samples more on either side.
const PIECE: usize = 1 << 15;

/// The samples `range` of `seg` conditioned with `pad` samples more on either side (where the segment has them):
/// the conditioned stretch, `range` within it, and the stretch's first sample in `seg`.
fn condition_piece(
    seg: &JointTrajectory,
    range: &std::ops::Range<usize>,
    source: VelocitySource,
    cutoff: Option<f64>,
    pad: usize,
) -> (Conditioned, std::ops::Range<usize>, usize) {
    let (lo, hi) = (range.start.saturating_sub(pad), (range.end + pad).min(seg.len()));
    let c = condition(&seg.slice(lo..hi), source, cutoff.unwrap_or(f64::MAX));
    (c, range.start - lo..range.end - lo, lo)
}

/// Samples the low-pass filter needs to settle (four time constants of the cut-off) before a piece's rows are
/// taken as the whole segment's filtering would give them (to ~1e-7 of the signal).
fn settling(source: VelocitySource, cutoff: Option<f64>, dt: f64) -> usize {
    match (source, cutoff) {
        (_, Some(fc)) => (4.0 / (fc * dt)).ceil() as usize,
        _ => 1,
    }
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

/// The joints' residuals of the robot `calibrated` over the logs ([`ResidualStats`]): over all of their samples up to
/// [`NOISE_SAMPLES`], else over [`NOISE_BLOCKS`] blocks spread evenly through them (a noise level and a correlation
/// time are told as well by ten minutes of samples as by hours, at a fraction of the cost).
fn residual_noise(
    calibrated: (&Model, &[Drive]),
    logs: &[Log],
    velocity: &VelocityChoice,
    convention: EffortConvention,
) -> Vec<ResidualStats> {
    let n = calibrated.0.dof();
    let pad = settling(velocity.source, velocity.cutoff, logs[0].dt);
    let blocks = noise_blocks(logs);
    let series: Vec<Vec<Vec<Option<Residual>>>> = dynforge_proto::parallel::map_in_order(&blocks, |(seg, range)| {
        let (c, rows, _) = condition_piece(seg, range, velocity.source, velocity.cutoff, pad);
        residuals(calibrated, &c, rows, convention)
    });
    dynforge_proto::parallel::map_in_order(&(0..n).collect::<Vec<_>>(), |&j| {
        let blocks: Vec<&[Option<Residual>]> = series.iter().map(|b| b[j].as_slice()).collect();
        ResidualStats { of_velocity: velocity_share(&blocks), ..correlation(&blocks, velocity.step) }
    })
}

/// What a joint's residual shows: its standard deviation (the torque noise, with whatever the model leaves),
/// integrated autocorrelation times (`time` over every sample, `time_of_rows` over every `step`-th: what the rows
/// summed see), and the share of its variance that is a function of the joint's own velocity ([`velocity_share`]).
#[derive(Debug, Clone, Copy, Default)]
struct ResidualStats {
    std: f64,
    time: f64,
    time_of_rows: f64,
    of_velocity: f64,
}

/// Standard deviation and integrated autocorrelation times of a residual given in blocks (a `None` is a row left
/// out), of every sample and of every `step`-th. Lags are summed until Sokal's window closes (the lag passes five
/// times the running time), so a residual correlated over `t` samples costs `~5 t` passes.
fn correlation(blocks: &[&[Option<Residual>]], step: usize) -> ResidualStats {
    let lag = |k: usize| {
        let (mut sum, mut count) = (0.0, 0usize);
        for b in blocks {
            for (e, f) in b.iter().zip(b.iter().skip(k)) {
                if let (Some(e), Some(f)) = (e, f) {
                    sum += e.torque * f.torque;
                    count += 1;
                }
            }
        }
        (count > 0).then(|| sum / count as f64)
    };
    let c0 = lag(0).unwrap_or(0.0);
    if c0 <= 0.0 {
        return ResidualStats { std: 0.0, time: 1.0, time_of_rows: 1.0, of_velocity: 0.0 };
    }
    let (mut t, mut rows) = (1.0, 1.0);
    for k in 1..=MAX_LAG {
        let Some(ck) = lag(k) else { break };
        t += 2.0 * ck / c0;
        if k % step.max(1) == 0 {
            rows += 2.0 * ck / c0;
        }
        if k as f64 >= 5.0 * t {
            break;
        }
    }
    ResidualStats { std: c0.sqrt(), time: t.max(1.0), time_of_rows: rows.max(1.0), of_velocity: 0.0 }
}

/// The share of a residual's variance that is a function of the joint's velocity: the correlation ratio (eta
/// squared) over bins of equal count of the signed velocity. What a friction law the model lacks leaves (a Stribeck
/// rise at low speed, a viscous force not proportional to speed) is such a function and scores near 1; what a
/// kinematic error, a misaligned log or white noise leaves depends on the rest of the motion and scores near 0
/// (white noise: `(bins - 1) / (rows - 1)`, under 0.01 from ten seconds of log).
fn velocity_share(blocks: &[&[Option<Residual>]]) -> f64 {
    let mut rows: Vec<Residual> = blocks.iter().flat_map(|b| b.iter().flatten().copied()).collect();
    let bins = (rows.len() / VELOCITY_BIN_ROWS).min(VELOCITY_BINS);
    if bins < 2 {
        return 0.0;
    }
    rows.sort_by(|a, b| a.velocity.total_cmp(&b.velocity));
    let mean = rows.iter().map(|r| r.torque).sum::<f64>() / rows.len() as f64;
    let total: f64 = rows.iter().map(|r| (r.torque - mean).powi(2)).sum();
    if total <= 0.0 {
        return 0.0;
    }
    let between: f64 = (0..bins)
        .map(|b| {
            let bin = &rows[b * rows.len() / bins..(b + 1) * rows.len() / bins];
            let m = bin.iter().map(|r| r.torque).sum::<f64>() / bin.len() as f64;
            bin.len() as f64 * (m - mean).powi(2)
        })
        .sum();
    between / total
}

/// Bins of [`velocity_share`], and the fewest rows per bin (fewer rows, fewer bins): enough bins to follow a
/// Stribeck rise a few percent of the speed range wide, enough rows that a bin's mean is not its noise.
const VELOCITY_BINS: usize = 64;
const VELOCITY_BIN_ROWS: usize = 50;

/// Samples of the logs the noise is measured on when they hold more (~9 min at 1 kHz), and the blocks they are
/// taken in.
const NOISE_SAMPLES: usize = 1 << 19;
const NOISE_BLOCKS: usize = 32;

/// The stretches of the logs' segments the noise is measured on: every segment whole when they hold at most
/// [`NOISE_SAMPLES`], else [`NOISE_BLOCKS`] blocks centred at evenly spaced points of their concatenation.
fn noise_blocks(logs: &[Log]) -> Vec<(&JointTrajectory, std::ops::Range<usize>)> {
    let segments: Vec<&JointTrajectory> = logs.iter().flat_map(|l| &l.segments).collect();
    let total: usize = segments.iter().map(|s| s.len()).sum();
    if total <= NOISE_SAMPLES {
        return segments.into_iter().map(|s| (s, 0..s.len())).collect();
    }
    let block = NOISE_SAMPLES / NOISE_BLOCKS;
    let mut out = Vec::new();
    for b in 0..NOISE_BLOCKS {
        let mut at = (2 * b + 1) * total / (2 * NOISE_BLOCKS);
        for s in &segments {
            if at < s.len() {
                let start = at.saturating_sub(block / 2).min(s.len().saturating_sub(block));
                out.push((*s, start..(start + block).min(s.len())));
                break;
            }
            at -= s.len();
        }
    }
    out
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
    // MIN_ROWS counts samples, as `dynforge info` does: rows taken every `step` samples stand for `step` each.
    let step = velocity.step.max(1);
    if let Some(j) = (0..n).find(|&j| ne.joint(j).3 * step < MIN_ROWS) {
        return Err(IdentifyError::TooFewRows { joint: model.joints()[j].name.clone(), rows: ne.joint(j).3 * step });
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
    let mut measured = vec![ResidualStats::default(); n];
    for _ in 0..2 {
        let pi = coordinates::parameters(n, &solution.x);
        let calibrated = model_with(model, &pi)?;
        measured = residual_noise((&calibrated, &drives(n, &pi)), logs, velocity, convention);
        weights = (0..n).map(|j| weight(j, measured[j].std.powi(2), measured[j].time_of_rows)).collect();
        solution = consistent::solve(ne, &weights, &prior, &solution.x)?;
    }
    let optima = consistent::optima(ne, &weights, &prior, solution)?;
    let mut solution = optima.best;
    let laplace = &solution.covariance + &optima.between;
    // The sandwich sees the residual as it is; a joint whose residual is under the noise floor is taken at the floor,
    // as its weight is (its scores scaled up): an exact simulation's residual is a model's error, not noise.
    let at_floor: Vec<f64> =
        (0..n).map(|j| weights[j] * (floor(j) / measured[j].std.max(f64::MIN_POSITIVE)).max(1.0)).collect();
    solution.covariance =
        sandwich(&solution, ne, &at_floor, &prior, (model, logs), (velocity, convention), &measured)? + &optima.between;
    let pi = coordinates::parameters(n, &solution.x);
    let calibrated = model_with(model, &pi)?;
    let noise = measured.iter().map(|m| m.std).collect();
    let correlation = measured.iter().map(|m| m.time).collect();
    let velocity_share = measured.iter().map(|m| m.of_velocity).collect();
    let mut id = Identification::new(report::Fitted {
        model,
        calibrated,
        ne,
        ls: &ls,
        prior: &prior,
        solution: &solution,
        laplace: &laplace,
        noise,
        correlation,
        velocity_share,
        convention,
        logs,
        noise_gain: noise_gain(velocity.source, velocity.cutoff, convention, logs[0].dt),
    });
    if !optima.gaps.is_empty() {
        let gaps: Vec<String> = optima.gaps.iter().map(|g| format!("{g:.2}")).collect();
        id.notes.push(format!(
            "the torques leave {} optima within {} of the objective (the others {} above the MAP's): the spreads \
             include the distance to them, weighted by their share of the posterior (exp(-gap))",
            optima.gaps.len() + 1,
            consistent::NEGLIGIBLE_GAP,
            gaps.join(", ")
        ));
    }
    Ok(id)
}

/// Blocks of the sandwich's scores, in correlation times of the slowest joint's residual: long enough that blocks
/// are nearly independent (Newey and West's bandwidth), short enough that minutes of log give hundreds of them.
const SANDWICH_BLOCK: f64 = 10.0;

/// The sandwich covariance of the MAP `solution`: `H^-1 (J^T M J + P) H^-1`, `M` the sum of the outer products of
/// the scores (each joint's rows weighted by `scored`) of blocks of [`SANDWICH_BLOCK`] correlation times, measured
/// on the noise's stretches of the logs and scaled to all rows. The Laplace covariance `H^-1` alone takes every
/// column to see the residual's whole variance times its correlation time; a slow column (friction's) sees far less
/// of a residual coloured near the filter's cut-off, a fast one (an inertia's) all of it.
fn sandwich(
    solution: &consistent::Solution,
    ne: &NormalEquations,
    scored: &[f64],
    prior: &CoordinatePrior,
    (model, logs): (&Model, &[Log]),
    (velocity, convention): (&VelocityChoice, EffortConvention),
    measured: &[ResidualStats],
) -> Result<DMatrix<f64>, IdentifyError> {
    let n = model.dof();
    let pi = DVector::from_vec(coordinates::parameters(n, &solution.x));
    let slowest = measured.iter().map(|m| m.time).fold(1.0f64, f64::max);
    let stretches = noise_blocks(logs);
    let block = ((SANDWICH_BLOCK * slowest).ceil() as usize).max(100);
    let pad = settling(velocity.source, velocity.cutoff, logs[0].dt);
    let parts = dynforge_proto::parallel::map_in_order(&stretches, |(seg, range)| {
        let (c, rows, lo) = condition_piece(seg, range, velocity.source, velocity.cutoff, pad);
        crate::rows::scores(model, &c, rows, (velocity.step, lo), convention, (&pi, scored), block)
    });
    let p = pi.len();
    let (mut meat, mut used) = (DMatrix::zeros(p, p), 0usize);
    for (blocks, rows) in &parts {
        used += rows;
        for g in blocks {
            meat += g * g.transpose();
        }
    }
    if used == 0 {
        return Ok(solution.covariance.clone());
    }
    meat *= ne.rows() as f64 / used as f64;
    let jac = coordinates::jacobian(n, &solution.x);
    let precision = prior.precision();
    let c = &solution.covariance;
    Ok(c * (jac.transpose() * meat * &jac + precision) * c)
}

/// Residual sum of squares of `pi` on joint `j` of `ne`.
fn ne_joint_rss(ne: &NormalEquations, j: usize, pi: &[f64]) -> f64 {
    let (a, b, c, _) = ne.joint(j);
    let p = ne.padded(pi);
    (p.dot(&(a * &p)) - 2.0 * b.dot(&p) + c).max(0.0)
}

/// `model` with the dynamic parameters `pi` (physical by construction: the consistent search's; drive terms after
/// them, which a URDF cannot hold, are left out).
fn model_with(model: &Model, pi: &[f64]) -> Result<Model, IdentifyError> {
    with_identified(model, pi).map_err(|e| IdentifyError::NotPhysical(e.to_string()))
}

/// An error when a joint's residual is far above its noise floor (a model that does not explain the log).
/// Partial correlation between a joint's effort and the URDF's torque (each with the joint's Coulomb and viscous
/// friction taken out) above which the URDF is taken to describe the effort, so that its scale tells the effort's
/// unit: the gravity-loaded joints of any arm (0.9 and more on the MuJoCo UR5 and Panda from nominal URDFs 30 % off).
/// A joint whose effort is friction and noise mostly shows far less, and its scale says nothing.
pub const MIN_CORRELATION: f64 = 0.8;

/// Typical scales of the effort over the URDF's torque (the median over the joints it describes) accepted as
/// torque: a URDF 50 % off stays within, and so does one that lacks the motors' rotor inertia, which a few joints
/// show as a scale of 1.5 (a UR10e's base) to 4.5 (its wrist 2) but the gravity-loaded ones do not; a current in A
/// against gears of 5-100 N m / A does not.
pub const EFFORT_SCALE: (f64, f64) = (1.0 / 3.0, 3.0);

/// An error unless the logged effort is in the URDF's joint torques: over the joints whose effort the URDF's torque
/// describes (partial correlation [`MIN_CORRELATION`] or more), the scale of the one onto the other is positive on
/// every one (a flipped sign is not) and within [`EFFORT_SCALE`] on the median (currents, or another unit, are not:
/// a unit scales every joint alike, where a missing rotor inertia scales a few). Judged on `ne` (the
/// logs' normal equations) with the URDF's rigid-body parameters, each joint's effort regressed on its URDF torque,
/// its Coulomb column, its viscous column and its offset's together (the URDF's friction, usually none, is what is
/// unknown most, and a sensor's bias is not the URDF's to know): the scale and the partial correlation are the URDF
/// torque's, those columns taken out of both sides (Frisch-Waugh). The rotor inertia is not taken out: it is part of
/// the scale on a joint whose torque is mostly inertial, as the tolerance allows.
fn check_effort_scale(ne: &NormalEquations, model: &Model) -> Result<(), CalibrateError> {
    let n = model.dof();
    let mut rigid = dynamic_parameters(model);
    for j in 0..n {
        let at = friction_index(n, j);
        rigid[at..at + 2].fill(0.0);
    }
    let pi = ne.padded(&rigid);
    let mut all = Vec::new();
    let (mut scales, mut suggested) = (Vec::new(), Vec::new());
    for (j, joint) in model.joints().iter().enumerate() {
        let (a, b, c, _) = ne.joint(j);
        let nuisance = [friction_index(n, j), friction_index(n, j) + 1, drive_index(n, j) + 1];
        // Gram entries of (effort, URDF torque) with the nuisance columns, and the nuisance columns' own.
        let api = a * &pi;
        let (uu, tu) = (pi.dot(&api), b.dot(&pi));
        let ff = nalgebra::Matrix3::from_fn(|r, k| a[(nuisance[r], nuisance[k])]);
        let (uf, tf) =
            (nalgebra::Vector3::from_fn(|r, _| api[nuisance[r]]), nalgebra::Vector3::from_fn(|r, _| b[nuisance[r]]));
        let inverse = ff.pseudo_inverse(1e-12 * ff.amax()).unwrap_or_else(|_| nalgebra::Matrix3::zeros());
        let (uu, tu, tt) = (uu - uf.dot(&(inverse * uf)), tu - tf.dot(&(inverse * uf)), c - tf.dot(&(inverse * tf)));
        if uu <= 1e-12 * pi.dot(&api).max(f64::MIN_POSITIVE) || tt <= 0.0 {
            all.push(format!("'{}' -", joint.name));
            suggested.push("?".into());
            continue;
        }
        let (scale, correlation) = (tu / uu, tu / (tt * uu).sqrt());
        all.push(format!("'{}' {scale:.3} (correlation {correlation:.2})", joint.name));
        let described = correlation.abs() >= MIN_CORRELATION;
        if described {
            scales.push((joint.name.as_str(), scale));
        }
        suggested.push(match described {
            true => format!("{:.3}", 1.0 / scale),
            false => "?".into(),
        });
    }
    let flipped: Vec<String> =
        scales.iter().filter(|(_, s)| *s < 0.0).map(|(name, s)| format!("joint '{name}' {s:.3}")).collect();
    let mut magnitudes: Vec<f64> = scales.iter().map(|(_, s)| s.abs()).collect();
    let typical = dynforge_recording::samples::median(&mut magnitudes);
    let wrong = match typical {
        _ if !flipped.is_empty() => flipped,
        Some(m) if !(EFFORT_SCALE.0..=EFFORT_SCALE.1).contains(&m) => {
            scales.iter().map(|(name, s)| format!("joint '{name}' {s:.3}")).collect()
        }
        _ => return Ok(()),
    };
    Err(CalibrateError::EffortScale { joints: wrong.join(", "), suggested: suggested.join(","), all: all.join(", ") })
}

/// A warning for each joint whose residual is a model's error rather than noise (over [`EXPLAINED_NRMSE`] of its
/// torque's spread and [`UNEXPLAINED_RATIO`] times its noise floor), saying how much is left and what it looks like.
/// A real arm is calibrated whatever it leaves: every model of this class leaves 10-15 % of some real joints'
/// torque, least squares and the makers' identified models included, and what is clearly wrong (units, signs, a
/// URDF whose torques do not have the effort's shape) is refused before the fit ([`check_effort_scale`]).
fn model_errors(id: &Identification) -> Vec<String> {
    let mut notes = Vec::new();
    for joint in &id.joints {
        let (residual, noise) = (joint.nrmse, joint.noise_floor);
        if residual <= EXPLAINED_NRMSE || residual <= UNEXPLAINED_RATIO * noise {
            continue;
        }
        let share = joint.velocity_share;
        let what = if share >= FRICTION_SHARE {
            "friction the Coulomb, viscous and offset terms do not hold (a Stribeck rise at low speed, a viscous \
             force not proportional to speed)"
        } else {
            "an error that depends on the rest of the motion: check the URDF's kinematics about this joint (axes, \
             link lengths) and that the log's torques are aligned in time with its positions"
        };
        notes.push(format!(
            "joint '{}' leaves {residual:.3} of its torque's spread unexplained, {:.0}x its noise; {:.0} % of that is \
             a function of its velocity: {what}. Its spreads include it",
            joint.name,
            residual / noise.max(f64::MIN_POSITIVE),
            100.0 * share,
        ));
    }
    notes
}

/// Share of a joint's unexplained residual that is a function of its velocity above which it is called friction:
/// a Stribeck rise scores 0.6-0.9 on the MuJoCo UR5, a wrong elbow axis under 0.1.
pub const FRICTION_SHARE: f64 = 0.5;

/// The normal equations of logs held out of a calibration: the same robot and effort convention as `id`'s, each
/// log's velocity conditioned as its own data ask (a clean held-out log is read as it is), whatever the calibration
/// was told (`--velocity`, `--cutoff`): what the held-out torque error of any parameter set is computed from, one
/// measure for every way of calibrating.
pub fn held_out(
    paths: &[PathBuf],
    document: Option<(&str, &str)>,
    options: &Options,
    id: &Identification,
) -> Result<NormalEquations, CalibrateError> {
    let logs = read_logs(paths, document, &options.reading)?;
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
        let (velocity, _) = sum_rows(std::slice::from_ref(log), &Conditioning::default())
            .map_err(|source| CalibrateError::Identify { file: log.name(), source })?;
        sums.merge(&velocity);
    }
    Ok(sums.equations(id.effort))
}

/// The nominal parameters of `model`, for comparisons.
pub fn nominal(model: &Model) -> Vec<f64> {
    dynamic_parameters(model)
}
