//! The transformer's examples: the windows of a dataset, split (by robot unless asked otherwise) and standardised.
//! With `--follow` it grows between epochs as the generation adds shards.

use dynforge_proto::NUM_LABELS;

use super::Examples;
use crate::cache::Skipped;
use crate::cache::windows::CachedWindows;
use crate::features::JacobianFeatures;
use crate::normalize::Standardizer;
use crate::split::{Origin, Split, SplitRule, segments};

/// Windows split and standardised, ready for batches.
pub struct Corpus {
    pub windows: CachedWindows,
    pub train: Vec<usize>,
    pub validation: Vec<usize>,
    pub standardizer: Standardizer,
}

impl Corpus {
    /// Adds the windows of the dataset shards `paths`, each to its side of the split `rule`. Shards that cannot be
    /// read, or are not dataset shards, are skipped and returned with the reason.
    pub fn add_shards(
        &mut self,
        paths: &[std::path::PathBuf],
        features: &JacobianFeatures,
        rule: &SplitRule,
    ) -> Vec<Skipped> {
        let mut skipped = Vec::new();
        for added in self.windows.add_shards(paths, features) {
            match added {
                // A shard is one recording: its windows are listed as `WindowSpec::windows` lists them.
                Ok((robot, new)) => {
                    for (segment, i) in segments(new.len(), &self.windows.spec).into_iter().zip(new) {
                        let trajectory = self.windows.trajectories[i];
                        match rule.side(Origin { robot, trajectory, segment }) {
                            Split::Train => self.train.push(i),
                            Split::Validation => self.validation.push(i),
                        }
                    }
                }
                Err(why) => skipped.push(why),
            }
        }
        skipped
    }
}

impl Examples for Corpus {
    fn shape(&self) -> [usize; 2] {
        [self.windows.spec.len, self.standardizer.columns.len()]
    }

    fn standardizer(&self) -> &Standardizer {
        &self.standardizer
    }

    fn train_len(&self) -> usize {
        self.train.len()
    }

    fn validation_len(&self) -> usize {
        self.validation.len()
    }

    fn train_batch(&self, ids: &[usize]) -> (Vec<f32>, Vec<f32>) {
        let [len, width] = self.shape();
        let mut x = Vec::with_capacity(ids.len() * len * width);
        let mut y = Vec::with_capacity(ids.len() * NUM_LABELS);
        for &i in ids {
            let w = self.train[i];
            x.extend(self.standardizer.inputs(&self.windows, w));
            y.extend(self.standardizer.targets(&self.windows.labels[w]));
        }
        (x, y)
    }

    fn validation_inputs(&self, ids: std::ops::Range<usize>) -> Vec<f32> {
        self.validation[ids].iter().flat_map(|&i| self.standardizer.inputs(&self.windows, i)).collect()
    }

    fn validation_labels(&self) -> Vec<[f64; NUM_LABELS]> {
        self.validation.iter().map(|&i| self.windows.labels[i]).collect()
    }
}
