//! A robot's log as its driver wrote it, for identification: the URDF's joints matched by name, on the log's own
//! clock (its median sampling period, 100 Hz to 1 kHz), cut into segments where the stamps jump (a paused
//! recorder), and the robot as the log shows it: the URDF's joints the log does not have, the mimic joints and those
//! the caller fixes are welded at the position the log gives them (or 0), so a gripper's fingers ride on the hand.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dynforge_robot::Model;
use dynforge_robot::urdf::{self, Welds};
use dynforge_shard::Bag;

use crate::error::ReadError;
use crate::read::{Reading, read_bag};
use crate::resample::resample;
use crate::samples::{GAP_PERIODS, JointTrajectory, from_bag_any_velocity};

/// Segments shorter than this many samples are left out: too short for the differences identification takes.
pub const MIN_SEGMENT: usize = 16;

/// A log read for identification.
#[derive(Debug, Clone)]
pub struct Log {
    /// The log's files (one, or the files of a split rosbag2 directory in recording order).
    pub files: Vec<PathBuf>,
    /// The URDF document of the robot (the given file, else the log's `/robot_description`) and where it came
    /// from: identification writes its result into it.
    pub document: String,
    pub source: String,
    /// The robot as the log shows it, with its welded joints.
    pub model: Model,
    pub welds: Welds,
    /// Whether the log has velocities (otherwise the segments' are zeros).
    pub velocity_logged: bool,
    /// The sampling period [s] every segment is on.
    pub dt: f64,
    /// Uniformly sampled stretches of the log, in time order, joints in the model's order.
    pub segments: Vec<JointTrajectory>,
    /// What was done to the log that a user should know (welded joints, gaps, resampling).
    pub notes: Vec<String>,
}

impl Log {
    /// The log's URDF with `model`'s parameters (a robot of the same joints, as read with the log's welds) written
    /// in exactly: what a simulation of that robot, or a nominal drawn around it, is given.
    pub fn urdf_of(&self, model: &Model) -> Result<String, dynforge_robot::ModelError> {
        urdf::patch_welded(&self.document, &self.source, model, &self.welds, urdf::Unsplit::Exact).map(|(text, _)| text)
    }

    /// Samples over all segments.
    pub fn samples(&self) -> usize {
        self.segments.iter().map(JointTrajectory::len).sum()
    }

    /// The log's name in messages: its file, or its directory for a split bag.
    pub fn name(&self) -> String {
        match self.files.len() {
            1 => self.files[0].display().to_string(),
            _ => self.files[0].parent().unwrap_or(&self.files[0]).display().to_string(),
        }
    }
}

/// Reads the log `path` (a file or a rosbag2 directory) for identification. The robot is the URDF `document` (text,
/// source) when given, else the log's `/robot_description`; read as `how` says (the joints it fixes are welded at
/// their mean logged position).
pub fn read_log(path: &Path, document: Option<(&str, &str)>, how: &Reading) -> Result<Log, ReadError> {
    let (files, bag) = read_bag(path, how)?;
    log_of(files, bag, document, how)
}

/// [`read_log`] of a log already read: its `files` and their messages `bag` (consumed: an hour's messages take
/// gigabytes, freed before the segments are cut).
pub fn log_of(files: Vec<PathBuf>, bag: Bag, document: Option<(&str, &str)>, how: &Reading) -> Result<Log, ReadError> {
    log_welded(files, bag, document, how, None)
}

/// [`log_of`] with the welded joints at the positions `at` holds (another log's of the same robot), where it holds
/// them, instead of at their mean in this log.
fn log_welded(
    files: Vec<PathBuf>,
    bag: Bag,
    document: Option<(&str, &str)>,
    how: &Reading,
    at: Option<&Welds>,
) -> Result<Log, ReadError> {
    let fixed = &how.fixed;
    let file = files[0].display().to_string();
    let content = |problem: String| ReadError::Content { file: file.clone(), problem };
    let (document, source) = match (document, &bag.robot_description) {
        (Some((text, source)), _) => (text.to_string(), source.to_string()),
        (None, Some(text)) => (text.clone(), format!("{file} (/robot_description)")),
        (None, None) => return Err(content("no /robot_description in the file: give the robot's URDF".into())),
    };
    let Some(first) = bag.joint_states.first() else {
        return Err(content("no joint state in the file (a ROS 2 bag's /joint_states, sensor_msgs/JointState)".into()));
    };
    let logged: Vec<String> = first.name.to_vec();
    let movable = urdf::movable_joints(&document, &source).map_err(|e| content(e.to_string()))?;
    if let Some(f) = fixed.iter().find(|f| !movable.free.contains(f) && !movable.mimic.contains(f)) {
        return Err(content(format!("--fix {f}: the URDF has no moving joint '{f}'")));
    }
    // A log with joints the URDF lacks, and the URDF with moving joints the log lacks: names that do not match, not
    // a gripper left out of the arm's log.
    let unknown: Vec<&String> =
        logged.iter().filter(|l| !movable.free.contains(l) && !movable.mimic.contains(l)).collect();
    let absent: Vec<&String> = movable.free.iter().filter(|m| !logged.contains(m)).collect();
    if !unknown.is_empty() && !absent.is_empty() {
        return Err(content(format!(
            "the log's joints {unknown:?} are not in the URDF ({source}), whose joints {absent:?} are not in the log: \
             the log and the URDF must name the joints alike"
        )));
    }
    let mut notes = Vec::new();
    let mut welds = Welds::new();
    for name in movable.free.iter().chain(&movable.mimic) {
        let is_mimic = movable.mimic.contains(name);
        if !logged.contains(name) {
            welds.insert(name.clone(), 0.0);
            if !is_mimic {
                notes.push(format!("joint '{name}' is not in the log: welded at 0"));
            }
        } else if is_mimic || fixed.contains(name) {
            let (mean, range) = position_spread(&bag, name).unwrap_or((0.0, 0.0));
            if !is_mimic && range > WELD_RANGE {
                return Err(content(format!(
                    "joint '{name}' is welded (--fix, or it moves too little to identify) but moves in the log over \
                     {range:.3} (rad or m; a weld takes at most {WELD_RANGE}): its motion's torques would be put on \
                     the other joints. Weld only a joint held still, or identify it"
                )));
            }
            match at.and_then(|w| w.get(name)) {
                Some(&first) => {
                    welds.insert(name.clone(), first);
                    if (first - mean).abs() > WELD_TOLERANCE {
                        notes.push(format!(
                            "joint '{name}' welded at {first:.6} as in the first log, though its mean here is {mean:.6}"
                        ));
                    }
                }
                None => {
                    welds.insert(name.clone(), mean);
                    notes.push(format!("joint '{name}' welded at {mean:.6} (its mean in the log)"));
                }
            }
        }
    }
    let model = urdf::parse_welded(&document, &source, &welds).map_err(|e| content(e.to_string()))?;
    let names: Vec<String> = model.joints().iter().map(|j| j.name.clone()).collect();
    let (mut trajectory, velocity_logged) = from_bag_any_velocity(&bag, &names, &files[0])?;
    if let Some(gains) = &how.gains {
        apply_gains(&mut trajectory, gains).map_err(|e| content(e.to_string()))?;
    }
    let clock = trajectory.clock();
    if clock.repeats > 0 {
        notes.push(format!(
            "{} sample(s) repeat the one before exactly while the arm moves (a logger's stale copies): left out",
            clock.repeats
        ));
    }
    if clock.skipped > 0 {
        notes.push(format!(
            "{} step(s) of two or more sampling periods (ticks the logger missed): interpolated over",
            clock.skipped
        ));
    }
    // The messages take several times the memory of the samples (an hour at 1 kHz: gigabytes, millions of blocks):
    // freed on a thread of their own while the segments are cut and the work goes on (here, if no thread can be
    // started: the refused closure is dropped, and the messages with it).
    let _ = std::thread::Builder::new().name("free-messages".into()).spawn(move || drop(bag));
    let (dt, segments) = segments(trajectory, &mut notes);
    if segments.is_empty() {
        return Err(content(format!("no stretch of {MIN_SEGMENT} or more evenly stamped samples")));
    }
    Ok(Log { files, document, source, model, welds, velocity_logged, dt, segments, notes })
}

/// `--gains` that do not match the robot's moving joints.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "--gains has {given} value(s) and the robot {} moving joint(s) ({}): one gain per joint, in the URDF's order",
    joints.len(),
    joints.join(", ")
)]
struct GainsProblem {
    given: usize,
    joints: Vec<String>,
}

/// The logged efforts of `traj` times `gains` (one per joint, in order): motor currents to joint torques.
fn apply_gains(traj: &mut JointTrajectory, gains: &[f64]) -> Result<(), GainsProblem> {
    let n = traj.joints();
    if gains.len() != n {
        return Err(GainsProblem { given: gains.len(), joints: traj.names.clone() });
    }
    traj.tau.chunks_mut(n).for_each(|row| row.iter_mut().zip(gains).for_each(|(t, g)| *t *= g));
    Ok(())
}

/// How far (rad or m) a joint welded at the first log's position may sit from it in another log without a note.
const WELD_TOLERANCE: f64 = 1e-3;

/// How far (rad or m) a welded joint may move in a log: a held joint's encoder jitter and a controller's sag are
/// thousandths; a weld of a joint that moved further puts its own motion's torques on the others.
pub const WELD_RANGE: f64 = 0.05;

/// The mean position of joint `name` over the messages that have it, and its range (largest less smallest).
fn position_spread(bag: &Bag, name: &str) -> Option<(f64, f64)> {
    let values: Vec<f64> = bag
        .joint_states
        .iter()
        .filter_map(|m| m.name.iter().position(|n| n == name).and_then(|c| m.position.get(c).copied()))
        .filter(|v| v.is_finite())
        .collect();
    let (lo, hi) = values.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    (!values.is_empty()).then(|| (values.iter().sum::<f64>() / values.len() as f64, hi - lo))
}

/// The median sampling period of `traj` and its stretches between gaps, each on a uniform grid of that period
/// (resampled linearly when the stamps jitter by more than 1 %).
fn segments(mut traj: JointTrajectory, notes: &mut Vec<String>) -> (f64, Vec<JointTrajectory>) {
    let steps: Vec<f64> = traj.t.windows(2).map(|w| w[1] - w[0]).collect();
    let Some(dt) = crate::samples::median(&mut steps.clone()) else { return (0.0, Vec::new()) };
    let mut cuts: Vec<usize> = vec![0];
    cuts.extend(steps.iter().enumerate().filter(|(_, s)| **s > GAP_PERIODS * dt).map(|(i, _)| i + 1));
    cuts.push(traj.len());
    if cuts.len() > 2 {
        notes.push(format!(
            "{} gap(s) in the stamps: identified as {} separate stretches",
            cuts.len() - 2,
            cuts.len() - 1
        ));
    }
    let mut out = Vec::new();
    let mut short = 0;
    let mut resampled = 0;
    for w in cuts.windows(2) {
        // One stretch (the usual log) is the trajectory itself, not a copy of it.
        let part = if cuts.len() == 2 { std::mem::take(&mut traj) } else { traj.slice(w[0]..w[1]) };
        if part.len() < MIN_SEGMENT {
            short += part.len();
            continue;
        }
        let jitter = part.t.windows(2).any(|p| ((p[1] - p[0]) - dt).abs() > 0.01 * dt);
        if jitter {
            resampled += 1;
            out.push(resample(&part, dt));
        } else {
            // Evenly stamped: the grid is the stamps, up to their rounding to nanoseconds.
            let mut part = part;
            let t0 = part.t[0];
            part.t.iter_mut().enumerate().for_each(|(k, t)| *t = t0 + k as f64 * dt);
            out.push(part);
        }
    }
    if short > 0 {
        notes.push(format!("{short} sample(s) in stretches shorter than {MIN_SEGMENT} samples left out"));
    }
    if resampled > 0 {
        notes.push(format!("{resampled} stretch(es) with uneven stamps resampled to {:.4} ms", dt * 1e3));
    }
    (dt, out)
}

/// The logged position range of each joint over all segments: what tells a joint that never moved.
pub fn position_ranges(log: &Log) -> Vec<(f64, f64)> {
    let n = log.model.dof();
    let mut out = vec![(f64::INFINITY, f64::NEG_INFINITY); n];
    for s in &log.segments {
        for (k, v) in s.q.iter().enumerate() {
            let r = &mut out[k % n];
            *r = (r.0.min(*v), r.1.max(*v));
        }
    }
    out
}

/// The logs of one robot read together: each must show the same robot as the first (same URDF, same welds).
pub fn read_logs(paths: &[PathBuf], document: Option<(&str, &str)>, how: &Reading) -> Result<Vec<Log>, ReadError> {
    // One log given twice (an overlapping shell glob) would count its samples twice, and every spread would shrink by
    // sqrt(2) for nothing.
    let resolved: Vec<PathBuf> = paths.iter().map(|p| dynforge_proto::run_dir::resolve(p)).collect();
    for (k, path) in resolved.iter().enumerate() {
        if let Some(first) = resolved[..k].iter().position(|p| p == path) {
            return Err(ReadError::Content {
                file: paths[k].display().to_string(),
                problem: format!(
                    "given twice (also as {}): each log counts once, or its samples would weigh double",
                    paths[first].display()
                ),
            });
        }
    }
    let mut logs: Vec<Log> = Vec::with_capacity(paths.len());
    for path in paths {
        let (files, bag) = read_bag(path, how)?;
        // One robot: a joint welded in every log is welded where the first log holds it (a gripper's finger is
        // held a few micrometres apart from log to log).
        let log = log_welded(files, bag, document, how, logs.first().map(|l| &l.welds))?;
        if let Some(first) = logs.first()
            && (first.model != log.model || first.welds.keys().ne(log.welds.keys()))
        {
            return Err(ReadError::Content {
                file: log.name(),
                problem: format!(
                    "a log of another robot than {} (its /robot_description or its joints differ): identify one robot \
                     at a time, or give --urdf if they are the same robot described differently",
                    first.name()
                ),
            });
        }
        logs.push(log);
    }
    Ok(logs)
}

/// Joints that never move in any of `logs` (a range under `1e-3` rad, `1e-4` m), by name with their range.
pub fn still_joints(logs: &[Log]) -> BTreeMap<String, f64> {
    let Some(first) = logs.first() else { return BTreeMap::new() };
    let n = first.model.dof();
    let mut range = vec![(f64::INFINITY, f64::NEG_INFINITY); n];
    for log in logs {
        for (r, (lo, hi)) in range.iter_mut().zip(position_ranges(log)) {
            *r = (r.0.min(lo), r.1.max(hi));
        }
    }
    (0..n)
        .filter(|&j| range[j].1 - range[j].0 < if first.model.is_prismatic(j) { 1e-4 } else { 1e-3 })
        .map(|j| (first.model.joints()[j].name.clone(), range[j].1 - range[j].0))
        .collect()
}
