//! What a design is measured against: random multi-sines built the usual way, each joint scaled alone into the same
//! bounds the design keeps (the acceleration limit included).

use dynforge_robot::rng::Rng;
use nalgebra::DMatrix;

use crate::information::{Base, Quality};
use crate::motion::MultiSine;
use crate::options::DENSE_RATE;
use crate::sampler::Sampler;

/// Random multi-sines drawn per comparison (alone, and sets of as many as the design has trajectories).
pub const DRAWS: usize = 20;

/// Shares of each joint's bounds a multi-sine is scaled to: the classical recipe's 95 % of the speed and 96 % of the
/// position room, and all of the acceleration limit.
const SPEED_SHARE: f64 = 0.95;
const ROOM_SHARE: f64 = 0.96;

/// Fade-in and fade-out of a multi-sine, as a share of its duration.
const FADE_SHARE: f64 = 0.1;

/// Step by which all joints of a multi-sine shrink together until its effort fits, and the most steps (to 5 %).
const EFFORT_STEP: f64 = 0.97;
const EFFORT_STEPS: usize = 100;

/// The best and the median of [`DRAWS`] motions by each criterion (each its own ranking).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Spread {
    pub best: Quality,
    pub median: Quality,
}

/// The random multi-sines a design is measured against: one alone, and a set of as many as the design has.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MultiSines {
    pub alone: Spread,
    pub sets: Spread,
}

/// A multi-sine scaled into the sampler's bounds, with its information; `None` when even 5 % of it needs more
/// effort than they allow. Its kinematic peaks are taken at 1 kHz (cheap without the dynamics): it is no trigonometric
/// polynomial of the period, whose peaks between samples the design's series bound.
pub(crate) fn fitted(sampler: &mut Sampler<'_>, mut m: MultiSine) -> Option<(MultiSine, DMatrix<f64>)> {
    let dense = (m.duration * DENSE_RATE).ceil() as usize;
    for (j, p) in sampler.kinematic_peaks_at(&m, dense).iter().enumerate() {
        let scale = (ROOM_SHARE / p[0]).min(SPEED_SHARE / p[1]).min(1.0 / p[2]);
        if !(scale > 0.0 && scale.is_finite()) {
            return None;
        }
        m.scale[j] *= scale;
    }
    let shrink = |m: &mut MultiSine| m.scale.iter_mut().for_each(|c| *c *= EFFORT_STEP);
    let (m, information, _) = sampler.shrink_until(m, MultiSine::clone, shrink, EFFORT_STEPS, |p| p[3] <= 1.0)?;
    Some((m, information))
}

/// [`DRAWS`] multi-sines alone and [`DRAWS`] sets of `count`, drawn from `seed`'s own streams, judged on `base`.
/// A draw that cannot be fitted is drawn again, at most `2 DRAWS (count + 1)` times; `None` if none of those fits.
pub(crate) fn multisines(sampler: &mut Sampler<'_>, base: &Base, count: usize, seed: u64) -> Option<MultiSines> {
    let duration = sampler.period;
    let start = sampler.bounds.start.clone();
    let mut draw = 0u64;
    let mut next = |sampler: &mut Sampler<'_>| {
        (0..2 * DRAWS * (count + 1)).find_map(|_| {
            draw += 1;
            let mut rng = Rng::stream(seed, &[u64::MAX, draw]);
            fitted(sampler, MultiSine::draw(duration, FADE_SHARE * duration, &start, &mut rng)).map(|(_, w)| w)
        })
    };
    let mut alone = Vec::with_capacity(DRAWS);
    let mut sets = Vec::with_capacity(DRAWS);
    for _ in 0..DRAWS {
        alone.push(Quality::of(base, &next(sampler)?));
    }
    for _ in 0..DRAWS {
        let mut w = next(sampler)?;
        for _ in 1..count {
            w += next(sampler)?;
        }
        sets.push(Quality::of(base, &w));
    }
    Some(MultiSines { alone: spread(&alone), sets: spread(&sets) })
}

/// The best and the median of `qualities`, by each criterion.
fn spread(qualities: &[Quality]) -> Spread {
    let sorted = |key: fn(&Quality) -> f64| {
        let mut v: Vec<f64> = qualities.iter().map(key).collect();
        v.sort_by(f64::total_cmp);
        v
    };
    let median = |v: &[f64]| 0.5 * (v[(v.len() - 1) / 2] + v[v.len() / 2]);
    let (log_det, condition, trace) = (sorted(|q| q.log_det), sorted(|q| q.condition), sorted(|q| q.trace));
    Spread {
        // Larger is better for log det, smaller for the condition number and the trace.
        best: Quality { log_det: log_det[log_det.len() - 1], condition: condition[0], trace: trace[0] },
        median: Quality { log_det: median(&log_det), condition: median(&condition), trace: median(&trace) },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::tests::{arm, options};
    use crate::sampler::Bounds;

    /// A fitted multi-sine: each joint alone at the first of 96 % of its room, 95 % of its speed bound or its
    /// acceleration limit (the efforts of this arm are far inside their limits, so nothing shrinks it after), at the
    /// 1 kHz samples it was fitted at.
    #[test]
    fn each_joint_of_a_multisine_reaches_the_first_of_its_shares() {
        let (model, options) = (arm(), options());
        let bounds = Bounds::new(&model, &options).expect("valid options");
        let mut sampler = Sampler::new(&model, &bounds, None, &options, options.rate);
        let dense = Sampler::new(&model, &bounds, None, &options, 1000.0);
        for draw in 0..5 {
            let mut rng = Rng::stream(9, &[draw]);
            let m = MultiSine::draw(options.duration, 0.4, &bounds.start, &mut rng);
            let (m, _) = fitted(&mut sampler, m).expect("fits");
            for p in dense.kinematic_peaks(&m) {
                let share = (p[0] / ROOM_SHARE).max(p[1] / SPEED_SHARE).max(p[2]);
                assert!((share - 1.0).abs() < 1e-9, "{p:?}");
            }
        }
    }
}
