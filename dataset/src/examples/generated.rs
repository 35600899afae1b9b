//! The physics estimator's examples: real evidence from the dataset, and robots drawn from the generator paired with
//! real excitations.
//!
//! A robot's evidence is exact algebra once its excitation is known (`Evidence::noiseless`: the torques of a robot
//! at coordinates `z` under excitation `H` say `b = H z`), so the map from evidence to labels can learn from as many
//! generated robots as wanted without simulating any: only the excitations, what a window or a recording of real
//! motion lets the torques see, come from the simulated dataset. Every epoch draws fresh robots, each paired with
//! the excitation of a random training window, recording or robot; the real training examples join them, and the
//! validation windows are the dataset's (the paper's protocol).

use dynforge_identify::{Evidence, IdentifyError, ParameterPrior};
use dynforge_proto::NUM_LABELS;
use dynforge_proto::generator::GeneratorConfig;
use dynforge_robot::generator::generate;
use dynforge_robot::parameters::{dynamic_parameters, labels_of};
use dynforge_robot::rng::Rng;

use super::{ExampleRecord, Examples};
use crate::cache::evidence::PhysicsSet;
use crate::evidence::{Draw, LABEL_COLUMNS, NOISE_FLOOR, draw_seed, feature_width, features};
use crate::normalize::Standardizer;
use crate::split::{Split, SplitRule};
use dynforge_proto::parallel::map_in_order;

/// How the physics examples are made.
#[derive(Debug, Clone)]
pub struct PhysicsSource {
    pub generator: GeneratorConfig,
    /// Seed of the generated robots (apart from the dataset's: [`draw_seed`]).
    pub seed: u64,
    /// How many generated robots per epoch, whether the dataset's own training examples join them (without them
    /// the network cannot memorise the real examples, and the dataset's simulations serve only as excitations and
    /// for validation), and whether half the generated robots carry torque noise (log-uniform from
    /// [`NOISY_LEVELS`]), their evidence weighted by it as `estimate` weighs a noisy log: the posteriors of real
    /// robots' logs, which simulation alone never shows the network. What the checkpoint records.
    pub examples: ExampleRecord,
}

/// The torque noise of noisy generated examples, relative to the torque RMS: from a good torque sensor to a motor
/// current read through a gearbox.
pub const NOISY_LEVELS: (f64, f64) = (1e-4, 1e-2);

/// Why the physics examples of a dataset cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum ExamplesError {
    #[error(transparent)]
    Identify(#[from] IdentifyError),
    #[error("no training windows to take excitations from (more robots, or another validation fraction)")]
    NoTrainingWindows,
}

/// Generated examples the input statistics are fitted to, besides the real ones.
const CALIBRATION: usize = 4096;

/// Standardised examples of the physics estimator.
pub struct PhysicsExamples {
    prior: ParameterPrior,
    standardizer: Standardizer,
    source: PhysicsSource,
    /// Real training examples (standardised inputs, row-major) and their labels.
    real_x: Vec<f32>,
    real_y: Vec<[f64; NUM_LABELS]>,
    validation_x: Vec<f32>,
    validation_y: Vec<[f64; NUM_LABELS]>,
    /// Packed excitations generated robots are paired with: training windows', training recordings', and per
    /// training robot the indices of its recordings.
    windows: Vec<Vec<f64>>,
    recordings: Vec<Vec<f64>>,
    robots: Vec<Vec<usize>>,
    /// This epoch's generated examples.
    drawn_x: Vec<f32>,
    drawn_y: Vec<[f64; NUM_LABELS]>,
}

impl PhysicsExamples {
    /// The examples of `set`, split by `rule`. Label statistics come from the generator
    /// (a calibration draw of its robots: what the network mostly sees, and well defined however few robots the
    /// dataset has); input statistics from the real training examples and the calibration draw (the labels'
    /// spreads and plug-in values stay in label units, since the network scales and adds its output with them).
    pub fn new(
        set: &PhysicsSet,
        prior: ParameterPrior,
        rule: &SplitRule,
        source: PhysicsSource,
    ) -> Result<Self, ExamplesError> {
        let (window_sides, recording_sides) = set.sides(rule);
        let (train_windows, validation): (Vec<usize>, Vec<usize>) =
            (0..set.windows.len()).partition(|&i| window_sides[i] == Split::Train);
        let train = |i: usize| recording_sides[i] == Split::Train;
        let ids: Vec<u64> = (0..CALIBRATION as u64).collect();
        let generated: Vec<[f64; NUM_LABELS]> = map_in_order(&ids, |&id| {
            generate(&source.generator, draw_seed(source.seed, Draw::Prior), id)
                .ok()
                .and_then(|r| labels_of(&r.model).ok())
        })
        .into_iter()
        .flatten()
        .collect();
        let standardizer = Standardizer::fit_labels(generated.iter());
        let (lm, ls) = (standardizer.label_mean, standardizer.label_std);
        let mut evidence: Vec<(Evidence, [f64; NUM_LABELS])> = Vec::new();
        evidence.extend(train_windows.iter().map(|&i| (set.windows.get(i), set.windows.labels[i])));
        let recordings: Vec<usize> = (0..set.recordings.len()).filter(|&i| train(i)).collect();
        evidence.extend(recordings.iter().map(|&i| (set.recordings.get(i), set.recordings.labels[i])));
        evidence.extend(set.recordings.per_robot(train).into_iter().map(|(_, y, e)| (e, y)));
        let raw = map_in_order(&evidence, |(e, _)| features(&prior, e, &lm, &ls));
        let raw: Vec<Vec<f32>> = raw.into_iter().collect::<Result<_, _>>()?;
        let validation_raw = map_in_order(&validation, |&i| features(&prior, &set.windows.get(i), &lm, &ls));
        let validation_raw: Vec<Vec<f32>> = validation_raw.into_iter().collect::<Result<_, _>>()?;
        let mut robots: std::collections::BTreeMap<u64, Vec<usize>> = Default::default();
        for (k, &i) in recordings.iter().enumerate() {
            robots.entry(set.recordings.robots[i]).or_default().push(k);
        }
        let mut out = PhysicsExamples {
            windows: train_windows.iter().map(|&i| set.windows.excitation(i).to_vec()).collect(),
            recordings: recordings.iter().map(|&i| set.recordings.excitation(i).to_vec()).collect(),
            robots: robots.into_values().collect(),
            real_x: Vec::new(),
            real_y: evidence.iter().map(|(_, y)| *y).collect(),
            validation_x: Vec::new(),
            validation_y: validation.iter().map(|&i| set.windows.labels[i]).collect(),
            prior,
            standardizer,
            source,
            drawn_x: Vec::new(),
            drawn_y: Vec::new(),
        };
        if out.windows.is_empty() || out.robots.is_empty() {
            return Err(ExamplesError::NoTrainingWindows);
        }
        // Input statistics over the real examples and a calibration draw of generated ones (a stream of its own),
        // since generated examples are most of what the network sees.
        let calibration: Vec<usize> = (0..CALIBRATION).collect();
        let drawn: Vec<Vec<f32>> = map_in_order(&calibration, |&k| out.draw_raw(usize::MAX, k))
            .into_iter()
            .flatten()
            .map(|(f, _)| f)
            .collect();
        let width = feature_width(out.prior.rank());
        let rows = raw.iter().chain(&drawn).map(Vec::as_slice);
        out.standardizer = Standardizer::fit_columns(out.standardizer, rows, width - LABEL_COLUMNS);
        out.real_x = raw.iter().flat_map(|f| out.standardizer.row(f)).collect();
        out.validation_x = validation_raw.iter().flat_map(|f| out.standardizer.row(f)).collect();
        Ok(out)
    }

    pub fn prior(&self) -> &ParameterPrior {
        &self.prior
    }

    /// Real training examples (windows, recordings and robots) trained on.
    pub fn real(&self) -> usize {
        self.real_len()
    }

    fn real_len(&self) -> usize {
        if self.source.examples.real { self.real_y.len() } else { 0 }
    }

    /// The excitation of generated example `k`: of the kind `k mod 3`, picked by `rng`.
    fn excitation(&self, k: usize, rng: &mut Rng) -> Vec<f64> {
        match k % 3 {
            0 => self.windows[rng.below(self.windows.len())].clone(),
            1 => self.recordings[rng.below(self.recordings.len())].clone(),
            _ => {
                let mut own = self.robots[rng.below(self.robots.len())].clone();
                let n = 1 + rng.below(own.len());
                for i in 0..n {
                    let j = i + rng.below(own.len() - i);
                    own.swap(i, j);
                }
                let mut h = self.recordings[own[0]].clone();
                for &r in &own[1..n] {
                    h.iter_mut().zip(&self.recordings[r]).for_each(|(a, b)| *a += b);
                }
                h
            }
        }
    }

    /// Generated example `k` of `epoch`, standardised: robot `epoch * generated_per_epoch + k` of the draw seed with the
    /// excitation the stream (seed, epoch, k) picks; `None` if the generator rejects the robot.
    fn draw(&self, epoch: usize, k: usize) -> Option<(Vec<f32>, [f64; NUM_LABELS])> {
        self.draw_raw(epoch, k).map(|(f, y)| (self.standardizer.row(&f), y))
    }

    /// [`Self::draw`] before standardisation.
    fn draw_raw(&self, epoch: usize, k: usize) -> Option<(Vec<f32>, [f64; NUM_LABELS])> {
        let id = (epoch.wrapping_mul(self.source.examples.generated_per_epoch).wrapping_add(k)) as u64;
        let robot = generate(&self.source.generator, self.source.seed, id).ok()?.model;
        let z = self.prior.coordinates(&dynamic_parameters(&robot));
        let mut rng = Rng::stream(self.source.seed, &[0x6578_6369_7465, epoch as u64, k as u64]);
        let mut e = Evidence::noiseless(self.prior.rank(), &self.excitation(k, &mut rng), &z);
        if self.source.examples.noisy && rng.unit() < 0.5 {
            let (lo, hi) = NOISY_LEVELS;
            let level = lo * (hi / lo).powf(rng.unit());
            let xi: Vec<f64> = (0..e.rank).map(|_| rng.normal()).collect();
            e = e.with_noise(level / NOISE_FLOOR, &xi);
        }
        let s = &self.standardizer;
        let f = features(&self.prior, &e, &s.label_mean, &s.label_std).ok()?;
        Some((f, labels_of(&robot).ok()?))
    }
}

impl Examples for PhysicsExamples {
    fn shape(&self) -> [usize; 2] {
        [1, feature_width(self.prior.rank())]
    }

    fn standardizer(&self) -> &Standardizer {
        &self.standardizer
    }

    fn begin_epoch(&mut self, epoch: usize) {
        if self.windows.is_empty() || self.robots.is_empty() {
            return;
        }
        let ks: Vec<usize> = (0..self.source.examples.generated_per_epoch).collect();
        let drawn = map_in_order(&ks, |&k| self.draw(epoch, k));
        self.drawn_x.clear();
        self.drawn_y.clear();
        for (x, y) in drawn.into_iter().flatten() {
            self.drawn_x.extend(x);
            self.drawn_y.push(y);
        }
    }

    fn train_len(&self) -> usize {
        self.real_len() + self.drawn_y.len()
    }

    fn planned_train_len(&self) -> usize {
        self.real_len() + self.source.examples.generated_per_epoch
    }

    fn validation_len(&self) -> usize {
        self.validation_y.len()
    }

    fn train_batch(&self, ids: &[usize]) -> (Vec<f32>, Vec<f32>) {
        let w = self.shape()[1];
        let mut x = Vec::with_capacity(ids.len() * w);
        let mut y = Vec::with_capacity(ids.len() * NUM_LABELS);
        for &i in ids {
            let (xs, label) = match i.checked_sub(self.real_len()) {
                None => (&self.real_x[i * w..(i + 1) * w], &self.real_y[i]),
                Some(d) => (&self.drawn_x[d * w..(d + 1) * w], &self.drawn_y[d]),
            };
            x.extend_from_slice(xs);
            y.extend(self.standardizer.targets(label));
        }
        (x, y)
    }

    fn validation_inputs(&self, ids: std::ops::Range<usize>) -> Vec<f32> {
        let per = self.shape()[0] * self.shape()[1];
        self.validation_x[ids.start * per..ids.end * per].to_vec()
    }

    fn validation_labels(&self) -> Vec<[f64; NUM_LABELS]> {
        self.validation_y.clone()
    }
}
