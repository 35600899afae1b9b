//! The full dynamic-parameter layout: 10 inertial parameters per link plus 2 friction parameters per joint.
//!
//! This is the vector `pi` of the linear-in-parameters model `tau = Y(q, qd, qdd) * pi`. The inertial part follows
//! the convention of the identification literature (and Pinocchio's `dynamicParameters`): mass, first moment of
//! mass `m * c`, and the inertia tensor about the link frame origin (not the COM), all in the link frame, because
//! those are the quantities the joint torques are linear in.

/// Inertial parameters per link, in this order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InertialParam {
    Mass,
    /// m * c_x
    Mx,
    /// m * c_y
    My,
    /// m * c_z
    Mz,
    /// Inertia about the link frame origin.
    Ixx,
    Ixy,
    Iyy,
    Ixz,
    Iyz,
    Izz,
}

impl InertialParam {
    pub const ALL: [InertialParam; INERTIAL_PARAMS_PER_LINK] = [
        InertialParam::Mass,
        InertialParam::Mx,
        InertialParam::My,
        InertialParam::Mz,
        InertialParam::Ixx,
        InertialParam::Ixy,
        InertialParam::Iyy,
        InertialParam::Ixz,
        InertialParam::Iyz,
        InertialParam::Izz,
    ];

    pub const fn name(self) -> &'static str {
        match self {
            InertialParam::Mass => "m",
            InertialParam::Mx => "mcx",
            InertialParam::My => "mcy",
            InertialParam::Mz => "mcz",
            InertialParam::Ixx => "Ixx",
            InertialParam::Ixy => "Ixy",
            InertialParam::Iyy => "Iyy",
            InertialParam::Ixz => "Ixz",
            InertialParam::Iyz => "Iyz",
            InertialParam::Izz => "Izz",
        }
    }
}

pub const INERTIAL_PARAMS_PER_LINK: usize = 10;

/// Friction parameters per joint, after all inertial parameters: `[coulomb, viscous]` for joint 0, then joint 1, ...
pub const FRICTION_PARAMS_PER_JOINT: usize = 2;

/// Length of the full parameter vector of an `n`-joint chain.
pub const fn num_params(n: usize) -> usize {
    n * (INERTIAL_PARAMS_PER_LINK + FRICTION_PARAMS_PER_JOINT)
}

/// Index of joint `j`'s Coulomb coefficient in the full vector (viscous is the next one).
pub const fn friction_index(n: usize, j: usize) -> usize {
    n * INERTIAL_PARAMS_PER_LINK + j * FRICTION_PARAMS_PER_JOINT
}
