//! The samples of a recording that identification and the torque check use, and how torque is paired with
//! acceleration.

use std::ops::Range;

use dynforge_recording::JointTrajectory;

/// Joint speed [rad/s] under which a joint's torque is left out of a sample: at rest, Coulomb friction is static
/// and takes any value in `[-mu_c, mu_c]`, so no parameter set predicts it.
pub const REST_SPEED: f64 = 1e-2;

/// Calls `f(q, qd, qdd, tau)` for every sample `i` of `range` that has a neighbour on each side, on a uniform grid.
///
/// Pairing: a logged effort is the torque applied over the *next* grid step (zero-order hold; our shards' contract,
/// and what a motor driver does between two commands). The central difference `(qd[i+1] - qd[i-1]) / 2 dt` is the
/// mean acceleration over `[t[i-1], t[i+1]]`, which the efforts held over those two steps produced: `tau[i-1]` and
/// `tau[i]`. So the torque paired with it is their mean. Pairing it with `tau[i]` alone errs by half the change of
/// torque over a step: measured as a 1.5-11 % bias of viscous friction and 50-70 % of wrist inertia on MuJoCo logs.
pub(crate) fn for_each(traj: &JointTrajectory, range: Range<usize>, mut f: impl FnMut(&[f64], &[f64], &[f64], &[f64])) {
    let (n, len) = (traj.joints(), traj.len());
    if len < 3 {
        return;
    }
    let dt = (traj.t[len - 1] - traj.t[0]) / (len - 1) as f64;
    let (mut qdd, mut tau) = (vec![0.0; n], vec![0.0; n]);
    for i in range.start.max(1)..range.end.min(len - 1) {
        let (q, qd, _) = traj.sample(i);
        for j in 0..n {
            qdd[j] = (traj.qd[(i + 1) * n + j] - traj.qd[(i - 1) * n + j]) / (2.0 * dt);
            tau[j] = 0.5 * (traj.tau[(i - 1) * n + j] + traj.tau[i * n + j]);
        }
        f(q, qd, &qdd, &tau);
    }
}
