//! Which commands can take a log, and why not: what `dynforge info` says beside the log's summary, found by reading
//! the log the way each command does (so what it says is what the command will do).

use std::path::PathBuf;

use dynforge_proto::shard::JobRecord;
use dynforge_recording::Reading;
use dynforge_recording::log::{Log, log_of};
use dynforge_recording::recording_of;
use dynforge_shard::Bag;

use super::MIN_ROWS;
use crate::signals::{Conditioning, VelocitySource, choose_signals};

/// Rates the identification is tested at [Hz]: a log outside them is read, with a caution.
pub const TESTED_RATES: (f64, f64) = (100.0, 1000.0);

/// What `identify` and `estimate` make of a log: what they would read, or why they cannot.
#[derive(Debug, Clone, PartialEq)]
pub struct Readiness {
    pub identify: Result<String, Refusal>,
    pub estimate: Result<String, Refusal>,
}

/// Why a command cannot take a log, as the command would say it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct Refusal(String);

impl Refusal {
    fn of(e: impl std::fmt::Display) -> Self {
        Refusal(e.to_string())
    }
}

impl Readiness {
    /// What each command would make of the log whose `files` hold the messages `bag` (read once by the caller),
    /// for the robot of the URDF `document` (text, source) when given, else of the log's `/robot_description`
    /// (`described`: whether it has a readable one; without either, both need the robot's URDF, and what they would
    /// read depends on it).
    pub fn of(files: Vec<PathBuf>, bag: Bag, described: bool, document: Option<(&str, &str)>) -> Readiness {
        if !described && document.is_none() {
            let why = Refusal::of("the log has no readable /robot_description: give the robot's URDF with --urdf");
            return Readiness { identify: Err(why.clone()), estimate: Err(why) };
        }
        let model = document.map(|(text, source)| dynforge_robot::urdf::parse(text, source));
        let estimate = match model {
            Some(Err(e)) => Err(Refusal::of(e)),
            Some(Ok(model)) => estimate(&files, &bag, Some(&model)),
            None => estimate(&files, &bag, None),
        };
        let identify = log_of(files, bag, document, &Reading::default()).map_err(Refusal::of).and_then(identify);
        Readiness { identify, estimate }
    }
}

fn identify(log: Log) -> Result<String, Refusal> {
    let logs = [log];
    // Joints that move too little (a gripper's, held still) identify welds, as it says.
    let idle = super::idle_joints(&logs);
    let log = &logs[0];
    let n = log.model.dof();
    if idle.len() == n {
        return Err(Refusal::of("no joint moves in the log: nothing to calibrate from"));
    }
    let silent: Vec<&str> = super::silent_joints(log).into_iter().filter(|name| !idle.contains_key(*name)).collect();
    if !silent.is_empty() {
        let why = format!("the effort of {} is zero throughout: no torques to calibrate from", silent.join(", "));
        return Err(Refusal(why));
    }
    let rate = 1.0 / log.dt;
    let segments: Vec<&dynforge_recording::JointTrajectory> = log.segments.iter().collect();
    let velocity = match choose_signals(&segments, log.dt, log.velocity_logged, &Conditioning::default()) {
        (VelocitySource::Logged, None, why) => format!("velocity as logged ({why})"),
        (VelocitySource::Logged, Some(fc), why) => format!("velocity as logged, low-passed at {fc:.1} Hz ({why})"),
        (VelocitySource::Positions, _, why) => format!("velocity from the positions ({why})"),
    };
    let mut said = format!(
        "{} joints, {} samples in {} stretch(es) at {rate:.1} Hz; {velocity}",
        n - idle.len(),
        log.samples(),
        log.segments.len()
    );
    if !idle.is_empty() {
        let names: Vec<&str> = idle.keys().map(String::as_str).collect();
        said += &format!("; {} move too little (under {MIN_ROWS} moving samples): welded", names.join(", "));
    }
    if !(0.95 * TESTED_RATES.0..=1.05 * TESTED_RATES.1).contains(&rate) {
        said += &format!(" (a rate outside the {:.0} Hz-{:.0} kHz tested)", TESTED_RATES.0, TESTED_RATES.1 / 1e3);
    }
    for note in &log.notes {
        said += &format!("; {note}");
    }
    Ok(said)
}

fn estimate(files: &[PathBuf], bag: &Bag, model: Option<&dynforge_robot::Model>) -> Result<String, Refusal> {
    let job = bag.metadata.get(dynforge_proto::shard::META_JOB);
    if job.is_some_and(JobRecord::is_family) {
        return Err(Refusal::of(
            "a shard of a robot's family (`generate --urdf`), labelled with its standard parameters: the estimators \
             learn the generator's robots; `identify` calibrates it",
        ));
    }
    let rec = recording_of(&files[0], bag, model).map_err(Refusal::of)?;
    Ok(format!(
        "a {}-joint robot, {:.1} s of motion: with a model trained on its family (dynforge estimate --checkpoint RUN)",
        rec.model.dof(),
        rec.trajectory.t.last().copied().unwrap_or(0.0)
    ))
}

impl std::fmt::Display for Readiness {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "Usable by:")?;
        for (command, verdict) in [("identify", &self.identify), ("estimate", &self.estimate)] {
            match verdict {
                Ok(what) => writeln!(f, "  {command}: yes: {what}")?,
                Err(why) => writeln!(f, "  {command}: no: {why}")?,
            }
        }
        Ok(())
    }
}
