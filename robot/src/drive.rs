//! The terms of a joint's drive that a URDF cannot state, identified beside the links: the motor's rotor inertia seen
//! through the gearbox (reflected inertia, MuJoCo's `armature`: `tau += I_a qdd`) and a constant torque offset (a
//! torque sensor's bias, friction that differs between directions: `tau += tau_0`).
//!
//! A geared arm's rotor inertia is of the order of its links' own about the first joints (a UR10e's about shoulder
//! lift: about as much again as the links'), and a fit without it puts it into the links: heavier links with their
//! centres of mass moved onto the axis, a URDF worse than the nominal one in any simulator. So the identified vector
//! is the robot's parameters (`dynforge_proto::params`) followed by these two per joint; the URDF's values of both are
//! zero.

use dynforge_proto::params::num_params;

use crate::Model;
use crate::model::ModelError;
use crate::parameters::with_dynamic_parameters;

/// Drive parameters per joint, after all of the robot's: `[armature, offset]` for joint 0, then joint 1, ...
pub const DRIVE_PER_JOINT: usize = 2;

/// Length of the identified vector of an `n`-joint chain: the robot's parameters and the drives'.
pub const fn identified_len(n: usize) -> usize {
    num_params(n) + DRIVE_PER_JOINT * n
}

/// Index of joint `j`'s armature in the identified vector (its offset is the next one).
pub const fn drive_index(n: usize, j: usize) -> usize {
    num_params(n) + DRIVE_PER_JOINT * j
}

/// Typical acceleration of a joint at its effort limit [rad/s^2 or m/s^2]: the prior's spread of its armature is
/// the effort limit over this. A geared arm's reflected rotor inertia takes a few percent of its effort limit at a
/// few rad/s^2 (a UR10e's shoulder lift: 3.7 kg m^2 against 330 N m; a Panda's: ~0.1-0.3 kg m^2 against 87 N m), so
/// the spread is wide for the data of any moving joint and narrow only against nonsense.
pub const ARMATURE_ACCELERATION: f64 = 50.0;

/// The prior's spread of a joint's offset, as a share of its effort limit: a sensor's bias or a direction's excess
/// friction is a few percent of what the joint can apply.
pub const OFFSET_SHARE: f64 = 0.1;

/// One joint's drive terms.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct Drive {
    /// Reflected rotor inertia [kg m^2; prismatic: kg].
    pub armature: f64,
    /// Constant torque [N m; prismatic: N].
    pub offset: f64,
}

/// The prior of joint `j`'s drive terms: means (none), standard deviations sized from its effort limit.
pub(crate) fn prior(model: &Model, j: usize) -> (Drive, Drive) {
    let effort = model.joints()[j].limits.effort;
    (Drive::default(), Drive { armature: effort / ARMATURE_ACCELERATION, offset: OFFSET_SHARE * effort })
}

/// The drive terms of every joint in an identified vector `pi` (zero where `pi` holds only the robot's parameters:
/// a URDF's).
pub fn drives(n: usize, pi: &[f64]) -> Vec<Drive> {
    (0..n)
        .map(|j| {
            let at = drive_index(n, j);
            match pi.get(at..at + DRIVE_PER_JOINT) {
                Some(d) => Drive { armature: d[0], offset: d[1] },
                None => Drive::default(),
            }
        })
        .collect()
}

/// A copy of `model` with the robot's part of an identified vector `pi` (the drives' terms after it are left out: a
/// model's links and joints cannot hold them).
pub fn with_identified(model: &Model, pi: &[f64]) -> Result<Model, ModelError> {
    with_dynamic_parameters(model, &pi[..num_params(model.dof()).min(pi.len())])
}

/// The identified vector of the robot's parameters `robot` and the drives `drives`.
pub fn identified(robot: &[f64], drives: &[Drive]) -> Vec<f64> {
    robot.iter().copied().chain(drives.iter().flat_map(|d| [d.armature, d.offset])).collect()
}
