//! Physics as the estimator's input. Joint torques are linear in the robot's parameters, so a window's torques at
//! their full 1 kHz rate say exactly what they can see of the robot: the identifiable combinations, as sharply as the
//! motion excites them. This stage turns every window (and every whole recording) into that statement, as
//! [`Evidence`] about the coordinates of the generator's parameter prior (`dynforge_identify::latent`); the
//! physics estimator maps its posterior to the 38 labels, learning from the generator what the torques cannot see.
//!
//! The prior is fitted to robots drawn from the dataset's own generator configuration (its manifest), never to the
//! dataset's robots themselves, so it holds no validation robot.

use std::path::Path;

use dynforge_identify::{
    Evidence, IdentifyError, LatentSums, ParameterPrior, Posterior, labels_of_parameters, latent_blocks,
};
use dynforge_proto::NUM_LABELS;
use dynforge_proto::content_hash;
use dynforge_proto::generator::GeneratorConfig;
use dynforge_recording::dataset::generator;
use dynforge_recording::{ReadError, Recording};
use dynforge_robot::generator::generate;
use dynforge_robot::parameters::dynamic_parameters;

use crate::window::WindowSpec;

/// Each joint's torque noise, as a fraction of the RMS of its own recorded torque. With the stops left out and the
/// viscous force paired with the span's mean velocity (`identify`'s pairing revision 2), the true parameters leave
/// ~1e-7 to 3e-6 of each joint's torque spread on simulated data; 3e-5 keeps a margin above that residual, and a
/// lower floor gains no more than the +-0.01 the small validation set moves by (pipeline, 48 robots: per-window R2
/// 0.953 at 3e-5, 0.956 at 1e-5; every level in `docs/measurements.md`). One level for all joints does worse: the wrists'
/// torques are two orders of magnitude below the shoulder's. A real robot's logs carry more (sensor noise,
/// transmissions): its posterior is then overconfident, and the estimate's refinement by the log's own torques uses
/// `identify`'s 1e-3 floor.
pub const NOISE_FLOOR: f64 = 3e-5;

/// Robots drawn from the generator to fit its prior: the generated arms span 30 directions of the 72 parameters,
/// found at any sample size above 30; the spread along them converges as `1 / sqrt(N)`, ~1 % at 20,000.
pub const PRIOR_ROBOTS: u64 = 20_000;

/// Purposes of generated robots that are never simulated, each a stream apart from the dataset's robots.
#[derive(Debug, Clone, Copy)]
pub enum Draw {
    Prior = 1,
    Synthetic = 2,
}

/// The seed of robots drawn for `purpose` beside the dataset of seed `seed`.
pub fn draw_seed(seed: u64, purpose: Draw) -> u64 {
    let mut key = [0u8; 24];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    key[8..16].copy_from_slice(&(purpose as u64).to_le_bytes());
    key[16..].copy_from_slice(b"dfdraws!");
    content_hash(&key)
}

#[derive(Debug, thiserror::Error)]
pub enum EvidenceError {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("{file}: {source}")]
    Identify { file: String, source: IdentifyError },
    #[error("the generator's parameter prior: {0}")]
    Generator(String),
}

/// The parameter prior of the generator `cfg`: [`PRIOR_ROBOTS`] robots drawn beside the dataset of seed `seed`.
pub fn generator_prior(cfg: &GeneratorConfig, seed: u64) -> Result<ParameterPrior, EvidenceError> {
    let seed = draw_seed(seed, Draw::Prior);
    let ids: Vec<u64> = (0..PRIOR_ROBOTS).collect();
    let robots = dynforge_proto::parallel::map_in_order(&ids, |&id| {
        generate(cfg, seed, id).map(|r| dynamic_parameters(&r.model))
    });
    let samples =
        robots.into_iter().collect::<Result<Vec<_>, _>>().map_err(|e| EvidenceError::Generator(e.to_string()))?;
    ParameterPrior::fit(&samples).map_err(|e| EvidenceError::Generator(e.to_string()))
}

/// The generator prior of a run directory, from its manifest.
pub fn dataset_prior(dir: &Path) -> Result<ParameterPrior, EvidenceError> {
    let (cfg, seed) = generator(dir)?.ok_or_else(|| {
        EvidenceError::Generator(format!(
            "{} has no {} to take the generator configuration from (the physics estimator learns the generator's \
             prior; train on a `dynforge generate` directory, or use --model transformer)",
            dir.display(),
            dynforge_proto::run_dir::MANIFEST
        ))
    })?;
    generator_prior(&cfg, seed)
}

/// The evidence of each window of `rec` (in [`WindowSpec::windows`] order) and of the whole recording, each with
/// every joint's noise at [`NOISE_FLOOR`] of its own torques there: simulated data, whose torques the regressor
/// explains to ~1e-7.
pub fn recording_evidence(
    rec: &Recording,
    prior: &ParameterPrior,
    spec: &WindowSpec,
) -> Result<(Vec<Evidence>, Evidence), EvidenceError> {
    let m = evidence_of(rec, prior, spec, false)?;
    Ok((m.windows, m.whole))
}

/// A log's evidence weighted by its own noise.
#[derive(Debug, Clone)]
pub struct MeasuredEvidence {
    pub windows: Vec<Evidence>,
    pub whole: Evidence,
    /// Each joint's torque noise as an NRMSE: the residual the prior's parameters leave, relative to the torque's
    /// standard deviation (~1e-7 on simulated data; 0 where the joint never moved).
    pub noise: Vec<f64>,
}

/// [`recording_evidence`] for a log that may be noisier than simulated data (a real robot's): each joint's noise is
/// the larger of the floor and the residual the whole recording leaves ([`LatentSums::measured_noise`]), for the
/// windows too (too short to tell noise from signal alone). On simulated data the residual is under the floor and
/// nothing changes.
pub fn measured_evidence(
    rec: &Recording,
    prior: &ParameterPrior,
    spec: &WindowSpec,
) -> Result<MeasuredEvidence, EvidenceError> {
    evidence_of(rec, prior, spec, true)
}

fn evidence_of(
    rec: &Recording,
    prior: &ParameterPrior,
    spec: &WindowSpec,
    measure: bool,
) -> Result<MeasuredEvidence, EvidenceError> {
    let bad = |source| EvidenceError::Identify { file: rec.path.display().to_string(), source };
    let len = rec.trajectory.len();
    let block = spec.block();
    let blocks = latent_blocks(&rec.model, prior, &rec.trajectory, block).map_err(bad)?;
    let sum = |range: std::ops::Range<usize>| {
        let mut s = LatentSums::new(rec.model.dof(), prior.rank());
        for b in &blocks[range.start / block..range.end.div_ceil(block)] {
            s.merge(b);
        }
        s
    };
    let all = sum(0..len);
    let variance = match measure {
        true => all.measured_noise(NOISE_FLOOR).map_err(bad)?,
        false => vec![0.0; rec.model.dof()],
    };
    let noise = variance.iter().zip(all.torque_std()).map(|(v, std)| if std > 0.0 { v.sqrt() / std } else { 0.0 });
    let evidence = |s: LatentSums| s.evidence_with_noise(NOISE_FLOOR, &variance);
    Ok(MeasuredEvidence {
        windows: spec.windows(len).iter().map(|w| evidence(sum(spec.samples(w, len)))).collect(),
        whole: evidence(all),
        noise: noise.collect(),
    })
}

/// Values of a standardised label the plug-in estimate is clipped to: a posterior mean with a link mass near zero
/// has a meaningless centre of mass.
const CLIP: f64 = 8.0;

/// Largest posterior spread of a standardised label passed on (the prior's own spread is about 1).
const SPREAD_CLIP: f64 = 4.0;

/// Width of [`features`] for a prior of rank `r`.
pub fn feature_width(rank: usize) -> usize {
    2 * rank + rank * rank.saturating_sub(1) / 2 + 2 * NUM_LABELS
}

/// Trailing values of [`features`] that are in standardised label units already (spread, then plug-in labels) and
/// are not standardised again: the network scales its correction by the first and adds it to the second.
pub const LABEL_COLUMNS: usize = 2 * NUM_LABELS;

/// What the estimator reads of a piece of evidence: the posterior mean and log variance of each prior coordinate,
/// their correlations (which combinations the data leave open: a 4 s window pins some directions and not others),
/// then per label its posterior spread (delta method through the posterior covariance) and its value at the
/// posterior mean (the plug-in estimate), both standardised by `label_mean`/`label_std` and clipped.
///
/// The plug-in labels are a complete estimate; the network corrects each by at most a few times its spread, so a
/// label the torques pin down (spread ~0) keeps what the torques say, and one they cannot see (spread ~1) is left to
/// what the generator's distribution implies.
pub fn features(
    prior: &ParameterPrior,
    e: &Evidence,
    label_mean: &[f64; NUM_LABELS],
    label_std: &[f64; NUM_LABELS],
) -> Result<Vec<f32>, IdentifyError> {
    let post = e.posterior()?;
    let (plug_in, spread_si) = label_posterior(prior, &post);
    let spread: [f64; NUM_LABELS] = std::array::from_fn(|k| {
        let s = spread_si[k] / label_std[k];
        if s.is_finite() { s.min(SPREAD_CLIP) } else { SPREAD_CLIP }
    });
    let r = prior.rank();
    let mut out = Vec::with_capacity(feature_width(r));
    out.extend(post.mean.iter().map(|&v| v as f32));
    out.extend(post.variance.iter().map(|&v| v.max(1e-30).ln() as f32));
    out.extend(post.correlation.iter().map(|&c| c as f32));
    out.extend(spread.iter().map(|&v| v as f32));
    out.extend((0..NUM_LABELS).map(|k| {
        let z = (plug_in[k] - label_mean[k]) / label_std[k];
        (if z.is_finite() { z.clamp(-CLIP, CLIP) } else { 0.0 }) as f32
    }));
    Ok(out)
}

/// What a posterior over the prior coordinates says of each label [SI], robot by robot: its value at the posterior
/// mean (the plug-in estimate) and its standard deviation by the delta method through the posterior covariance (not
/// finite where a link's mass is near zero).
pub fn label_posterior(prior: &ParameterPrior, post: &Posterior) -> ([f64; NUM_LABELS], [f64; NUM_LABELS]) {
    let r = prior.rank();
    let at = |z: &[f64]| labels_of_parameters(&prior.parameters(z));
    let plug_in = at(&post.mean);
    // d label / d z by central differences (labels are smooth in z where the mass is away from zero).
    const H: f64 = 1e-4;
    let mut grad = vec![[0.0; NUM_LABELS]; r];
    let mut z = post.mean.clone();
    for (i, g) in grad.iter_mut().enumerate() {
        z[i] = post.mean[i] + H;
        let up = at(&z);
        z[i] = post.mean[i] - H;
        let down = at(&z);
        z[i] = post.mean[i];
        *g = std::array::from_fn(|k| (up[k] - down[k]) / (2.0 * H));
    }
    let sd = |i: usize| post.variance[i].sqrt();
    let cov = |i: usize, j: usize| match i.cmp(&j) {
        std::cmp::Ordering::Equal => post.variance[i],
        std::cmp::Ordering::Less => post.correlation[i * r - i * (i + 1) / 2 + j - i - 1] * sd(i) * sd(j),
        std::cmp::Ordering::Greater => post.correlation[j * r - j * (j + 1) / 2 + i - j - 1] * sd(i) * sd(j),
    };
    let spread = std::array::from_fn(|k| {
        let mut v = 0.0;
        for i in 0..r {
            for j in 0..r {
                v += grad[i][k] * cov(i, j) * grad[j][k];
            }
        }
        v.max(0.0).sqrt()
    });
    (plug_in, spread)
}
