//! What the estimators train on: standardised examples of both sides of the robot-level split. The transformer's
//! are windows ([`corpus::Corpus`]); the physics estimator's are pieces of evidence, real and drawn from the
//! generator ([`generated::PhysicsExamples`]). The training loop (`dynforge_trainer::training`) sees only
//! [`Examples`].

pub mod corpus;
pub mod generated;

use dynforge_proto::NUM_LABELS;
use serde::{Deserialize, Serialize};

use crate::normalize::Standardizer;

/// What a run trains on: standardised examples of both splits.
pub trait Examples: Sync {
    /// The shape of one example's input, `[steps, values per step]`.
    fn shape(&self) -> [usize; 2];
    /// The statistics that standardise inputs and labels.
    fn standardizer(&self) -> &Standardizer;
    /// Prepares epoch `epoch` (e.g. draws its generated examples); called before its first batch, also on resume.
    fn begin_epoch(&mut self, _epoch: usize) {}
    fn train_len(&self) -> usize;
    /// Training examples an epoch will have, known before [`Examples::begin_epoch`] draws any.
    fn planned_train_len(&self) -> usize {
        self.train_len()
    }
    fn validation_len(&self) -> usize;
    /// Standardised inputs and targets of training examples `ids` (`0..train_len()`), concatenated.
    fn train_batch(&self, ids: &[usize]) -> (Vec<f32>, Vec<f32>);
    /// Standardised inputs of validation examples `ids` (`0..validation_len()`), concatenated: asked for a chunk at
    /// a time, so that the validation set (a fifth of 16 GB of windows at the paper's scale) is never copied whole.
    fn validation_inputs(&self, ids: std::ops::Range<usize>) -> Vec<f32>;
    /// The labels [SI] of every validation example.
    fn validation_labels(&self) -> Vec<[f64; NUM_LABELS]>;
}

/// What the physics estimator trains on besides its prior, as a checkpoint records it (a resumed run says when it
/// changes).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExampleRecord {
    /// Robots drawn from the generator per epoch.
    pub generated_per_epoch: usize,
    /// Whether the dataset's training windows, recordings and robots were trained on too.
    pub real: bool,
    /// Whether half the generated robots carried torque noise.
    #[serde(default)]
    pub noisy: bool,
}
