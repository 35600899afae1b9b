//! What a robot's family (`generate --urdf`) teaches identification about that robot: how far `identify`'s values
//! lie from the truth, per parameter, at the noise of the user's bag.
//!
//! The family's variants are drawn from the prior `identify` assumes, so its maximum a posteriori values are already
//! the best the torques and the URDF allow; what a Laplace approximation cannot promise is that its standard
//! deviations hold: along directions the torques pin only in combination, the log-Cholesky map curves, and a
//! mass the posterior calls known within 5 % may be off by 8 %. The family measures it: every variant is degraded
//! as the bag is (its effort noise, its encoder, its velocity from positions), identified from the URDF as the bag
//! is, and each parameter's standardized errors `z = (value - truth) / std` give the factor its spread needs
//! ([`FamilySpreads`]).

use std::path::Path;

use dynforge_proto::run_dir::{SHARDS, write_atomic};
use dynforge_proto::{content_hash, content_hash_hex};
use dynforge_recording::dataset::shards_by_robot;
use dynforge_recording::log::{Log, read_log, read_logs};
use dynforge_recording::{JointTrajectory, ReadError, Reading};
use dynforge_robot::rng::Rng;

use super::report::{Decided, INFORMED, Identification, Kind};
use super::{Options, identify_read};
use crate::signals::{EffortConvention, effort_noise};

/// How a bag's signals differ from a simulation's exact ones, to be done to a variant's logs: the effort's
/// convention, white effort noise and encoder quantization, per joint.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Degradation {
    /// How the bag's effort was taken. A family's simulation holds each torque over its step; a torque sampled at
    /// `t_i` is, between the step before and the step after, their mean.
    pub effort: EffortConvention,
    /// White effort noise [N m or N] per joint.
    pub effort_noise: Vec<f64>,
    /// Encoder step [rad or m] per joint, where the bag's positions are quantized.
    pub encoder_step: Vec<Option<f64>>,
}

/// Share of a joint's positions that must lie on a grid for it to be taken as an encoder's.
const ON_GRID: f64 = 0.99;

impl Degradation {
    /// The degradation the logs show: each joint's white effort noise (its median second difference) and its
    /// encoder step (the smallest position change, when [`ON_GRID`] of the positions are multiples of it).
    pub fn of(logs: &[Log], effort: EffortConvention) -> Self {
        Self::of_segments(&logs.iter().flat_map(|l| &l.segments).collect::<Vec<_>>(), effort)
    }

    fn of_segments(segments: &[&JointTrajectory], effort: EffortConvention) -> Self {
        let n = segments.first().map_or(0, |s| s.joints());
        let effort_noise = effort_noise(segments).into_iter().map(|(sigma, _)| sigma).collect();
        let encoder_step = (0..n)
            .map(|j| {
                let positions = || segments.iter().flat_map(|s| s.q.iter().skip(j).step_by(n));
                let changes = segments.iter().flat_map(|s| s.q.chunks(n).zip(s.q.chunks(n).skip(1)));
                let step = changes.map(|(a, b)| (b[j] - a[j]).abs()).filter(|d| *d > 0.0).fold(f64::INFINITY, f64::min);
                if !step.is_finite() {
                    return None;
                }
                let (total, on) = positions().fold((0usize, 0usize), |(total, on), q| {
                    let k = q / step;
                    (total + 1, on + usize::from((k - k.round()).abs() < GRID_TOLERANCE))
                });
                (on as f64 >= ON_GRID * total as f64).then_some(step)
            })
            .collect();
        Degradation { effort, effort_noise, encoder_step }
    }

    /// `log` as the bag's driver would have written it: noise on every effort (a stream of `seed`), positions on the
    /// encoder's grid.
    pub fn apply(&self, log: &mut Log, seed: u64) {
        for (k, seg) in log.segments.iter_mut().enumerate() {
            self.apply_to(seg, &mut Rng::stream(seed, &[k as u64]));
        }
    }

    fn apply_to(&self, seg: &mut JointTrajectory, rng: &mut Rng) {
        let n = seg.joints();
        if self.effort == EffortConvention::Sampled {
            for i in (n..seg.tau.len()).rev() {
                seg.tau[i] = 0.5 * (seg.tau[i] + seg.tau[i - n]);
            }
        }
        for (i, tau) in seg.tau.iter_mut().enumerate() {
            *tau += self.effort_noise.get(i % n).copied().unwrap_or(0.0) * rng.normal();
        }
        for (i, q) in seg.q.iter_mut().enumerate() {
            if let Some(Some(step)) = self.encoder_step.get(i % n) {
                *q = (*q / step).round() * step;
            }
        }
    }
}

/// How close to a multiple of the step (in steps) a quantized position is: an encoder's count times its step,
/// rounded to a double, is within ~1e-10 steps of it at a thousand revolutions.
const GRID_TOLERANCE: f64 = 1e-6;

/// One parameter's standardized errors over a family's variants, and the factor its spread is given.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ParameterSpread {
    pub name: String,
    pub kind: Kind,
    /// The factor the identification's standard deviation needs on the family.
    pub factor: f64,
    /// Mean of `z` (a bias, in standard deviations) and the share of variants within one and two standard
    /// deviations before the factor.
    pub mean_z: f64,
    pub within_1: f64,
    pub within_2: f64,
}

impl ParameterSpread {
    /// The factor applied: the family's, where it widens the spread.
    pub fn applied(&self) -> f64 {
        self.factor.max(1.0)
    }
}

/// Factors for the spreads of one robot's identification, measured on its family.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FamilySpreads {
    /// Variants identified, and refused (a variant whose logs the identification refused).
    pub variants: usize,
    pub refused: usize,
    pub parameters: Vec<ParameterSpread>,
}

/// Fewest identified variants a factor is measured from: the 95th percentile of 32 values is their second largest.
pub const MIN_VARIANTS: usize = 32;

/// Why a calibration of spreads could not be made or applied.
#[derive(Debug, thiserror::Error)]
pub enum SpreadError {
    #[error("{0} variants identified: at least {MIN_VARIANTS} are needed to measure a spread (generate more)")]
    TooFew(usize),
    #[error("the family's parameters ({0}) are not the identification's ({1}): a family of another robot")]
    Mismatch(String, String),
}

/// Why a family's spreads could not be measured.
#[derive(Debug, thiserror::Error)]
pub enum MeasureError {
    #[error("reading {dir}: {source}")]
    Shards { dir: String, source: std::io::Error },
    #[error(
        "a shard of the robot's family cannot be read: delete {dir} and run again (the family is made anew): {source}"
    )]
    Damaged { dir: String, source: ReadError },
    #[error(transparent)]
    Spread(#[from] SpreadError),
    #[error("writing {file}: {source}")]
    Write { file: String, source: std::io::Error },
}

/// What measuring a family's spreads says as it goes.
pub trait MeasureObserver {
    /// The spreads were measured before with the same settings: read from `path`.
    fn reused(&mut self, path: &Path);
    /// Variant `k` of `of` is being identified.
    fn variant(&mut self, k: usize, of: usize);
    /// Robot `robot`'s variant was refused by the identification.
    fn refused(&mut self, robot: u64, why: &str);
    /// Every variant has been identified.
    fn done(&mut self);
}

impl FamilySpreads {
    /// The spread factors of the family in `dir` at `degradation`, identified with `options` from the URDF
    /// `document`: read from the family's cache when measured before with the same settings, else measured and kept
    /// there.
    pub fn measure(
        dir: &Path,
        document: Option<(&str, &str)>,
        degradation: &Degradation,
        options: &Options,
        observer: &mut dyn MeasureObserver,
    ) -> Result<Self, MeasureError> {
        let key = serde_json::json!({
            "degradation": degradation,
            "conditioning": format!("{:?}", options.conditioning),
            "spread": options.spread,
            "fixed": options.reading.fixed,
            "urdf": document.map(|(text, _)| content_hash(text.as_bytes())),
            "version": env!("CARGO_PKG_VERSION"),
        });
        let path = dir.join(format!("spreads-{}.json", content_hash_hex(key.to_string().as_bytes())));
        if let Ok(text) = std::fs::read_to_string(&path)
            && let Ok(spreads) = serde_json::from_str::<FamilySpreads>(&text)
        {
            observer.reused(&path);
            return Ok(spreads);
        }
        let shards = shards_by_robot(dir)
            .map_err(|source| MeasureError::Shards { dir: dir.join(SHARDS).display().to_string(), source })?;
        let damaged = |source| MeasureError::Damaged { dir: dir.display().to_string(), source };
        // The family's shards are torque logs as dynforge writes them, whatever the user's logs are.
        let reading = Reading::welding(&options.reading.fixed);
        let (mut pairs, mut refused) = (Vec::new(), 0);
        for (k, (r, mine)) in shards.iter().enumerate() {
            observer.variant(k, shards.len());
            let mut logs = read_logs(mine, document, &reading).map_err(damaged)?;
            for (k, log) in logs.iter_mut().enumerate() {
                degradation.apply(log, content_hash(format!("variant {r} log {k}").as_bytes()));
            }
            match identify_read(logs, options) {
                Ok((id, _)) => {
                    let mut truth: Identification = id.clone();
                    truth.report_values_of(&read_log(&mine[0], None, &reading).map_err(damaged)?.model);
                    pairs.push((id, truth));
                }
                Err(e) => {
                    refused += 1;
                    observer.refused(*r, &e.to_string());
                }
            }
        }
        observer.done();
        let spreads = FamilySpreads::fit(&pairs, refused)?;
        let text = serde_json::to_string_pretty(&spreads).expect("spreads serialize");
        write_atomic(&path, text.as_bytes())
            .map_err(|source| MeasureError::Write { file: path.display().to_string(), source })?;
        Ok(spreads)
    }

    /// The factors from identified variants and the same identifications with the truth's values in place of
    /// theirs (`Identification::report_values_of` the variant): per parameter, the smallest factor that puts 68 %
    /// of the variants within one standard deviation and 95 % within two (the empirical quantiles of `|z|`).
    pub fn fit(pairs: &[(Identification, Identification)], refused: usize) -> Result<Self, SpreadError> {
        let Some((first, _)) = pairs.first() else { return Err(SpreadError::TooFew(0)) };
        let names: Vec<_> = first.parameters().into_iter().map(|p| (p.name, p.kind)).collect();
        let mut zs = vec![Vec::with_capacity(pairs.len()); names.len()];
        for (id, truth) in pairs {
            let (got, want) = (id.parameters(), truth.parameters());
            if got.len() != names.len() || want.len() != names.len() {
                return Err(SpreadError::Mismatch(names.len().to_string(), got.len().to_string()));
            }
            for ((z, e), t) in zs.iter_mut().zip(got).zip(want) {
                z.push(e.estimate.z(t.estimate.value));
            }
        }
        Self::of_z(names, &zs, refused)
    }

    /// The factors from each parameter's standardized errors `zs` over the variants.
    fn of_z(names: Vec<(String, Kind)>, zs: &[Vec<f64>], refused: usize) -> Result<Self, SpreadError> {
        let variants = zs.first().map_or(0, Vec::len);
        if variants < MIN_VARIANTS {
            return Err(SpreadError::TooFew(variants));
        }
        let parameters = names
            .into_iter()
            .zip(zs)
            .map(|((name, kind), z)| {
                let mut abs: Vec<f64> = z.iter().map(|v| v.abs()).collect();
                abs.sort_by(f64::total_cmp);
                let quantile = |p: f64| abs[((p * abs.len() as f64).ceil() as usize).clamp(1, abs.len()) - 1];
                let within = |c: f64| abs.iter().filter(|&&v| v < c).count() as f64 / abs.len() as f64;
                let factor = quantile(0.68).max(quantile(0.95) / 2.0);
                let mean_z = z.iter().sum::<f64>() / z.len() as f64;
                ParameterSpread {
                    name,
                    kind,
                    factor: if factor.is_finite() && factor > 0.0 { factor } else { 1.0 },
                    mean_z,
                    within_1: within(1.0),
                    within_2: within(2.0),
                }
            })
            .collect();
        Ok(FamilySpreads { variants, refused, parameters })
    }

    /// `id`'s spreads widened by their factors (a factor under one is not applied: the family is simulated with the
    /// model `identify` fits, so it cannot show how far a real robot departs from it, which only adds error); what
    /// decided each parameter judged again on the new spread.
    pub fn apply(&self, id: &mut Identification) -> Result<(), SpreadError> {
        let names: Vec<String> = id.parameters().into_iter().map(|p| p.name).collect();
        if names.len() != self.parameters.len() || names.iter().zip(&self.parameters).any(|(a, b)| *a != b.name) {
            let first = |v: &mut dyn Iterator<Item = String>| v.take(3).collect::<Vec<_>>().join(", ");
            return Err(SpreadError::Mismatch(
                first(&mut self.parameters.iter().map(|p| p.name.clone())),
                first(&mut names.into_iter()),
            ));
        }
        for (e, p) in id.estimates_mut().zip(&self.parameters) {
            e.std *= p.applied();
            e.decided = if e.std < INFORMED * e.prior_std { Decided::Torques } else { Decided::Prior };
        }
        Ok(())
    }

    /// A kind's parameters: how many, the median factor the family measured, and how many were widened.
    pub fn of_kind(&self, kind: Kind) -> (usize, f64, usize) {
        let mut f: Vec<f64> = self.parameters.iter().filter(|p| p.kind == kind).map(|p| p.factor).collect();
        f.sort_by(f64::total_cmp);
        let widened = f.iter().filter(|v| **v > 1.0).count();
        (f.len(), f.get(f.len() / 2).copied().unwrap_or(1.0), widened)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Errors drawn twice as wide as the spreads said get a factor of ~2, and a factor applied puts ~68 % and ~95 %
    /// of them within one and two: the 68th percentile of 4,000 |z| has a standard error of ~0.7 % of the
    /// quantile's probability, ~2 % of its value; 5 % is 2.5 standard errors.
    #[test]
    fn errors_twice_as_wide_as_the_spreads_get_a_factor_of_two() {
        let mut rng = Rng::stream(3, &[]);
        let n = 4000;
        let zs = vec![
            (0..n).map(|_| 2.0 * rng.normal()).collect::<Vec<f64>>(),
            (0..n).map(|_| 0.5 * rng.normal()).collect(),
        ];
        let names = vec![("a.mass".to_string(), Kind::Mass), ("j.coulomb".to_string(), Kind::Friction)];
        let c = FamilySpreads::of_z(names, &zs, 0).unwrap();
        assert!((c.parameters[0].factor - 2.0).abs() < 0.1, "{:?}", c.parameters[0]);
        assert!((c.parameters[1].factor - 0.5).abs() < 0.025, "{:?}", c.parameters[1]);
        // Before: half of the wide errors within one; after, 68 %.
        assert!((c.parameters[0].within_1 - 0.383).abs() < 0.03, "{:?}", c.parameters[0]);
        for (p, z) in c.parameters.iter().zip(&zs) {
            let within = |k: f64| z.iter().filter(|v| (*v / p.factor).abs() < k).count() as f64 / n as f64;
            assert!(
                (within(1.0) - 0.68).abs() < 0.01 && within(2.0) > 0.94,
                "{}: {} {}",
                p.name,
                within(1.0),
                within(2.0)
            );
        }
    }

    #[test]
    fn too_few_variants_are_refused() {
        let zs = vec![vec![1.0; MIN_VARIANTS - 1]];
        let err = FamilySpreads::of_z(vec![("a.mass".into(), Kind::Mass)], &zs, 0).unwrap_err();
        assert!(matches!(err, SpreadError::TooFew(n) if n == MIN_VARIANTS - 1), "{err}");
    }

    /// The step of a 2^17-count encoder is found from quantized positions, not from exact ones, and noise put on
    /// an exact effort is measured back at its level (the median-based estimate's standard error at 20,000 samples
    /// is ~1 %).
    #[test]
    fn an_encoders_step_and_the_effort_noise_are_measured_and_applied() {
        let step = std::f64::consts::TAU / 131072.0;
        let len = 20_000;
        let t: Vec<f64> = (0..len).map(|i| i as f64 * 1e-3).collect();
        let q: Vec<f64> = t.iter().flat_map(|t| [(0.8 * t).sin(), 0.3 * (1.3 * t).cos()]).collect();
        let tau: Vec<f64> = t.iter().flat_map(|t| [10.0 * (0.8 * t).cos(), 2.0 * t.sin()]).collect();
        let exact = JointTrajectory { names: vec!["a".into(), "b".into()], t, qd: vec![0.0; q.len()], q, tau };
        let none = Degradation::of_segments(&[&exact], EffortConvention::Held);
        assert_eq!(none.encoder_step, vec![None, None]);
        assert!(none.effort_noise.iter().all(|s| *s < 1e-4), "{:?}", none.effort_noise);
        let bag = Degradation {
            effort: EffortConvention::Held,
            effort_noise: vec![0.1, 0.02],
            encoder_step: vec![Some(step), None],
        };
        let mut degraded = exact.clone();
        bag.apply_to(&mut degraded, &mut Rng::stream(1, &[]));
        let seen = Degradation::of_segments(&[&degraded], EffortConvention::Held);
        let found = seen.encoder_step[0].expect("quantized positions");
        assert!((found / step - 1.0).abs() < 1e-9, "{found} vs {step}");
        assert_eq!(seen.encoder_step[1], None);
        for (s, want) in seen.effort_noise.iter().zip([0.1, 0.02]) {
            assert!((s / want - 1.0).abs() < 0.05, "{s} vs {want}");
        }
    }
}
