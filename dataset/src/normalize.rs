//! Feature filtering and standardisation, with statistics from the training split only (stored with a model so
//! inference applies the same transform).
//!
//! Columns whose training values are constant (to 1e-12 of their magnitude) carry no information and are dropped;
//! the others, and every label, are standardised to zero mean and unit variance.

use dynforge_proto::NUM_LABELS;

use crate::cache::windows::CachedWindows;
use crate::split::{Split, SplitRule};

/// Per-column and per-label mean and standard deviation, and the kept columns.
#[derive(Debug, Clone, PartialEq)]
pub struct Standardizer {
    /// Indices of the kept input columns.
    pub columns: Vec<usize>,
    pub mean: Vec<f64>,
    pub std: Vec<f64>,
    pub label_mean: [f64; NUM_LABELS],
    pub label_std: [f64; NUM_LABELS],
}

/// Window indices of each side of the split `rule`.
pub fn split_windows(w: &CachedWindows, rule: &SplitRule) -> (Vec<usize>, Vec<usize>) {
    let origins = w.origins();
    (0..w.count()).partition(|&i| rule.side(origins[i]) == Split::Train)
}

fn mean_std(sum: f64, sum2: f64, n: f64) -> (f64, f64) {
    let mean = sum / n;
    (mean, (sum2 / n - mean * mean).max(0.0).sqrt())
}

impl Standardizer {
    /// A placeholder with no columns, to be replaced by a fitted one.
    pub fn fit_empty() -> Standardizer {
        Standardizer {
            columns: Vec::new(),
            mean: Vec::new(),
            std: Vec::new(),
            label_mean: [0.0; NUM_LABELS],
            label_std: [1.0; NUM_LABELS],
        }
    }

    /// Statistics of the windows `train` of `w`.
    pub fn fit(w: &CachedWindows, train: &[usize]) -> Standardizer {
        let (len, width) = (w.spec.len, w.width);
        let mut s = vec![0.0f64; width];
        let mut s2 = vec![0.0f64; width];
        let (mut lo, mut hi) = (vec![f64::INFINITY; width], vec![f64::NEG_INFINITY; width]);
        for &i in train {
            for row in w.data[i * len * width..(i + 1) * len * width].chunks_exact(width) {
                for (c, &v) in row.iter().enumerate() {
                    let v = v as f64;
                    s[c] += v;
                    s2[c] += v * v;
                    lo[c] = lo[c].min(v);
                    hi[c] = hi[c].max(v);
                }
            }
        }
        let n = (train.len() * len).max(1) as f64;
        let columns: Vec<usize> =
            (0..width).filter(|&c| hi[c] - lo[c] > 1e-12 * hi[c].abs().max(lo[c].abs()).max(1e-30)).collect();
        let (mean, std): (Vec<f64>, Vec<f64>) = columns.iter().map(|&c| mean_std(s[c], s2[c], n)).unzip();
        let (mut label_mean, mut label_std) = ([0.0; NUM_LABELS], [1.0; NUM_LABELS]);
        for k in 0..NUM_LABELS {
            let (a, b) = train.iter().map(|&i| w.labels[i][k]).fold((0.0, 0.0), |(a, b), v| (a + v, b + v * v));
            let (m, sd) = mean_std(a, b, train.len().max(1) as f64);
            label_mean[k] = m;
            label_std[k] = if sd > 0.0 { sd } else { 1.0 };
        }
        Standardizer { columns, mean, std, label_mean, label_std }
    }

    /// Label statistics of `labels` alone (no input columns yet).
    pub fn fit_labels<'a>(labels: impl Iterator<Item = &'a [f64; NUM_LABELS]>) -> Standardizer {
        let (mut s, mut s2, mut n) = ([0.0; NUM_LABELS], [0.0; NUM_LABELS], 0usize);
        for y in labels {
            for k in 0..NUM_LABELS {
                s[k] += y[k];
                s2[k] += y[k] * y[k];
            }
            n += 1;
        }
        let mut out = Standardizer::fit_empty();
        for k in 0..NUM_LABELS {
            let (m, sd) = mean_std(s[k], s2[k], n.max(1) as f64);
            out.label_mean[k] = m;
            out.label_std[k] = if sd > 0.0 { sd } else { 1.0 };
        }
        out
    }

    /// `labels` (from [`Self::fit_labels`]) with input statistics over `rows`: every column is kept; the first
    /// `standardised` are standardised, the rest pass unchanged (mean 0, deviation 1), e.g. values already in
    /// standardised label units.
    pub fn fit_columns<'a>(
        labels: Standardizer,
        rows: impl Iterator<Item = &'a [f32]>,
        standardised: usize,
    ) -> Standardizer {
        let (mut s, mut s2, mut n, mut width) = (Vec::<f64>::new(), Vec::<f64>::new(), 0usize, 0usize);
        for row in rows {
            if s.is_empty() {
                width = row.len();
                (s, s2) = (vec![0.0; width], vec![0.0; width]);
            }
            for (c, &v) in row.iter().enumerate() {
                s[c] += v as f64;
                s2[c] += v as f64 * v as f64;
            }
            n += 1;
        }
        let (mean, std) = (0..width)
            .map(|c| match c < standardised {
                true => mean_std(s[c], s2[c], n.max(1) as f64),
                false => (0.0, 1.0),
            })
            .map(|(m, sd)| (m, if sd > 0.0 { sd } else { 1.0 }))
            .unzip();
        Standardizer { columns: (0..width).collect(), mean, std, ..labels }
    }

    /// One input row (all columns of the raw row), filtered and standardised.
    pub fn row(&self, raw: &[f32]) -> Vec<f32> {
        self.columns.iter().enumerate().map(|(k, &c)| ((raw[c] as f64 - self.mean[k]) / self.std[k]) as f32).collect()
    }

    /// Standardised, filtered inputs of window `i`: `len x columns.len()` values.
    pub fn inputs(&self, w: &CachedWindows, i: usize) -> Vec<f32> {
        let (len, width) = (w.spec.len, w.width);
        let mut out = Vec::with_capacity(len * self.columns.len());
        for row in w.data[i * len * width..(i + 1) * len * width].chunks_exact(width) {
            out.extend(self.row(row));
        }
        out
    }

    /// Standardised labels.
    pub fn targets(&self, y: &[f64; NUM_LABELS]) -> [f32; NUM_LABELS] {
        std::array::from_fn(|k| ((y[k] - self.label_mean[k]) / self.label_std[k]) as f32)
    }

    /// Physical labels from standardised ones.
    pub fn labels(&self, t: &[f32; NUM_LABELS]) -> [f64; NUM_LABELS] {
        std::array::from_fn(|k| t[k] as f64 * self.label_std[k] + self.label_mean[k])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::window::WindowSpec;

    fn windows() -> CachedWindows {
        // 4 windows of 2 steps x 3 columns: column 1 is constant, labels vary with the window.
        let mut data = Vec::new();
        for i in 0..4 {
            for t in 0..2 {
                data.extend([i as f32 + t as f32, 7.0, -(i as f32) * 2.0]);
            }
        }
        CachedWindows {
            spec: WindowSpec::new(2, 1, 1),
            width: 3,
            data,
            labels: (0..4).map(|i| [i as f64; NUM_LABELS]).collect(),
            robots: vec![10, 11, 12, 13],
            trajectories: vec![0; 4],
            hit: false,
        }
    }

    #[test]
    fn constant_columns_are_dropped_and_the_rest_standardised_on_training_windows_only() {
        let w = windows();
        let s = Standardizer::fit(&w, &[0, 1, 2]);
        assert_eq!(s.columns, [0, 2]);
        // Column 0 over windows 0-2: values 0,1,1,2,2,3 -> mean 1.5; column 2: 0,0,-2,-2,-4,-4 -> mean -2.
        assert!((s.mean[0] - 1.5).abs() < 1e-12 && (s.mean[1] + 2.0).abs() < 1e-12);
        let all: Vec<f32> = (0..3).flat_map(|i| s.inputs(&w, i)).collect();
        let col = |k: usize| all.iter().skip(k).step_by(2).map(|v| *v as f64).collect::<Vec<_>>();
        for k in 0..2 {
            let c = col(k);
            let m = c.iter().sum::<f64>() / c.len() as f64;
            let v = c.iter().map(|x| (x - m).powi(2)).sum::<f64>() / c.len() as f64;
            assert!(m.abs() < 1e-6 && (v - 1.0).abs() < 1e-6, "column {k}: mean {m}, var {v}");
        }
        // Window 3 was not used: its statistics did not enter (label mean of windows 0-2 is 1).
        assert!((s.label_mean[0] - 1.0).abs() < 1e-12);
        let y = [3.0; NUM_LABELS];
        let back = s.labels(&s.targets(&y));
        assert!(back.iter().all(|v| (v - 3.0).abs() < 1e-6));
    }

    #[test]
    fn no_robot_is_on_both_sides_of_the_split() {
        let mut w = windows();
        w.robots = (0..4).map(|i| i / 2).collect(); // two windows per robot
        for seed in 0..20 {
            let (train, val) = split_windows(&w, &SplitRule::robots(seed, 0.5));
            assert_eq!(train.len() + val.len(), 4);
            for &t in &train {
                assert!(val.iter().all(|&v| w.robots[v] != w.robots[t]), "seed {seed}");
            }
        }
    }
}
