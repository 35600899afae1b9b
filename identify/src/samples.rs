//! The samples of a recording that identification and the torque check use, and how torque is paired with
//! acceleration and velocity.

use std::ops::Range;

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI};
use dynforge_recording::JointTrajectory;
use dynforge_robot::{Data, Model, regressor};
use nalgebra::DMatrix;

/// Joint speed [rad/s] under which a joint's torque is left out of a sample: at rest, Coulomb friction is static
/// and takes any value in `[-mu_c, mu_c]`, so no parameter set predicts it.
pub const REST_SPEED: f64 = 1e-2;

/// Revision of the sample selection and pairing below: anything cached from identification sums is keyed by it.
/// 2: the viscous column pairs with the span's mean velocity, and spans where a joint stops or starts are left out.
pub const PAIRING_REVISION: u32 = 2;

/// What white noise on the logged efforts becomes after pairing: each paired torque is the mean of two consecutive
/// efforts, so its noise has half the variance and a lag-1 correlation of 1/2, and the sums over neighbouring rows
/// carry `1 + 2 x 1/2 = 2` times the variance the residual shows. The residual's variance times this is the
/// effort noise itself, and the weight that tells the evidence's information right (on the log's own grid; a log
/// resampled from a slower rate has noise correlated over more samples).
pub const PAIRED_NOISE_GAIN: f64 = 2.0;

/// Joint speed [rad/s] that counts as stopped (held by static friction or a brake). Above rounding (a resampled
/// zero reads 1e-17), below any encoder's resolution.
pub const STOPPED_SPEED: f64 = 1e-9;

/// Calls `f(i, y, qd, tau)` for every sample `i` of `range` that has a neighbour on each side, on a uniform grid,
/// and no joint stopping or starting in between: `y` is the regressor paired with the efforts `tau`, `qd` the
/// measured velocity (to tell moving joints).
///
/// Stops and starts: a joint whose speed is [`STOPPED_SPEED`] at one of `i-1, i, i+1` and above it at another
/// switches between sliding and sticking inside the span, and the span's mean acceleration mixes the two regimes.
/// Its own row has no model there, and the other joints' rows see the switch through the coupling (in our simulator
/// the stop also lands the velocity on zero within a substep). Those spans are left out for every joint: a fraction
/// of a percent of the samples, they carry nearly all the residual the true parameters leave (figures in
/// `docs/measurements.md`).
///
/// Pairing with acceleration: a logged effort is the torque applied over the *next* grid step (zero-order hold;
/// our shards' contract, and what a motor driver does between two commands). The central difference
/// `(qd[i+1] - qd[i-1]) / 2 dt` is the mean acceleration over `[t[i-1], t[i+1]]`, which the efforts held over those
/// two steps produced: `tau[i-1]` and `tau[i]`. So the torque paired with it is their mean. Pairing it with `tau[i]`
/// alone errs by half the change of torque over a step, which biases viscous friction and the wrists' inertia
/// (`docs/measurements.md`).
///
/// Pairing with velocity: the mean torque over that span balances the *mean* viscous force over it, and the mean
/// velocity over `[t[i-1], t[i+1]]` is exactly `(q[i+1] - q[i-1]) / 2 dt`, whatever the integrator did inside the
/// steps. `qd[i]` instead misses the kink the effort's change puts in the velocity at `t[i]`: an error of
/// `mu_v dt/4` times the change of acceleration, i.e. `lambda dt / 4` of the torque's change for a joint whose
/// viscous rate `lambda = mu_v / inertia` is high (light wrists: hundreds per second). Paired with `qd[i]`, the true
/// parameters would leave that error as residual wherever the effort changes fast.
pub(crate) fn for_each(
    model: &Model,
    data: &mut Data,
    traj: &JointTrajectory,
    range: Range<usize>,
    mut f: impl FnMut(usize, &DMatrix<f64>, &[f64], &[f64]),
) {
    let (n, len) = (traj.joints(), traj.len());
    if len < 3 {
        return;
    }
    let dt = (traj.t[len - 1] - traj.t[0]) / (len - 1) as f64;
    let (mut qdd, mut tau) = (vec![0.0; n], vec![0.0; n]);
    let stopped = |i: usize, j: usize| traj.qd[i * n + j].abs() <= STOPPED_SPEED;
    for i in range.start.max(1)..range.end.min(len - 1) {
        if (0..n).any(|j| (stopped(i - 1, j) != stopped(i, j)) || (stopped(i, j) != stopped(i + 1, j))) {
            continue;
        }
        let (q, qd, _) = traj.sample(i);
        for j in 0..n {
            qdd[j] = (traj.qd[(i + 1) * n + j] - traj.qd[(i - 1) * n + j]) / (2.0 * dt);
            tau[j] = 0.5 * (traj.tau[(i - 1) * n + j] + traj.tau[i * n + j]);
        }
        regressor(model, data, q, qd, &qdd);
        for j in 0..n {
            data.regressor[(j, NI * n + NF * j + 1)] = (traj.q[(i + 1) * n + j] - traj.q[(i - 1) * n + j]) / (2.0 * dt);
        }
        f(i, &data.regressor, qd, &tau);
    }
}

/// Per joint, the columns its row of the regressor can be non-zero in: the inertial parameters of links `j..` and
/// joint `j`'s friction pair.
pub(crate) fn row_support(dof: usize) -> Vec<Vec<usize>> {
    (0..dof).map(|j| (NI * j..NI * dof).chain([NI * dof + NF * j, NI * dof + NF * j + 1]).collect()).collect()
}
