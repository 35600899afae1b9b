//! The paper's robot generator: one fixed kinematic chain, randomized link bodies and joint friction.
//!
//! Robot `id` of seed `seed` is drawn from its own random stream (see [`crate::rng`]), so it is identical whichever
//! process generates it and in whatever order. Inertial parameters follow exactly from the link geometry
//! ([`section`]); every robot is checked for physical validity before it is returned.

pub mod section;

use dynforge_proto::generator::{GeneratorConfig, Range, SectionKind};
pub use section::{Beam, BeamInertia, Section};

use crate::model::{Friction, Geometry, Inertial, Joint, JointKind, Limits, Link, Model, ModelError, Pose, Shape};
use crate::rng::{Rng, domain};
use crate::urdf::BaseLink;

/// A generated robot: the model plus the geometry it was built from (the worker's collision shapes use it).
#[derive(Debug, Clone, PartialEq)]
pub struct GeneratedRobot {
    pub seed: u64,
    pub id: u64,
    pub model: Model,
    /// The body of link 1..6, in model order.
    pub beams: [Beam; 6],
    pub base: BaseLink,
}

impl GeneratedRobot {
    /// The robot's URDF.
    pub fn urdf(&self) -> String {
        crate::urdf::to_string(&self.model, &self.base)
    }
}

fn draw(rng: &mut Rng, r: &Range) -> f64 {
    rng.uniform(r[0], r[1])
}

/// Visual/collision envelope of a beam: a box for the square, else the circumscribed cylinder.
fn envelope(beam: &Beam) -> Geometry {
    let origin = Pose { xyz: [0.0, 0.0, beam.length / 2.0], rpy: [0.0; 3] };
    let shape = match beam.section {
        Section::Square { d } => Shape::Box { size: [d, d, beam.length] },
        s => Shape::Cylinder { radius: s.circumradius(), length: beam.length },
    };
    Geometry { origin, shape }
}

/// Generates robot `id` of dataset `seed`.
pub fn generate(config: &GeneratorConfig, seed: u64, id: u64) -> Result<GeneratedRobot, ModelError> {
    let source = format!("generated robot {id} of seed {seed}");
    config
        .validate()
        .map_err(|e| ModelError { source_name: source.clone(), problem: crate::model::ModelProblem::Config(e.0) })?;
    let k = &config.kinematics;
    let mut rng = Rng::stream(seed, &[domain::ROBOT, id]);
    let mut beams = Vec::with_capacity(6);
    let mut links = Vec::with_capacity(6);
    let mut joints = Vec::with_capacity(6);
    for i in 0..6 {
        // Fixed draw order per link: section kind, diameter, wall, gradient (the wall is drawn even when unused so
        // that changing the section list never shifts the other draws).
        let kind = config.sections[rng.below(config.sections.len())];
        let d = k.nominal_diameters[i] * draw(&mut rng, &config.diameter_scale);
        let wall = d * draw(&mut rng, &config.tube_wall_fraction);
        let gradient = draw(&mut rng, &config.density_gradient);
        let section = match kind {
            SectionKind::Solid => Section::Solid { d },
            SectionKind::Tube => Section::Tube { d, wall },
            SectionKind::Square => Section::Square { d },
            SectionKind::Hexagon => Section::Hexagon { d },
        };
        let beam = Beam { section, length: k.link_lengths[i], gradient, density: config.density };
        let b = beam.inertia();
        links.push(Link {
            name: format!("link_{}", i + 1),
            inertial: Inertial {
                origin: Pose { xyz: [0.0, 0.0, b.com_z], rpy: [0.0; 3] },
                mass: b.mass,
                inertia: [b.ixx, 0.0, 0.0, b.iyy, 0.0, b.izz],
            },
            visuals: vec![envelope(&beam)],
            collisions: vec![envelope(&beam)],
        });
        beams.push(beam);
    }
    for j in 0..6 {
        let friction =
            Friction { coulomb: draw(&mut rng, &config.coulomb[j]), viscous: draw(&mut rng, &config.viscous[j]) };
        let z = if j == 0 { k.pedestal_height } else { k.link_lengths[j - 1] };
        joints.push(Joint {
            name: format!("joint_{j}"),
            kind: JointKind::Revolute,
            origin: Pose { xyz: [0.0, 0.0, z], rpy: [0.0; 3] },
            axis: k.axes[j],
            limits: Limits {
                lower: k.position_limits[j][0],
                upper: k.position_limits[j][1],
                effort: k.effort[j],
                velocity: k.velocity[j],
            },
            friction,
        });
    }
    let pedestal = Geometry {
        origin: Pose { xyz: [0.0, 0.0, k.pedestal_height / 2.0], rpy: [0.0; 3] },
        shape: Shape::Cylinder { radius: k.pedestal_diameter / 2.0, length: k.pedestal_height },
    };
    let model = Model::new(&source, format!("df6_s{seed}_r{id}"), "base_link", joints, links)?;
    Ok(GeneratedRobot {
        seed,
        id,
        model,
        beams: beams.try_into().expect("six beams"),
        base: BaseLink { visuals: vec![pedestal.clone()], collisions: vec![pedestal] },
    })
}
