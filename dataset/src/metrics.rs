//! R2 and RMSE per target, and their overall values; and a training run's history per epoch (`metrics.csv`,
//! `metrics.json`).
//!
//! Averaging, stated once: per-target R2 = 1 - SS_res / SS_tot over the evaluated windows (SS_tot about the
//! evaluated windows' own mean, as scikit-learn's `r2_score`); overall R2 = the unweighted mean of the 38 per-target
//! values (scikit-learn's `uniform_average`). RMSE is reported in standardised units (target minus the training
//! mean, divided by the training standard deviation), so targets of different units and magnitudes compare and
//! average; overall RMSE = sqrt of the mean of the 38 per-target mean squared errors. Per-target RMSE is also kept in
//! physical units.

use std::path::{Path, PathBuf};

use dynforge_proto::NUM_LABELS;
use dynforge_proto::run_dir::write_atomic;
use serde::{Deserialize, Serialize};

/// Scores of one target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TargetScore {
    pub r2: f64,
    /// RMSE in standardised units.
    pub rmse: f64,
    /// RMSE in the label's SI unit.
    pub rmse_si: f64,
}

/// Scores of all targets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    pub targets: Vec<TargetScore>,
    pub r2: f64,
    pub rmse: f64,
    /// Samples (windows, or recordings) scored.
    pub count: usize,
}

/// Scores of predictions against truths, both in SI units; `scale[k]` is the training standard deviation of
/// target k (the standardisation scale).
pub fn score(predicted: &[[f64; NUM_LABELS]], truth: &[[f64; NUM_LABELS]], scale: &[f64; NUM_LABELS]) -> Scores {
    assert_eq!(predicted.len(), truth.len(), "one prediction per truth");
    let n = truth.len().max(1) as f64;
    let targets: Vec<TargetScore> = (0..NUM_LABELS)
        .map(|k| {
            // Shifted by the first value, so a constant target has SS_tot exactly 0 (a plain mean of n equal
            // values can be off by an ulp, and 1 - SS_res / 1e-32 is no score).
            let origin = truth.first().map_or(0.0, |t| t[k]);
            let mean = origin + truth.iter().map(|t| t[k] - origin).sum::<f64>() / n;
            let ss_tot: f64 = truth.iter().map(|t| (t[k] - mean).powi(2)).sum();
            let ss_res: f64 = predicted.iter().zip(truth).map(|(p, t)| (p[k] - t[k]).powi(2)).sum();
            let rmse_si = (ss_res / n).sqrt();
            // A constant target is predicted perfectly or not at all.
            let r2 = if ss_tot > 0.0 {
                1.0 - ss_res / ss_tot
            } else if ss_res == 0.0 {
                1.0
            } else {
                f64::NEG_INFINITY
            };
            TargetScore { r2, rmse: rmse_si / scale[k], rmse_si }
        })
        .collect();
    let r2 = targets.iter().map(|t| t.r2).sum::<f64>() / NUM_LABELS as f64;
    let rmse = (targets.iter().map(|t| t.rmse * t.rmse).sum::<f64>() / NUM_LABELS as f64).sqrt();
    Scores { targets, r2, rmse, count: truth.len() }
}

/// JSON has no infinities or NaN (serde_json writes them as null): read null back as NaN.
fn nullable<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// One epoch's figures, as written to metrics.csv / metrics.json.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochMetrics {
    pub epoch: usize,
    pub step: usize,
    pub lr: f64,
    pub train_loss: f64,
    pub validation_loss: f64,
    /// -inf when a target is constant over the validation windows (a single validation robot).
    #[serde(deserialize_with = "nullable")]
    pub validation_r2: f64,
    pub validation_rmse: f64,
    pub windows_per_second: f64,
    /// Wall-clock seconds of this epoch: preparing its examples and its training steps (not validation).
    pub seconds: f64,
    /// Process CPU seconds (user + system, all threads) of the same span: the cost measure for comparing designs on
    /// accuracy per CPU-hour.
    #[serde(default)]
    pub cpu_seconds: f64,
}

/// The epoch's line of a training log.
impl std::fmt::Display for EpochMetrics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "epoch {:>3}: train loss {:.4}, validation loss {:.4}, R2 {:.4}, RMSE {:.4}, {:.0} examples/s, {:.1} s ({:.1} \
             CPU s)",
            self.epoch,
            self.train_loss,
            self.validation_loss,
            self.validation_r2,
            self.validation_rmse,
            self.windows_per_second,
            self.seconds,
            self.cpu_seconds
        )
    }
}

/// Writes a run's history into its directory `dir` as `metrics.csv` and `metrics.json` (atomically); on failure the
/// file and the error.
pub fn write_history(dir: &Path, history: &[EpochMetrics]) -> Result<(), (PathBuf, std::io::Error)> {
    let mut csv = String::from(
        "epoch,step,lr,train_loss,validation_loss,validation_r2,validation_rmse,windows_per_second,seconds,cpu_seconds\n",
    );
    for m in history {
        csv.push_str(&format!(
            "{},{},{:.6e},{:.6},{:.6},{:.6},{:.6},{:.1},{:.2},{:.2}\n",
            m.epoch,
            m.step,
            m.lr,
            m.train_loss,
            m.validation_loss,
            m.validation_r2,
            m.validation_rmse,
            m.windows_per_second,
            m.seconds,
            m.cpu_seconds
        ));
    }
    let at = |name: &str| {
        let path = dir.join(name);
        move |e: std::io::Error| (path, e)
    };
    write_atomic(&dir.join("metrics.csv"), csv.as_bytes()).map_err(at("metrics.csv"))?;
    let json = serde_json::to_vec_pretty(history).map_err(|e| at("metrics.json")(std::io::Error::other(e)))?;
    write_atomic(&dir.join("metrics.json"), &json).map_err(at("metrics.json"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_a_hand_computed_example() {
        // Target 0: truths 1, 2, 3, 4 (mean 2.5, SS_tot 5); predictions 1, 2, 3, 5 (SS_res 1): R2 = 0.8,
        // RMSE = sqrt(1/4) = 0.5, standardised by scale 2: 0.25. Every other target is predicted exactly (R2 = 1,
        // RMSE 0). Overall R2 = (0.8 + 37) / 38; overall RMSE = sqrt(0.25^2 / 38).
        let truth: Vec<[f64; NUM_LABELS]> = (1..=4).map(|v| [v as f64; NUM_LABELS]).collect();
        let mut predicted = truth.clone();
        predicted[3][0] = 5.0;
        let scale = [2.0; NUM_LABELS];
        let s = score(&predicted, &truth, &scale);
        assert!((s.targets[0].r2 - 0.8).abs() < 1e-15);
        assert!((s.targets[0].rmse_si - 0.5).abs() < 1e-15 && (s.targets[0].rmse - 0.25).abs() < 1e-15);
        assert!(s.targets[1..].iter().all(|t| t.r2 == 1.0 && t.rmse == 0.0));
        assert!((s.r2 - 37.8 / 38.0).abs() < 1e-15);
        assert!((s.rmse - (0.0625f64 / 38.0).sqrt()).abs() < 1e-15);
        assert_eq!(s.count, 4);
    }

    #[test]
    fn a_constant_target_is_perfect_or_minus_infinity_never_a_huge_number() {
        // 0.1 summed 7 times and divided by 7 is not 0.1 in f64: a naive mean gives SS_tot ~ 1e-34.
        let truth: Vec<[f64; NUM_LABELS]> = vec![[0.1; NUM_LABELS]; 7];
        let mut predicted = truth.clone();
        assert!(score(&predicted, &truth, &[1.0; NUM_LABELS]).targets.iter().all(|t| t.r2 == 1.0));
        predicted[0][3] = 0.2;
        assert_eq!(score(&predicted, &truth, &[1.0; NUM_LABELS]).targets[3].r2, f64::NEG_INFINITY);
    }

    #[test]
    fn predicting_the_mean_scores_zero_and_worse_is_negative() {
        let truth: Vec<[f64; NUM_LABELS]> = (0..10).map(|v| [v as f64; NUM_LABELS]).collect();
        let mean = vec![[4.5; NUM_LABELS]; 10];
        assert!(score(&mean, &truth, &[1.0; NUM_LABELS]).r2.abs() < 1e-15);
        let reversed: Vec<_> = truth.iter().rev().copied().collect();
        assert!(score(&reversed, &truth, &[1.0; NUM_LABELS]).r2 < -1.0);
    }
}
