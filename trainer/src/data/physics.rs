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
    Evidence, IdentifyError, LatentSums, PAIRING_REVISION, ParameterPrior, latent_blocks, packed_len, parameter_labels,
};
use dynforge_proto::NUM_LABELS;
use dynforge_proto::run_dir::{CACHE, SHARDS};
use dynforge_recording::dataset::{generator, list_shards};
use dynforge_recording::{ReadError, Recording, read};
use dynforge_robot::generator::{GeneratorConfig, generate};
use dynforge_robot::parameters::dynamic_parameters;
use dynforge_shard::content_hash;

use super::cache::{CacheKey, check_not_pruned};
use super::codec::{Decoder, Encoder};
use super::partitions::merged_order;
use super::window::WindowSpec;

/// Each joint's torque noise, as a fraction of the RMS of its own recorded torque. With the stops left out and the
/// viscous force paired with the span's mean velocity (`identify`'s pairing revision 2), the true parameters leave
/// ~1e-7 to 3e-6 of each joint's torque spread on simulated data, so the torques can be trusted far more than the
/// 1e-3 the old pairing (which left 1e-5 to 1e-3) needed. Pipeline (48 robots), per window / per robot: 1e-3 0.901 /
/// 0.956, 3e-4 0.928 / 0.961, 1e-4 0.938 / 0.961, 3e-5 0.953 / 0.962, 1e-5 0.956 / 0.962 (the last two within the
/// +-0.01 the small validation set moves by; 3e-5 keeps a margin above the residual). One level for all joints does
/// worse: the wrists' torques are two orders of magnitude below the shoulder's. A real robot's logs carry more
/// (sensor noise, transmissions): its posterior is then overconfident, and the estimate's refinement by the log's
/// own torques uses `identify`'s 1e-3 floor.
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
pub enum PhysicsError {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("{file}: {source}")]
    Identify { file: String, source: IdentifyError },
    #[error("the generator's parameter prior: {0}")]
    Generator(String),
    #[error("{0}: interrupted while computing the physics of the shards; nothing was cached")]
    Interrupted(String),
}

/// The parameter prior of the generator `cfg`: [`PRIOR_ROBOTS`] robots drawn beside the dataset of seed `seed`.
pub fn generator_prior(cfg: &GeneratorConfig, seed: u64) -> Result<ParameterPrior, PhysicsError> {
    let seed = draw_seed(seed, Draw::Prior);
    let ids: Vec<u64> = (0..PRIOR_ROBOTS).collect();
    let robots =
        crate::parallel::map_in_order(&ids, |&id| generate(cfg, seed, id).map(|r| dynamic_parameters(&r.model)));
    let samples =
        robots.into_iter().collect::<Result<Vec<_>, _>>().map_err(|e| PhysicsError::Generator(e.to_string()))?;
    ParameterPrior::fit(&samples).map_err(|e| PhysicsError::Generator(e.to_string()))
}

/// The generator prior of a run directory, from its manifest.
pub fn dataset_prior(dir: &Path) -> Result<ParameterPrior, PhysicsError> {
    let (cfg, seed) = generator(dir)?.ok_or_else(|| {
        PhysicsError::Generator(format!(
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
) -> Result<(Vec<Evidence>, Evidence), PhysicsError> {
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
) -> Result<MeasuredEvidence, PhysicsError> {
    evidence_of(rec, prior, spec, true)
}

fn evidence_of(
    rec: &Recording,
    prior: &ParameterPrior,
    spec: &WindowSpec,
    measure: bool,
) -> Result<MeasuredEvidence, PhysicsError> {
    let bad = |source| PhysicsError::Identify { file: rec.path.display().to_string(), source };
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

/// Pieces of evidence with their robot and labels, stored flat.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EvidenceList {
    pub rank: usize,
    pub robots: Vec<u64>,
    pub labels: Vec<[f64; NUM_LABELS]>,
    /// For windows: the index of their recording in the set's recordings.
    pub recording: Vec<u64>,
    h: Vec<f64>,
    b: Vec<f64>,
}

impl EvidenceList {
    fn new(rank: usize) -> Self {
        EvidenceList { rank, ..Default::default() }
    }

    pub fn len(&self) -> usize {
        self.robots.len()
    }

    pub fn is_empty(&self) -> bool {
        self.robots.is_empty()
    }

    fn push(&mut self, robot: u64, labels: [f64; NUM_LABELS], recording: u64, e: &Evidence) {
        self.robots.push(robot);
        self.labels.push(labels);
        self.recording.push(recording);
        self.h.extend(&e.h);
        self.b.extend(&e.b);
    }

    /// Appends item `i` of `other`, as part of recording `recording`.
    fn push_from(&mut self, other: &EvidenceList, i: usize, recording: u64) {
        let (r, p) = (self.rank, packed_len(self.rank));
        self.robots.push(other.robots[i]);
        self.labels.push(other.labels[i]);
        self.recording.push(recording);
        self.h.extend(&other.h[i * p..(i + 1) * p]);
        self.b.extend(&other.b[i * r..(i + 1) * r]);
    }

    /// Evidence `i`.
    pub fn get(&self, i: usize) -> Evidence {
        let (r, p) = (self.rank, packed_len(self.rank));
        Evidence { rank: r, h: self.h[i * p..(i + 1) * p].to_vec(), b: self.b[i * r..(i + 1) * r].to_vec() }
    }

    /// The packed excitation `H` of evidence `i` alone.
    pub fn excitation(&self, i: usize) -> &[f64] {
        let p = packed_len(self.rank);
        &self.h[i * p..(i + 1) * p]
    }

    fn encode(&self, e: &mut Encoder) {
        e.u64s([self.len() as u64]).u64s(self.robots.iter().copied()).u64s(self.recording.iter().copied());
        e.f64s(&self.labels.concat()).f64s(&self.h).f64s(&self.b);
    }

    fn decode(d: &mut Decoder, rank: usize) -> Option<Self> {
        let n = d.usize()?;
        let robots = d.u64s(n)?;
        let recording = d.u64s(n)?;
        let labels =
            d.f64s(n.checked_mul(NUM_LABELS)?)?.chunks_exact(NUM_LABELS).map(|c| c.try_into().expect("38")).collect();
        let h = d.f64s(n.checked_mul(packed_len(rank))?)?;
        let b = d.f64s(n.checked_mul(rank)?)?;
        Some(EvidenceList { rank, robots, labels, recording, h, b })
    }
}

/// A dataset's physics: the evidence of every window (same windows, same order as the window cache's) and of every
/// whole recording.
#[derive(Debug, Clone, PartialEq)]
pub struct PhysicsSet {
    pub spec: WindowSpec,
    pub windows: EvidenceList,
    pub recordings: EvidenceList,
    /// Whether this came from the cache file.
    pub hit: bool,
}

const MAGIC: &[u8; 8] = b"DFPHY001";

impl PhysicsSet {
    /// An empty set for evidence in the coordinates of a prior of rank `rank`.
    pub fn new(spec: WindowSpec, rank: usize) -> Self {
        PhysicsSet { spec, windows: EvidenceList::new(rank), recordings: EvidenceList::new(rank), hit: false }
    }

    /// Adds a dataset recording (with labels and robot id): its windows' and its whole evidence.
    pub fn add(&mut self, rec: &Recording, prior: &ParameterPrior) -> Result<(), String> {
        let (Some(labels), Some(robot)) = (rec.labels, rec.robot) else {
            return Err(format!("{}: no labels or robot id (not a dataset shard)", rec.path.display()));
        };
        let (windows, whole) = recording_evidence(rec, prior, &self.spec).map_err(|e| e.to_string())?;
        self.append(robot, labels, &windows, &whole);
        Ok(())
    }

    /// The sets of a run's partitions as one (`crate::data::partitions`): recordings and windows in merged order,
    /// each window still pointing at its recording.
    pub(crate) fn combine(parts: &[PhysicsSet]) -> PhysicsSet {
        let (spec, rank) = parts.first().map_or((WindowSpec::default(), 0), |p| (p.spec, p.windows.rank));
        let mut out = PhysicsSet::new(spec, rank);
        let mut moved: Vec<Vec<u64>> = parts.iter().map(|p| vec![0; p.recordings.len()]).collect();
        let robots = |f: fn(&PhysicsSet) -> &EvidenceList| parts.iter().map(|p| &f(p).robots[..]).collect::<Vec<_>>();
        for (p, items) in merged_order(&robots(|s| &s.recordings)) {
            for i in items {
                moved[p][i] = out.recordings.len() as u64;
                out.recordings.push_from(&parts[p].recordings, i, moved[p][i]);
            }
        }
        for (p, items) in merged_order(&robots(|s| &s.windows)) {
            for i in items {
                let list = &parts[p].windows;
                out.windows.push_from(list, i, moved[p][list.recording[i] as usize]);
            }
        }
        out
    }

    fn append(&mut self, robot: u64, labels: [f64; NUM_LABELS], windows: &[Evidence], whole: &Evidence) {
        let k = self.recordings.len() as u64;
        self.recordings.push(robot, labels, k, whole);
        for w in windows {
            self.windows.push(robot, labels, k, w);
        }
    }

    pub(crate) fn encode(&self) -> Vec<u8> {
        let mut e = Encoder::new(MAGIC, (self.windows.h.len() + self.recordings.h.len()) * 8);
        e.u64s([self.spec.len, self.spec.stride, self.spec.ssr, self.windows.rank].map(|v| v as u64));
        self.windows.encode(&mut e);
        self.recordings.encode(&mut e);
        e.finish()
    }

    pub(crate) fn decode(bytes: &[u8]) -> Option<Self> {
        let mut d = Decoder::open(bytes, MAGIC)?;
        let spec = WindowSpec { len: d.usize()?, stride: d.usize()?, ssr: d.usize()? };
        let rank = d.usize()?;
        let windows = EvidenceList::decode(&mut d, rank)?;
        let recordings = EvidenceList::decode(&mut d, rank)?;
        d.done().then_some(PhysicsSet { spec, windows, recordings, hit: true })
    }
}

pub(crate) const KIND: &str = "physics";

/// What the cache depends on besides the dataset: the window geometry, the noise model and the prior.
fn key(spec: &WindowSpec, prior: &ParameterPrior) -> CacheKey {
    let mut m = format!(
        "physics|{}:{}:{}|{}|{}|{}|",
        spec.len,
        spec.stride,
        spec.ssr,
        NOISE_FLOOR,
        prior.rank(),
        PAIRING_REVISION
    )
    .into_bytes();
    for v in prior.mean().iter().chain(prior.factor()) {
        m.extend(v.to_le_bytes());
    }
    m.extend(MAGIC);
    CacheKey::new(KIND, &m)
}

/// The physics of every shard of the `generate` directory `dir`: from its cache if current, else computed on all
/// cores (calling `progress(done, total)`; `false` stops, an error, with nothing cached) and cached. Shards that cannot be read, or are not dataset shards, are
/// skipped and returned with the reason.
pub fn load_or_build(
    dir: &Path,
    spec: &WindowSpec,
    prior: &ParameterPrior,
    mut progress: impl FnMut(usize, usize) -> bool,
) -> Result<(PhysicsSet, Vec<String>), PhysicsError> {
    let path = key(spec, prior).path(dir)?;
    if let Some(set) = std::fs::read(&path).ok().and_then(|b| PhysicsSet::decode(&b)) {
        return Ok((set, Vec::new()));
    }
    check_not_pruned(dir, KIND)?;
    let io = |p: &Path, e: std::io::Error| ReadError::Content { file: p.display().to_string(), problem: e.to_string() };
    let shards = dir.join(SHARDS);
    let paths = list_shards(&shards).map_err(|e| io(&shards, e))?;
    let mut set = PhysicsSet::new(*spec, prior.rank());
    let mut skipped = Vec::new();
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut done = 0;
    for chunk in paths.chunks(8 * threads) {
        if !progress(done, paths.len()) {
            return Err(PhysicsError::Interrupted(dir.display().to_string()));
        }
        let results = crate::parallel::map_in_order(chunk, |p| -> Result<_, String> {
            let rec = read(p, None).map_err(|e| e.to_string())?;
            let (Some(labels), Some(robot)) = (rec.labels, rec.robot) else {
                return Err(format!("{}: no labels or robot id (not a dataset shard)", p.display()));
            };
            let (windows, whole) = recording_evidence(&rec, prior, spec).map_err(|e| e.to_string())?;
            Ok((robot, labels, windows, whole))
        });
        for r in results {
            match r {
                Ok((robot, labels, windows, whole)) => set.append(robot, labels, &windows, &whole),
                Err(why) => skipped.push(why),
            }
        }
        done += chunk.len();
    }
    progress(done, paths.len());
    let cache = dir.join(CACHE);
    std::fs::create_dir_all(&cache).map_err(|e| io(&cache, e))?;
    dynforge_proto::run_dir::write_atomic(&path, &set.encode()).map_err(|e| io(&path, e))?;
    Ok((set, skipped))
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
    let r = prior.rank();
    let at = |z: &[f64]| parameter_labels(&prior.parameters(z));
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
    let spread: [f64; NUM_LABELS] = std::array::from_fn(|k| {
        let mut v = 0.0;
        for i in 0..r {
            for j in 0..r {
                v += grad[i][k] * cov(i, j) * grad[j][k];
            }
        }
        let s = v.max(0.0).sqrt() / label_std[k];
        if s.is_finite() { s.min(SPREAD_CLIP) } else { SPREAD_CLIP }
    });
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
