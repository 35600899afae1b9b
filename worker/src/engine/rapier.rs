//! The rapier engine: rapier3d-f64's reduced-coordinate multibody built from the robot model.
//!
//! Each link is a dynamic rigid body carrying the link's exact mass properties; each joint a revolute
//! `GenericJoint` whose frames reproduce the URDF placement and axis. rapier has no generalized-force input, so a
//! joint torque is applied as an equal and opposite torque pair on the child and parent bodies, which the multibody
//! projects exactly onto the joint. Friction uses rapier's own joint models: viscous as the (implicit) joint
//! damping, Coulomb as the joint's dry-friction constraint. rapier's default joint damping (0.1 per DOF) is removed.
//! The integrator is semi-implicit Euler with `substeps` substeps per period (first order); collisions are checked
//! by the worker's shared collision model, so no colliders are built here.

use dynforge_robot::Model;
use rapier3d_f64::prelude::*;

use super::Engine;

use dynforge_proto::sim::EngineKind;

/// Substeps per 1 ms period: energy drift falls first-order with the substep; 8 keeps the inverse-dynamics
/// residual of the logged data near 1e-3.
pub const DEFAULT_SUBSTEPS: usize = 8;

pub struct RapierEngine {
    pipeline: PhysicsPipeline,
    params: IntegrationParameters,
    islands: IslandManager,
    broad_phase: BroadPhaseBvh,
    narrow_phase: NarrowPhase,
    bodies: RigidBodySet,
    colliders: ColliderSet,
    impulse_joints: ImpulseJointSet,
    multibody_joints: MultibodyJointSet,
    soft_bodies: SoftBodySet,
    ccd: CCDSolver,
    gravity: Vector,
    /// Base, then the links.
    bodies_of_links: Vec<RigidBodyHandle>,
    joints: Vec<MultibodyJointHandle>,
    /// Joint axes in the child frames.
    axes: Vec<Vector>,
    /// Generalized-coordinate index of each joint.
    dof: Vec<usize>,
    q: Vec<f64>,
    qd: Vec<f64>,
}

fn vec3(v: &nalgebra::Vector3<f64>) -> Vector {
    Vector::new(v.x, v.y, v.z)
}

fn mat3(m: &nalgebra::Matrix3<f64>) -> Matrix {
    Matrix::from_cols(
        Vector::new(m[(0, 0)], m[(1, 0)], m[(2, 0)]),
        Vector::new(m[(0, 1)], m[(1, 1)], m[(2, 1)]),
        Vector::new(m[(0, 2)], m[(1, 2)], m[(2, 2)]),
    )
}

impl RapierEngine {
    /// An engine for `model` (revolute joints: [`crate::simulate::engine_for`] refuses others) with control period
    /// `dt` and `substeps` integration substeps per period.
    pub fn new(model: &Model, dt: f64, substeps: usize) -> Self {
        let n = model.dof();
        let mut bodies = RigidBodySet::new();
        let mut multibody_joints = MultibodyJointSet::new();
        let base = bodies.insert(RigidBodyBuilder::fixed().can_sleep(false));
        let mut bodies_of_links = vec![base];
        let mut joints = Vec::with_capacity(n);
        let mut axes = Vec::with_capacity(n);
        for i in 0..n {
            let inertia = model.inertia(i);
            let mass = MassProperties::with_inertia_matrix(vec3(&inertia.com()), inertia.mass, mat3(&inertia.i_com()));
            let body = bodies.insert(RigidBodyBuilder::dynamic().additional_mass_properties(mass).can_sleep(false));
            let axis = vec3(&model.axis(i).into_inner());
            let x_to_axis = Rotation::from_rotation_arc(Vector::X, axis);
            let placement = model.placement(i);
            let origin = Rotation::from_mat3(&mat3(&placement.rot)).normalize();
            let joint = GenericJointBuilder::new(JointAxesMask::LOCKED_REVOLUTE_AXES)
                .local_frame1(Pose::from_parts(vec3(&placement.trans), origin * x_to_axis))
                .local_frame2(Pose::from_parts(Vector::ZERO, x_to_axis))
                .contacts_enabled(false)
                .build();
            let parent = *bodies_of_links.last().expect("base inserted");
            joints.push(multibody_joints.insert(parent, body, joint, true).expect("a chain has no loops"));
            bodies_of_links.push(body);
            axes.push(axis);
        }
        let params =
            IntegrationParameters { dt, num_solver_iterations: substeps, max_ccd_substeps: 0, ..Default::default() };
        let mut engine = RapierEngine {
            pipeline: PhysicsPipeline::new(),
            params,
            islands: IslandManager::new(),
            broad_phase: BroadPhaseBvh::new(),
            narrow_phase: NarrowPhase::new(),
            bodies,
            colliders: ColliderSet::new(),
            impulse_joints: ImpulseJointSet::new(),
            multibody_joints,
            soft_bodies: SoftBodySet::new(),
            ccd: CCDSolver::new(),
            gravity: vec3(&model.gravity()),
            bodies_of_links,
            joints,
            axes,
            dof: Vec::new(),
            q: vec![0.0; n],
            qd: vec![0.0; n],
        };
        // Forward kinematics first: it turns the root into a fixed joint, after which the DOF indices are final.
        let (mb, _) = engine.multibody_joints.get_mut(engine.joints[0]).expect("multibody exists");
        mb.forward_kinematics(&engine.bodies, true);
        mb.damping_mut().fill(0.0);
        engine.dof = (0..n)
            .map(|j| {
                let (mb, link) = engine.multibody_joints.get(engine.joints[j]).expect("joint exists");
                mb.link(link).expect("link exists").assembly_id()
            })
            .collect();
        let (mb, _) = engine.multibody_joints.get_mut(engine.joints[0]).expect("multibody exists");
        for j in 0..n {
            let f = &model.joints()[j].friction;
            mb.damping_mut()[engine.dof[j]] = f.viscous;
            mb.frictions_mut()[engine.dof[j]] = f.coulomb;
        }
        engine
    }

    fn read_state(&mut self) {
        let (mb, _) = self.multibody_joints.get(self.joints[0]).expect("multibody exists");
        let v = mb.generalized_velocity();
        for j in 0..self.joints.len() {
            let (mb, link) = self.multibody_joints.get(self.joints[j]).expect("joint exists");
            self.q[j] = mb.link(link).expect("link exists").joint().coords()[3];
            self.qd[j] = v[self.dof[j]];
        }
    }
}

impl Engine for RapierEngine {
    fn kind(&self) -> EngineKind {
        EngineKind::Rapier
    }

    fn reset(&mut self, q: &[f64], qd: &[f64]) {
        self.read_state();
        let current = self.q.clone();
        let (mb, _) = self.multibody_joints.get_mut(self.joints[0]).expect("multibody exists");
        let mut displacement = vec![0.0; mb.ndofs()];
        for j in 0..self.joints.len() {
            displacement[self.dof[j]] = q[j] - current[j];
            mb.generalized_velocity_mut()[self.dof[j]] = qd[j];
        }
        mb.apply_displacements(&displacement);
        mb.forward_kinematics(&self.bodies, false);
        mb.update_rigid_bodies(&mut self.bodies, true);
        self.read_state();
    }

    fn step(&mut self, tau: &[f64]) {
        for &h in &self.bodies_of_links {
            self.bodies[h].reset_torques(false);
        }
        for j in 0..self.joints.len() {
            let (parent, child) = (self.bodies_of_links[j], self.bodies_of_links[j + 1]);
            let axis = self.bodies[child].rotation() * self.axes[j] * tau[j];
            self.bodies[child].add_torque(axis, true);
            // A no-op on the fixed base, as it should be.
            self.bodies[parent].add_torque(-axis, true);
        }
        self.pipeline.step(
            self.gravity,
            &self.params,
            &mut self.islands,
            &mut self.broad_phase,
            &mut self.narrow_phase,
            &mut self.bodies,
            &mut self.colliders,
            &mut self.impulse_joints,
            &mut self.multibody_joints,
            &mut self.soft_bodies,
            &mut self.ccd,
            &(),
            &(),
        );
        self.read_state();
    }

    fn q(&self) -> &[f64] {
        &self.q
    }

    fn qd(&self) -> &[f64] {
        &self.qd
    }
}
