//! Physics beside the network, scored the way a user with several logs of one robot would work: each validation
//! robot is identified from the first half of its trajectories, and every estimate then predicts the torques of the
//! other half.
//!
//! Estimates compared: the network alone (its windows' predictions averaged); classical least squares on the
//! regressor (base parameters: torques only, no labels); physics with the training distribution as prior (labels by
//! `dynforge_identify::refine` from the training mean and spread: what the torques alone say about each label); and
//! the hybrid, the network's estimate refined by the same physics with the network's own per-robot error as prior.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dynforge_identify::{NormalEquations, Prior, TorqueError, least_squares, refine};
use dynforge_proto::NUM_LABELS;
use dynforge_recording::dataset::shards_by_robot;
use dynforge_recording::{Recording, read};
use dynforge_robot::parameters::dynamic_parameters;
use serde::{Deserialize, Serialize};

use crate::recording::{normal_equations, physical_parameters, recording_error};
use crate::tables::group_r2;
use crate::torque::{TorqueRow, table};
use crate::{Estimator, EvaluationError};
use dynforge_dataset::metrics::{Scores, score};
use dynforge_proto::parallel::map_in_order;

/// What the identification check reports.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct IdentificationCheck {
    pub robots: usize,
    /// Recordings identified from and predicted, over all robots.
    pub fit_recordings: usize,
    pub held_out_recordings: usize,
    /// Identifiable parameter combinations (median over robots) of the full parameter vector's `params`.
    pub rank: usize,
    pub params: usize,
    /// Per-robot label scores of the network, of physics with the training prior, and of the hybrid.
    pub network: Scores,
    pub physics: Scores,
    pub hybrid: Scores,
    /// Held-out torque NRMSE of every estimate, the true and the training-mean parameters.
    pub torque: Vec<TorqueRow>,
}

impl IdentificationCheck {
    pub fn markdown(&self) -> String {
        let mut out = format!(
            "\n**Identification** ({} validation robots, identified from {} recordings, torques predicted on {} held-out \
             ones; {} of {} parameter combinations identifiable, median)\n\n",
            self.robots, self.fit_recordings, self.held_out_recordings, self.rank, self.params
        );
        let groups = group_r2(&self.network);
        out.push_str(&format!(
            "| labels per robot | R2 | RMSE |{}\n|---|---:|---:|{}\n",
            groups.iter().map(|(g, _)| format!(" {g} R2 |")).collect::<String>(),
            "---:|".repeat(groups.len())
        ));
        for (name, s) in [
            ("network", &self.network),
            ("physics, training prior", &self.physics),
            ("hybrid: network refined by physics", &self.hybrid),
        ] {
            out.push_str(&format!(
                "| {name} | {:.4} | {:.4} |{}\n",
                s.r2,
                s.rmse,
                group_r2(s).iter().map(|(_, r)| format!(" {r:.4} |")).collect::<String>()
            ));
        }
        out.push_str("\nHeld-out torque NRMSE:\n\n");
        out.push_str(&table(&self.torque));
        out
    }
}

/// One robot's estimates and its held-out recordings' sums.
struct RobotResult {
    truth: [f64; NUM_LABELS],
    network: [f64; NUM_LABELS],
    physics: [f64; NUM_LABELS],
    hybrid: [f64; NUM_LABELS],
    rank: usize,
    fit: usize,
    held_out: NormalEquations,
    held: usize,
    /// Parameter vectors in the order of `ROWS`.
    params: Vec<Vec<f64>>,
}

/// Other validation robots needed to measure the network's error per label.
const MIN_OTHER_ROBOTS: usize = 8;

const ROWS: [&str; 6] =
    ["true", "training mean", "network", "least squares (base parameters)", "physics, training prior", "hybrid"];

/// Runs the check on up to `max_robots` validation robots of `data` that have at least two readable recordings
/// long enough for a window. `training` is the training robots' label distribution (the physics prior);
/// `errors` holds the network's per-robot estimate minus truth for validation robots: the hybrid's prior spread for
/// a robot is their RMS over the other robots, so no robot informs its own prior.
pub(crate) fn check(
    estimator: &impl Estimator,
    data: &Path,
    max_robots: usize,
    training: &Prior,
    errors: &BTreeMap<u64, [f64; NUM_LABELS]>,
    progress: &mut impl FnMut(&str, usize, usize),
) -> Result<Option<IdentificationCheck>, EvaluationError> {
    let by_robot = shards_by_robot(data).unwrap_or_default();
    let (ids, robots): (Vec<u64>, Vec<Vec<PathBuf>>) =
        by_robot.into_iter().filter(|(r, v)| estimator.holds_out_robot(*r) && v.len() >= 2).take(max_robots).unzip();
    let (_, label_std) = estimator.label_statistics();
    // The hybrid's prior spread for robot r: the network's RMS error over every other validation robot (leave one
    // out), or the training spread when too few others are known.
    let network_std = |r: u64| -> [f64; NUM_LABELS] {
        let others: Vec<&[f64; NUM_LABELS]> = errors.iter().filter(|(o, _)| **o != r).map(|(_, e)| e).collect();
        std::array::from_fn(|k| {
            let rms = (others.iter().map(|e| e[k] * e[k]).sum::<f64>() / others.len().max(1) as f64).sqrt();
            if others.len() >= MIN_OTHER_ROBOTS { rms.max(1e-6 * label_std[k]) } else { training.std()[k] }
        })
    };
    let robots: Vec<(u64, Vec<PathBuf>)> = ids.into_iter().zip(robots).collect();
    let chunk = 2 * std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut results = Vec::new();
    for (k, group) in robots.chunks(chunk).enumerate() {
        progress("identification", k * chunk, robots.len());
        let done = map_in_order(group, |(r, paths)| one_robot(estimator, paths, training, &network_std(*r)));
        for r in done {
            results.extend(r?);
        }
    }
    progress("identification", robots.len(), robots.len());
    if results.is_empty() {
        return Ok(None);
    }
    let truth: Vec<_> = results.iter().map(|r| r.truth).collect();
    let scores = |f: fn(&RobotResult) -> [f64; NUM_LABELS]| {
        score(&results.iter().map(f).collect::<Vec<_>>(), &truth, &label_std)
    };
    let mut errors = vec![TorqueError::default(); ROWS.len()];
    for r in &results {
        for (e, pi) in errors.iter_mut().zip(&r.params) {
            e.add(&r.held_out, pi);
        }
    }
    let mut ranks: Vec<usize> = results.iter().map(|r| r.rank).collect();
    ranks.sort_unstable();
    Ok(Some(IdentificationCheck {
        robots: results.len(),
        fit_recordings: results.iter().map(|r| r.fit).sum(),
        held_out_recordings: results.iter().map(|r| r.held).sum(),
        rank: ranks[ranks.len() / 2],
        params: dynforge_proto::params::num_params(results[0].held_out.dof()),
        network: scores(|r| r.network),
        physics: scores(|r| r.physics),
        hybrid: scores(|r| r.hybrid),
        torque: ROWS.iter().zip(&errors).map(|(name, e)| TorqueRow::new(name, e)).collect(),
    }))
}

/// Identifies one robot from the first half of its recordings (sorted by name, i.e. by trajectory) and scores it on
/// the rest; `None` when too few recordings are readable and long enough.
fn one_robot(
    estimator: &impl Estimator,
    paths: &[PathBuf],
    training: &Prior,
    network_std: &[f64; NUM_LABELS],
) -> Result<Option<RobotResult>, EvaluationError> {
    let preps: Vec<_> = paths.iter().filter_map(|p| read(p, None).ok()).filter(|p| p.labels.is_some()).collect();
    if preps.len() < 2 {
        return Ok(None);
    }
    let (fit, held) = preps.split_at(preps.len().div_ceil(2));
    let template = &fit[0].model;
    let truth = fit[0].labels.unwrap_or([0.0; NUM_LABELS]);
    // The estimator's estimate from the fit recordings (those long enough for a window).
    let mut fit_ne = NormalEquations::new(template.dof());
    for p in fit {
        fit_ne.merge(&normal_equations(p)?);
    }
    let long: Vec<&Recording> =
        fit.iter().filter(|p| !estimator.window_spec().windows(p.trajectory.len()).is_empty()).collect();
    if long.is_empty() || fit_ne.rows() == 0 {
        return Ok(None);
    }
    let network = estimator.estimate(&long).map_err(EvaluationError::Estimator)?;
    let mut held_out = NormalEquations::new(template.dof());
    for p in held {
        held_out.merge(&normal_equations(p)?);
    }
    let bad = |e| recording_error(&fit[0], e);
    let ls = least_squares(&fit_ne).map_err(bad)?;
    let physics = refine(&fit_ne, template, training, ls.sigma).map_err(bad)?.labels;
    let network_prior = Prior::new(network, network_std).map_err(bad)?;
    let hybrid = refine(&fit_ne, template, &network_prior, ls.sigma).map_err(bad)?.labels;
    let mut params = vec![dynamic_parameters(template)];
    for labels in [&training.mean, &network] {
        params.push(physical_parameters(&fit[0], template, labels)?.0);
    }
    let rank = ls.rank;
    params.push(ls.pi);
    for labels in [&physics, &hybrid] {
        params.push(physical_parameters(&fit[0], template, labels)?.0);
    }
    Ok(Some(RobotResult { truth, network, physics, hybrid, rank, fit: fit.len(), held: held.len(), held_out, params }))
}
