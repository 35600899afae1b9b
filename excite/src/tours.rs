//! The generator's motions on the user's robot, as the yardstick of a design: the dataset generator's protocol
//! (random waypoints inside the joint limits, each free of self-collision and joined to the last by a free straight
//! path, minimum-jerk moves at half the speed limit, each held 2 s) run for the design's total duration. The
//! waypoints' seed is the design's.

use dynforge_proto::sim::{TrajectoryConfig, minimum_jerk, straight_path_free};
use dynforge_robot::rng::Rng;
use dynforge_robot::{Data, Model, regressor};
use nalgebra::{DMatrix, DVector};

use crate::collision::SelfCollision;
use crate::information::Information;

/// The scaled information of the generator's tour on `model` lasting `total` seconds, sampled at `rate`, each joint
/// weighted by its `noise`; `None` when no free waypoint is found.
pub fn tour_information(
    model: &Model,
    collision: Option<&SelfCollision>,
    scales: &[f64],
    noise: &[f64],
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
                let (lo, hi) = cfg.waypoint_range(j.limits.lower, j.limits.upper);
                rng.uniform(lo, hi)
            })
            .collect()
    };
    let mut w = Information::new(&DVector::from_column_slice(scales), noise);
    let (mut elapsed, mut from) = (0.0, None::<Vec<f64>>);
    while elapsed < total {
        let to = (0..cfg.max_attempts).map(|_| draw(&mut rng)).find(|q| {
            free(q, &mut data)
                && from.as_ref().is_none_or(|a| straight_path_free(a, q, cfg.path_step, |q| free(q, &mut data)))
        })?;
        let Some(a) = from.replace(to.clone()) else { continue };
        let duration = cfg.move_duration((0..n).map(|j| (to[j] - a[j], model.joints()[j].limits.velocity)));
        let steps = ((duration + cfg.hold).min(total - elapsed) * rate).round() as usize;
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for k in 0..steps {
            let [s, ds, dds] = minimum_jerk(k as f64 / rate, duration);
            for j in 0..n {
                let d = to[j] - a[j];
                (q[j], qd[j], qdd[j]) = (a[j] + d * s, d * ds, d * dds);
            }
            w.add(regressor(model, &mut data, &q, &qd, &qdd));
        }
        elapsed += duration + cfg.hold;
    }
    Some(w.finish())
}
