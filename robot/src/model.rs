//! The robot model: an immutable description of a fixed-base serial chain of revolute and prismatic joints.
//!
//! The model keeps every parameter exactly as a URDF states it (joint origins as xyz + rpy, inertials as origin +
//! mass + inertia about the COM) so that a write -> read round trip is lossless, and precomputes the spatial
//! quantities (joint placements, unit axes, link inertias) the algorithms use. Scratch space lives in
//! [`crate::Data`], one per thread, as in Pinocchio's Model/Data split.

use nalgebra::{Matrix3, SymmetricEigen, Unit, Vector3};

use crate::spatial::{Inertia, Motion, Se3};

/// Standard gravity used by default, pointing along -z of the base frame [m/s^2].
pub const GRAVITY: f64 = 9.81;

/// A pose as URDF writes it: translation, then fixed-axis roll-pitch-yaw.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose {
    pub xyz: [f64; 3],
    pub rpy: [f64; 3],
}

impl Pose {
    pub fn se3(&self) -> Se3 {
        Se3::from_xyz_rpy(self.xyz, self.rpy)
    }

    /// Inverse of [`Pose::se3`] (exact up to rounding; rpy chosen in the principal range).
    pub fn from_se3(x: &Se3) -> Self {
        let r = nalgebra::Rotation3::from_matrix_unchecked(x.rot);
        let (roll, pitch, yaw) = r.euler_angles();
        Pose { xyz: [x.trans.x, x.trans.y, x.trans.z], rpy: [roll, pitch, yaw] }
    }
}

/// Joint friction: `tau_f = coulomb * sign(qd) + viscous * qd` (URDF `<dynamics friction= damping=>`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Friction {
    /// Coulomb friction torque magnitude [N m].
    pub coulomb: f64,
    /// Viscous coefficient [N m s/rad].
    pub viscous: f64,
}

/// Largest effort [N m or N], speed [rad/s or m/s] and position [rad or m] limits taken as a joint's real ones: ten
/// times and more the largest of any arm (a heavy-payload arm's base: ~50 kN m at ~2 rad/s; a linear axis: ~100 kN,
/// a few m/s, tens of m). What lies beyond is a placeholder (1e308, 1e30, 1e10 for "none"), and a placeholder sizes
/// the identification's priors, the excitation's scaling and the controller's gains to nonsense.
pub const MAX_EFFORT: f64 = 1e6;
pub const MAX_VELOCITY: f64 = 1e3;
pub const MAX_POSITION: f64 = 1e3;

/// Joint limits (URDF `<limit>`); a continuous joint has infinite position limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    pub lower: f64,
    pub upper: f64,
    /// Maximum actuator torque [N m].
    pub effort: f64,
    /// Maximum joint speed [rad/s].
    pub velocity: f64,
}

impl Limits {
    /// The position interval the joint moves within, `None` for one without: a continuous joint's infinite limits,
    /// limits out of order, or a range of a thousand (rad or m) or more, which no joint has.
    pub fn range(&self) -> Option<(f64, f64)> {
        (self.upper > self.lower && self.upper - self.lower < 1e3).then_some((self.lower, self.upper))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    Revolute,
    /// A revolute joint without position limits.
    Continuous,
    /// Translation along the axis [m]; its friction is in N and N s/m, its effort limit in N.
    Prismatic,
}

impl JointKind {
    /// The URDF `type` attribute.
    pub fn urdf_name(self) -> &'static str {
        match self {
            JointKind::Revolute => "revolute",
            JointKind::Continuous => "continuous",
            JointKind::Prismatic => "prismatic",
        }
    }
}

/// A moving joint; joint `i` moves link `i` of the model (the paper's link `i + 1`).
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    pub name: String,
    pub kind: JointKind,
    /// Placement of the joint frame in the previous link's frame (the base frame for joint 0) at q = 0.
    pub origin: Pose,
    /// Rotation axis in the joint frame, as written (normalised when used).
    pub axis: [f64; 3],
    pub limits: Limits,
    pub friction: Friction,
}

/// Inertial parameters as URDF states them: COM frame (origin + rpy), mass, and the inertia about the COM in the
/// COM frame's axes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Inertial {
    pub origin: Pose,
    pub mass: f64,
    /// `[ixx, ixy, ixz, iyy, iyz, izz]`
    pub inertia: [f64; 6],
}

impl Inertial {
    /// Spatial inertia about the link frame origin.
    pub fn spatial(&self) -> Inertia {
        let [ixx, ixy, ixz, iyy, iyz, izz] = self.inertia;
        let i_frame = Matrix3::new(ixx, ixy, ixz, ixy, iyy, iyz, ixz, iyz, izz);
        let r = crate::spatial::rpy_rotation(self.origin.rpy);
        Inertia::from_com(self.mass, Vector3::from(self.origin.xyz), r * i_frame * r.transpose())
    }

    /// The URDF form of a spatial inertia (COM frame aligned with the link frame).
    pub fn from_spatial(i: &Inertia) -> Self {
        let c = i.com();
        let m = i.i_com();
        Inertial {
            origin: Pose { xyz: [c.x, c.y, c.z], rpy: [0.0; 3] },
            mass: i.mass,
            inertia: [m[(0, 0)], m[(0, 1)], m[(0, 2)], m[(1, 1)], m[(1, 2)], m[(2, 2)]],
        }
    }
}

/// A geometric primitive for visuals and collisions (kept so written URDFs still render).
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    Cylinder { radius: f64, length: f64 },
    Box { size: [f64; 3] },
    Sphere { radius: f64 },
    Capsule { radius: f64, length: f64 },
    Mesh { filename: String, scale: Option<[f64; 3]> },
}

/// A placed shape in a link frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Geometry {
    pub origin: Pose,
    pub shape: Shape,
}

/// A moving link.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Link {
    pub name: String,
    pub inertial: Inertial,
    pub visuals: Vec<Geometry>,
    pub collisions: Vec<Geometry>,
}

/// Problems a model can have; always reported with the name of the offending element.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelProblem {
    #[error("cannot read: {0}")]
    Io(String),
    #[error("cannot parse URDF: {0}")]
    Parse(String),
    #[error("the chain has no moving joint")]
    NoMovingJoint,
    #[error("joint '{joint}' has unsupported type {kind} (revolute, continuous and prismatic joints move)")]
    UnsupportedJoint { joint: String, kind: String },
    #[error("joint '{joint}' refers to link '{link}', which is not defined")]
    UnknownLink { joint: String, link: String },
    #[error("link '{link}' has more than one parent joint")]
    MultipleParents { link: String },
    #[error("{kind} '{name}' is defined more than once")]
    Duplicate { kind: &'static str, name: String },
    #[error("elements are nested more than {0} deep (a URDF needs a handful of levels)")]
    TooDeep(usize),
    #[error("the URDF has {0} root links (expected exactly one)")]
    Roots(usize),
    #[error("link '{link}' carries several moving branches (joints {joints}): only serial chains are supported")]
    Branching { link: String, joints: String },
    #[error("link '{link}' has no inertia (missing <inertial> or zero mass) but moves")]
    MissingInertia { link: String },
    #[error("link '{link}' has a non-physical inertia: {reason}")]
    InvalidInertia { link: String, reason: InertiaError },
    #[error("joint '{joint}': {reason}")]
    InvalidJoint { joint: String, reason: String },
    #[error("invalid generator config: {0}")]
    Config(String),
    #[error("chain has {joints} joints but {links} links")]
    Mismatch { joints: usize, links: usize },
}

/// A model error, naming where the model came from (a file path or a generator description).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{source_name}: {problem}")]
pub struct ModelError {
    pub source_name: String,
    pub problem: ModelProblem,
}

/// Why an inertia is not one a real body can have (see [`check_physical`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InertiaError {
    #[error("mass {0} is not positive")]
    Mass(f64),
    #[error("inertia has non-finite entries")]
    NonFinite,
    #[error("inertia is not symmetric")]
    Asymmetric,
    /// The principal moments about the COM, smallest first.
    #[error("principal moments {0:?} are not all positive")]
    NotPositive([f64; 3]),
    /// The principal moments about the COM, smallest first.
    #[error("principal moments {0:?} violate the triangle inequality")]
    Triangle([f64; 3]),
}

/// Checks that an inertia is one a real body can have: positive mass, positive-definite rotational inertia about the
/// COM, and principal moments obeying the triangle inequality (`I1 + I2 >= I3`, with a relative slack for rounding).
pub fn check_physical(i: &Inertia) -> Result<(), InertiaError> {
    if !(i.mass.is_finite() && i.mass > 0.0) {
        return Err(InertiaError::Mass(i.mass));
    }
    let ic = i.i_com();
    if ic.iter().any(|v| !v.is_finite()) {
        return Err(InertiaError::NonFinite);
    }
    if (ic - ic.transpose()).norm() > 1e-12 * ic.norm() {
        return Err(InertiaError::Asymmetric);
    }
    let e = SymmetricEigen::new(ic).eigenvalues;
    let mut ev = [e[0], e[1], e[2]];
    ev.sort_by(f64::total_cmp);
    if ev[0] <= 0.0 {
        return Err(InertiaError::NotPositive(ev));
    }
    let slack = 1e-9 * ev[2];
    if ev[0] + ev[1] + slack < ev[2] {
        return Err(InertiaError::Triangle(ev));
    }
    Ok(())
}

/// The robot: base + `n` joints + `n` moving links, with precomputed spatial quantities.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    name: String,
    base: String,
    joints: Vec<Joint>,
    links: Vec<Link>,
    gravity: Vector3<f64>,
    placements: Vec<Se3>,
    axes: Vec<Unit<Vector3<f64>>>,
    subspaces: Vec<Motion>,
    inertias: Vec<Inertia>,
}

impl Model {
    /// Builds and validates a model. `source_name` is used in error messages (file path or generator identity).
    pub fn new(
        source_name: &str,
        name: impl Into<String>,
        base: impl Into<String>,
        joints: Vec<Joint>,
        links: Vec<Link>,
    ) -> Result<Model, ModelError> {
        let err = |problem| ModelError { source_name: source_name.to_string(), problem };
        if joints.is_empty() {
            return Err(err(ModelProblem::NoMovingJoint));
        }
        if joints.len() != links.len() {
            return Err(err(ModelProblem::Mismatch { joints: joints.len(), links: links.len() }));
        }
        let mut axes = Vec::with_capacity(joints.len());
        for j in &joints {
            let bad = |reason: String| err(ModelProblem::InvalidJoint { joint: j.name.clone(), reason });
            let axis = Vector3::from(j.axis);
            if !axis.iter().all(|v| v.is_finite()) || axis.norm() < 1e-9 {
                return Err(bad(format!("axis {:?} is not a direction", j.axis)));
            }
            axes.push(Unit::new_normalize(axis));
            if j.origin.xyz.iter().chain(&j.origin.rpy).any(|v| !v.is_finite()) {
                return Err(bad("origin is not finite".into()));
            }
            let l = &j.limits;
            if j.kind != JointKind::Continuous && !(l.lower < l.upper) {
                return Err(bad(format!("limits lower {} / upper {} do not bound a range", l.lower, l.upper)));
            }
            // Finite and real too: they size the identification's priors, the excitation's scaling and the
            // controller's gains.
            if !(l.effort > 0.0 && l.effort <= MAX_EFFORT && l.velocity > 0.0 && l.velocity <= MAX_VELOCITY) {
                return Err(bad(format!(
                    "effort {} and velocity {} limits must be positive and finite, the joint's real limits (at most \
                     {MAX_EFFORT:e} N m or N and {MAX_VELOCITY:e} rad/s or m/s)",
                    l.effort, l.velocity
                )));
            }
            if j.kind != JointKind::Continuous && !(l.lower.abs() <= MAX_POSITION && l.upper.abs() <= MAX_POSITION) {
                return Err(bad(format!(
                    "limits lower {} / upper {} are no joint's range (at most {MAX_POSITION:e} rad or m either way; a \
                     joint without position limits is `continuous`)",
                    l.lower, l.upper
                )));
            }
            let f = &j.friction;
            if !(f.coulomb >= 0.0 && f.viscous >= 0.0 && f.coulomb.is_finite() && f.viscous.is_finite()) {
                return Err(bad(format!("friction {} / damping {} must be finite and >= 0", f.coulomb, f.viscous)));
            }
        }
        let mut inertias = Vec::with_capacity(links.len());
        for l in &links {
            if l.inertial.mass == 0.0 {
                return Err(err(ModelProblem::MissingInertia { link: l.name.clone() }));
            }
            let i = l.inertial.spatial();
            check_physical(&i).map_err(|reason| err(ModelProblem::InvalidInertia { link: l.name.clone(), reason }))?;
            inertias.push(i);
        }
        let placements = joints.iter().map(|j| j.origin.se3()).collect();
        let subspaces = joints
            .iter()
            .zip(&axes)
            .map(|(j, a)| match j.kind {
                JointKind::Prismatic => Motion::new(Vector3::zeros(), a.into_inner()),
                _ => Motion::new(a.into_inner(), Vector3::zeros()),
            })
            .collect();
        Ok(Model {
            name: name.into(),
            base: base.into(),
            joints,
            links,
            gravity: Vector3::new(0.0, 0.0, -GRAVITY),
            placements,
            axes,
            subspaces,
            inertias,
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }
    /// Name of the fixed base link.
    pub fn base(&self) -> &str {
        &self.base
    }
    /// Number of degrees of freedom.
    pub fn dof(&self) -> usize {
        self.joints.len()
    }
    pub fn joints(&self) -> &[Joint] {
        &self.joints
    }
    pub fn links(&self) -> &[Link] {
        &self.links
    }
    /// Gravity acceleration in the base frame.
    pub fn gravity(&self) -> Vector3<f64> {
        self.gravity
    }
    /// Placement of joint `i` in its parent frame at q = 0.
    pub fn placement(&self, i: usize) -> &Se3 {
        &self.placements[i]
    }
    /// Unit axis of joint `i` in its own frame: the rotation axis of a revolute joint, the direction of a prismatic
    /// one.
    pub fn axis(&self, i: usize) -> &Unit<Vector3<f64>> {
        &self.axes[i]
    }

    /// Joint `i`'s motion subspace `S` in its own frame: the twist of unit joint speed, `(axis, 0)` for a revolute
    /// joint and `(0, axis)` for a prismatic one (angular first).
    pub fn subspace(&self, i: usize) -> &Motion {
        &self.subspaces[i]
    }

    /// Whether joint `i` translates.
    pub fn is_prismatic(&self, i: usize) -> bool {
        self.joints[i].kind == JointKind::Prismatic
    }
    /// Spatial inertia of link `i` about its frame origin.
    pub fn inertia(&self, i: usize) -> &Inertia {
        &self.inertias[i]
    }
    /// Index of the joint (= moving link) with this joint or link name.
    pub fn find(&self, name: &str) -> Option<usize> {
        (0..self.dof()).find(|&i| self.joints[i].name == name || self.links[i].name == name)
    }

    /// A copy with other link inertias and joint friction, e.g. an identified estimate. Validated like `new`.
    pub fn with_dynamics(&self, inertials: &[Inertial], friction: &[Friction]) -> Result<Model, ModelError> {
        if inertials.len() != self.dof() || friction.len() != self.dof() {
            return Err(ModelError {
                source_name: format!("model '{}'", self.name),
                problem: ModelProblem::Mismatch { joints: friction.len(), links: inertials.len() },
            });
        }
        let mut joints = self.joints.clone();
        let mut links = self.links.clone();
        for (j, f) in joints.iter_mut().zip(friction) {
            j.friction = *f;
        }
        for (l, i) in links.iter_mut().zip(inertials) {
            l.inertial = *i;
        }
        Model::new(&format!("model '{}'", self.name), self.name.clone(), self.base.clone(), joints, links)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Callers, tests and users match on these texts: they stay as they are.
    #[test]
    fn inertia_errors_keep_their_texts() {
        let ev = vec![-1.0, 0.5, 2.25];
        assert_eq!(InertiaError::Mass(-1.5).to_string(), format!("mass {} is not positive", -1.5));
        assert_eq!(InertiaError::NonFinite.to_string(), "inertia has non-finite entries");
        assert_eq!(InertiaError::Asymmetric.to_string(), "inertia is not symmetric");
        assert_eq!(
            InertiaError::NotPositive([-1.0, 0.5, 2.25]).to_string(),
            format!("principal moments {ev:?} are not all positive")
        );
        assert_eq!(
            InertiaError::Triangle([-1.0, 0.5, 2.25]).to_string(),
            format!("principal moments {ev:?} violate the triangle inequality")
        );
        let bad = Inertia::from_com(1.0, Vector3::zeros(), Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 3.0)));
        let problem = ModelProblem::InvalidInertia { link: "l1".into(), reason: check_physical(&bad).unwrap_err() };
        assert_eq!(
            problem.to_string(),
            "link 'l1' has a non-physical inertia: principal moments [1.0, 1.0, 3.0] violate the triangle inequality"
        );
    }
}
