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
    BatchScatter, Evidence, IdentifyError, LatentSums, ParameterPrior, Posterior, batch_scatter, labels_of_parameters,
    latent_blocks,
};
use dynforge_proto::NUM_LABELS;
use dynforge_proto::content_hash;
use dynforge_proto::generator::GeneratorConfig;
use dynforge_recording::dataset::generator;
use dynforge_recording::{ReadError, Recording};
use dynforge_robot::generator::generate;
use dynforge_robot::parameters::dynamic_parameters;
use dynforge_robot::rng::Rng;

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
    /// How the whole recording's scores scatter over batches of [`SCATTER_BATCH`] samples against the noise it
    /// assumed: what the evidence's posterior is worth on this log.
    pub scatter: BatchScatter,
}

/// Samples per batch of [`batch_scatter`]: a quarter second at 1 kHz, longer than the controller's transients.
pub const SCATTER_BATCH: usize = 256;

/// What a simulated log's posterior is worth along the directions its torques decide, as a multiple of its batch
/// scatter ([`BatchScatter::ratio`]): the sandwich `Evidence::sandwich(COHERENCE * ratio)`. The true parameters'
/// residual there is the pairing's discretization, smooth over hundreds of milliseconds and growing with speed (one
/// fast robot: 1e-7 of a joint's torque spread when slow, 3e-5 at 1 rad/s); what of it aliases into the parameters
/// is alike in every batch and leaves no scatter, so the scatter sees only part of it. Chosen on 128 robots apart from
/// the calibration's and the held-out ones (`dynforge-bench-coverage`, first logs, refined; docs/training.md): at 3,
/// 10, 30, 100 and 300 times the ratio, 27, 26, 19, 24 and 31 labels of 4,864 fell beyond four spreads.
pub const COHERENCE: f64 = 30.0;

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
        LatentSums::sum(rec.model.dof(), prior.rank(), &blocks[range.start / block..range.end.div_ceil(block)])
    };
    let all = sum(0..len);
    let variance = match measure {
        true => all.measured_noise(NOISE_FLOOR).map_err(bad)?,
        false => vec![0.0; rec.model.dof()],
    };
    let noise = variance.iter().zip(all.torque_std()).map(|(v, std)| if std > 0.0 { v.sqrt() / std } else { 0.0 });
    let evidence = |s: LatentSums| s.evidence_with_noise(NOISE_FLOOR, &variance);
    let scatter = match measure {
        true => {
            let batches: Vec<LatentSums> = blocks
                .chunks(SCATTER_BATCH.div_ceil(block))
                .map(|c| LatentSums::sum(rec.model.dof(), prior.rank(), c))
                .collect();
            batch_scatter(&batches, NOISE_FLOOR, &variance).map_err(bad)?
        }
        false => BatchScatter::default(),
    };
    Ok(MeasuredEvidence {
        windows: spec.windows(len).iter().map(|w| evidence(sum(spec.samples(w, len)))).collect(),
        whole: evidence(all),
        noise: noise.collect(),
        scatter,
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
    let plug_in = labels_of_parameters(&prior.parameters(&post.mean));
    let grad = label_gradient(prior, &post.mean);
    let cov = post.covariance();
    let spread = std::array::from_fn(|k| {
        let mut v = 0.0;
        for i in 0..r {
            for j in 0..r {
                v += grad[i][k] * cov[(i, j)] * grad[j][k];
            }
        }
        v.max(0.0).sqrt()
    });
    (plug_in, spread)
}

/// `d label / d z` at the prior's coordinates `z`, row `i` for coordinate `i`, by central differences (labels are
/// smooth in `z` where the mass is away from zero).
pub fn label_gradient(prior: &ParameterPrior, z: &[f64]) -> Vec<[f64; NUM_LABELS]> {
    const H: f64 = 1e-4;
    let at = |z: &[f64]| labels_of_parameters(&prior.parameters(z));
    let mut z = z.to_vec();
    (0..z.len())
        .map(|i| {
            let centre = z[i];
            z[i] = centre + H;
            let up = at(&z);
            z[i] = centre - H;
            let down = at(&z);
            z[i] = centre;
            std::array::from_fn(|k| (up[k] - down[k]) / (2.0 * H))
        })
        .collect()
}

/// Draws of the prior's coordinates in [`label_deviation`]: its percentiles are then within ~1 % of the
/// posterior's (a 2.3 % tail holds ~47 draws).
pub const LABEL_DRAWS: usize = 2048;

/// How far each label [SI] of a posterior over the prior's coordinates lies from `estimate`: the narrowest `s` such
/// that `estimate +- s` holds the posterior's central 68.3 % and `estimate +- 2 s` its central 95.4 % (percentiles
/// of [`LABEL_DRAWS`] draws of `z` from `post` through the labels' own map). Where the delta method linearises at the
/// mean, this keeps what the map does to a posterior that is wide along it: a centre of mass is a first moment over
/// a mass, and a moment about it subtracts `m c^2` from one about the joint, so a label the torques decide only in
/// part has a skewed posterior, with a tail where a drawn mass nears zero; and the estimate (the network's, not the
/// posterior's mean) need not sit at its centre. Percentiles, not moments: the tail beyond 2.3 % does not count. The
/// draws are one fixed stream: the same posterior always gives the same spreads. Not finite where a percentile is
/// not (a mass at zero in more than 2.3 % of the draws).
pub fn label_deviation(prior: &ParameterPrior, post: &Posterior, estimate: &[f64; NUM_LABELS]) -> [f64; NUM_LABELS] {
    let r = prior.rank();
    let root = covariance_root(post);
    let mean = nalgebra::DVector::from_column_slice(&post.mean);
    let mut rng = Rng::stream(DEVIATION_STREAM, &[]);
    let mut draws: Vec<Vec<f64>> = (0..NUM_LABELS).map(|_| Vec::with_capacity(LABEL_DRAWS)).collect();
    for _ in 0..LABEL_DRAWS {
        let xi = nalgebra::DVector::from_fn(r, |_, _| rng.normal());
        let z = &mean + &root * xi;
        let labels = labels_of_parameters(&prior.parameters(z.as_slice()));
        // A non-finite label sorts to the far end: beyond every percentile, or it makes one non-finite.
        draws.iter_mut().zip(labels).for_each(|(d, l)| d.push(if l.is_nan() { f64::INFINITY } else { l }));
    }
    std::array::from_fn(|k| {
        let d = &mut draws[k];
        d.sort_by(f64::total_cmp);
        let at = |p: f64| d[((p * LABEL_DRAWS as f64) as usize).min(LABEL_DRAWS - 1)] - estimate[k];
        let (one, two) = (at(ONE_SIDED).abs().max(at(1.0 - ONE_SIDED)), at(TWO_SIDED).abs().max(at(1.0 - TWO_SIDED)));
        one.max(0.5 * two)
    })
}

/// A square root `L` of the posterior's covariance (`L L^T`, by its eigen-decomposition, rounding's negative
/// eigenvalues taken as zero): `mean + L xi` with standard normal `xi` is a draw from it.
fn covariance_root(post: &Posterior) -> nalgebra::DMatrix<f64> {
    let eig = nalgebra::SymmetricEigen::new(post.covariance());
    &eig.eigenvectors * nalgebra::DMatrix::from_diagonal(&eig.eigenvalues.map(|v| v.max(0.0).sqrt()))
}

/// The lower percentiles of a standard normal's central 68.3 and 95.4 %: one and two standard deviations.
const ONE_SIDED: f64 = 0.158_655;
const TWO_SIDED: f64 = 0.022_750;

/// The stream of [`label_deviation`]'s draws.
const DEVIATION_STREAM: u64 = 0x6465_7669_6174_696f;

#[cfg(test)]
mod tests {
    use super::*;
    use dynforge_identify::packed_len;
    use dynforge_proto::{LABELS, LabelKind};

    /// The prior of 400 generated arms, and a posterior whose evidence decides some of its directions sharply and
    /// leaves others mostly to the prior (`H` diagonal, from 1e-2 to 1e6), about one of them.
    fn posterior() -> (ParameterPrior, Posterior, Vec<f64>) {
        let cfg = GeneratorConfig::default();
        let samples: Vec<Vec<f64>> =
            (0..400).map(|id| dynamic_parameters(&generate(&cfg, 3, id).unwrap().model)).collect();
        let prior = ParameterPrior::fit(&samples).unwrap();
        let r = prior.rank();
        let mut h = vec![0.0; packed_len(r)];
        for i in 0..r {
            h[i * r - i * (i + 1) / 2 + i] = 10f64.powf(-2.0 + 8.0 * i as f64 / (r - 1) as f64);
        }
        let truth = prior.coordinates(&samples[0]);
        let post = Evidence::noiseless(r, &h, &truth).posterior().unwrap();
        (prior, post, truth)
    }

    /// A label linear in the parameters (a friction coefficient, a mass) has a Gaussian posterior: about its mean
    /// the deviation is its standard deviation (the delta method's, exact here), and about an estimate `d` off the
    /// mean it is `d + sd` (the central 68 % interval's far end). Tolerance: the percentiles of 2,048 draws scatter
    /// by ~3 % of a standard deviation each; three times that.
    #[test]
    fn a_linear_labels_deviation_is_its_standard_deviation_plus_the_estimates_offset() {
        let (prior, post, _) = posterior();
        let (mean, sd) = label_posterior(&prior, &post);
        let centred = label_deviation(&prior, &post, &mean);
        let off: [f64; NUM_LABELS] = std::array::from_fn(|k| mean[k] + 3.0 * sd[k]);
        let shifted = label_deviation(&prior, &post, &off);
        let linear = LABELS
            .iter()
            .enumerate()
            .filter(|(_, l)| matches!(l.kind, LabelKind::Coulomb | LabelKind::Viscous | LabelKind::Mass));
        for (k, l) in linear {
            assert!((centred[k] / sd[k] - 1.0).abs() < 0.1, "{}: {} against {}", l.name, centred[k], sd[k]);
            assert!((shifted[k] / sd[k] - 4.0).abs() < 0.3, "{}: {} against 4 x {}", l.name, shifted[k], sd[k]);
        }
    }

    /// Every label, however skewed its posterior (a centre of mass is a ratio, a moment about it subtracts `m c^2`):
    /// on draws of their own, `estimate +- deviation` holds at least the posterior's central 68.3 % and `+- 2
    /// deviation` its 95.4 % (less the percentiles' sampling error, ~1 and 0.5 % over 2,048 draws, three times).
    #[test]
    fn a_labels_deviation_covers_the_posteriors_central_shares_on_fresh_draws() {
        let (prior, post, truth) = posterior();
        let estimate = labels_of_parameters(&prior.parameters(&truth));
        let deviation = label_deviation(&prior, &post, &estimate);
        let r = prior.rank();
        let root = covariance_root(&post);
        let mut rng = Rng::stream(11, &[]);
        let n = 4096;
        let (mut one, mut two) = ([0usize; NUM_LABELS], [0usize; NUM_LABELS]);
        for _ in 0..n {
            let z = nalgebra::DVector::from_column_slice(&post.mean)
                + &root * nalgebra::DVector::from_fn(r, |_, _| rng.normal());
            let labels = labels_of_parameters(&prior.parameters(z.as_slice()));
            for k in 0..NUM_LABELS {
                let d = (labels[k] - estimate[k]).abs();
                one[k] += usize::from(d <= deviation[k]);
                two[k] += usize::from(d <= 2.0 * deviation[k]);
            }
        }
        for (k, l) in LABELS.iter().enumerate() {
            let (one, two) = (one[k] as f64 / n as f64, two[k] as f64 / n as f64);
            assert!(deviation[k].is_finite() && deviation[k] > 0.0, "{}: {}", l.name, deviation[k]);
            assert!(one >= 0.683 - 0.04 && two >= 0.954 - 0.02, "{}: {one:.3} / {two:.3}", l.name);
        }
    }
}
