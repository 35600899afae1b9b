//! The generator's motions on the user's robot, as the yardstick of a design: the dataset generator's protocol
//! (random waypoints inside the joint limits, each free of self-collision and joined to the last by a free straight
//! path, minimum-jerk moves at half the speed limit, each held 2 s) run for the design's total duration. The
//! waypoints' seed is the design's.

use dynforge_proto::sim::{TrajectoryConfig, minimum_jerk};
use dynforge_robot::rng::Rng;
use dynforge_robot::{Data, Model, regressor};
use nalgebra::{DMatrix, DVector};

use crate::collision::SelfCollision;
use crate::information::add_rows;

/// The scaled information of the generator's tour on `model` lasting `total` seconds, sampled at `rate`; `None` when
/// no free waypoint is found.
pub fn tour_information(
    model: &Model,
    collision: Option<&SelfCollision>,
    scales: &[f64],
    (total, rate): (f64, f64),
    seed: u64,
) -> Option<DMatrix<f64>> {
    let cfg = TrajectoryConfig::default();
    let n = model.dof();
    let mut data = Data::new(model);
    let free = |q: &[f64], data: &mut Data| collision.is_none_or(|c| c.first_contact(model, data, q).is_none());
    let mut rng = Rng::stream(seed, &[2]);
    let draw = |rng: &mut Rng| -> Vec<f64> {
        model
            .joints()
            .iter()
            .map(|j| {
                let l = &j.limits;
                let (lo, hi) = (l.lower.max(-std::f64::consts::PI), l.upper.min(std::f64::consts::PI));
                rng.uniform(lo + cfg.limit_margin, hi - cfg.limit_margin)
            })
            .collect()
    };
    let p = scales.len();
    let scales = DVector::from_column_slice(scales);
    let mut w = DMatrix::zeros(p, p);
    let (mut elapsed, mut from) = (0.0, None::<Vec<f64>>);
    while elapsed < total {
        let to = (0..cfg.max_attempts).map(|_| draw(&mut rng)).find(|q| {
            free(q, &mut data) && from.as_ref().is_none_or(|a| path_free(a, q, cfg.path_step, |q| free(q, &mut data)))
        })?;
        let Some(a) = from.replace(to.clone()) else { continue };
        let duration = (0..n)
            .map(|j| 1.875 * (to[j] - a[j]).abs() / (cfg.speed_fraction * model.joints()[j].limits.velocity))
            .fold(cfg.min_move, f64::max);
        let steps = ((duration + cfg.hold).min(total - elapsed) * rate).round() as usize;
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for k in 0..steps {
            let [s, ds, dds] = minimum_jerk(k as f64 / rate, duration);
            for j in 0..n {
                let d = to[j] - a[j];
                (q[j], qd[j], qdd[j]) = (a[j] + d * s, d * ds, d * dds);
            }
            add_rows(&mut w, regressor(model, &mut data, &q, &qd, &qdd), &scales);
        }
        elapsed += duration + cfg.hold;
    }
    Some(w)
}

/// Both ends of the straight joint-space path from `a` to `b`, and points on it no more than `step` apart, are
/// `free`.
fn path_free(a: &[f64], b: &[f64], step: f64, mut free: impl FnMut(&[f64]) -> bool) -> bool {
    let span = a.iter().zip(b).map(|(x, y)| (y - x).abs()).fold(0.0, f64::max);
    let m = (span / step).ceil().max(1.0) as usize;
    (0..=m).all(|k| {
        let s = k as f64 / m as f64;
        let q: Vec<f64> = a.iter().zip(b).map(|(x, y)| x + s * (y - x)).collect();
        free(&q)
    })
}
