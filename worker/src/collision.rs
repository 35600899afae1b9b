//! Collision checks of a generated robot against itself, its pedestal and the ground, with parry3d-f64 shapes that
//! match the generated link bodies (cylinders for solid and tube sections, boxes for squares, hexagonal prisms for
//! hexagons), optionally inflated by a safety margin.
//!
//! Adjacent bodies (pedestal-link 1, link k-link k+1) touch at their joint by construction and are not checked.

use dynforge_robot::collision::{pose, y_onto_z};
use dynforge_robot::generator::{GeneratedRobot, Section};
use dynforge_robot::spatial::Se3;
use parry3d_f64::math::{Pose, Vec3};
use parry3d_f64::query::intersection_test;
use parry3d_f64::shape::{ConvexPolyhedron, Cuboid, Cylinder, Shape};

/// A robot's collision bodies: the first contact in the configuration whose link frames are `o_m_i`.
pub trait Collides {
    fn contact(&self, o_m_i: &[Se3]) -> Option<Contact>;
}

/// What two bodies collided. Body 0 is the pedestal, body k (1-6) is link k.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Contact {
    SelfCollision { a: usize, b: usize },
    Ground { link: usize },
}

impl std::fmt::Display for Contact {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Contact::SelfCollision { a: 0, b } => write!(f, "link {b} hits the pedestal"),
            Contact::SelfCollision { a, b } => write!(f, "link {a} hits link {b}"),
            Contact::Ground { link } => write!(f, "link {link} hits the ground"),
        }
    }
}

/// A body: shape, and its placement in the frame of the link it belongs to.
struct Body {
    shape: Box<dyn Shape>,
    offset: Se3,
}

/// The collision bodies of one robot.
pub struct CollisionModel {
    pedestal: Body,
    links: Vec<Body>,
    /// Non-adjacent body pairs to test (0 = pedestal, k = link k).
    pairs: Vec<(usize, usize)>,
    /// Height of the ground plane.
    ground_z: f64,
}

/// A prism of `section` along +z from 0 to `length`, grown by `margin` in every direction.
fn beam_body(section: &Section, length: f64, margin: f64) -> Body {
    // parry's cylinders run along y: turned onto z, centred at mid-length.
    let along_z = Se3::new(y_onto_z(), nalgebra::Vector3::new(0.0, 0.0, length / 2.0));
    let half = length / 2.0 + margin;
    let shape: Box<dyn Shape> = match *section {
        Section::Solid { d } | Section::Tube { d, .. } => Box::new(Cylinder::new(half, d / 2.0 + margin)),
        Section::Square { d } => Box::new(Cuboid::new(Vec3::new(d / 2.0 + margin, half, d / 2.0 + margin))),
        Section::Hexagon { d } => {
            let r = d / 3f64.sqrt() + margin * 2.0 / 3f64.sqrt();
            let points: Vec<Vec3> = (0..12)
                .map(|k| {
                    let t = std::f64::consts::PI / 3.0 * (k % 6) as f64;
                    Vec3::new(r * t.cos(), if k < 6 { -half } else { half }, r * t.sin())
                })
                .collect();
            Box::new(ConvexPolyhedron::from_convex_hull(&points).expect("a hexagonal prism is convex"))
        }
    };
    Body { shape, offset: along_z }
}

impl CollisionModel {
    /// Bodies of `robot`, each grown by `margin` [m] (0 for the exact geometry).
    pub fn new(robot: &GeneratedRobot, margin: f64) -> Self {
        let k = &robot.model;
        let links: Vec<Body> = robot.beams.iter().map(|b| beam_body(&b.section, b.length, margin)).collect();
        let pedestal_h = k.placement(0).trans.z;
        let pedestal_d = match robot.base.collisions.first().map(|g| &g.shape) {
            Some(dynforge_robot::model::Shape::Cylinder { radius, .. }) => 2.0 * radius,
            _ => 0.0,
        };
        let mut pedestal = beam_body(&Section::Solid { d: pedestal_d }, pedestal_h, margin);
        // The pedestal sits on the ground: keep its bottom at z = 0 so it never counts as touching the ground.
        pedestal.offset.trans.z = pedestal_h / 2.0;
        let n = links.len();
        let pairs = (0..=n).flat_map(|a| (a + 2..=n).map(move |b| (a, b))).collect();
        CollisionModel { pedestal, links, pairs, ground_z: 0.0 }
    }

    /// First contact in the configuration whose link frames are `o_m_i` (from forward kinematics), if any.
    pub fn check(&self, o_m_i: &[Se3]) -> Option<Contact> {
        let pose = |body: usize| -> Pose {
            if body == 0 {
                pose(&self.pedestal.offset)
            } else {
                pose(&o_m_i[body - 1].compose(&self.links[body - 1].offset))
            }
        };
        let shape = |body: usize| -> &dyn Shape {
            if body == 0 { self.pedestal.shape.as_ref() } else { self.links[body - 1].shape.as_ref() }
        };
        let poses: Vec<Pose> = (0..=self.links.len()).map(pose).collect();
        // Ground: the lowest point of each link (exact, from its support map). Link 1 stands on the pedestal.
        for link in 2..=self.links.len() {
            let lowest = shape(link).as_support_map().map(|s| s.support_point(&poses[link], -Vec3::Z).z);
            if lowest.is_some_and(|z| z < self.ground_z) {
                return Some(Contact::Ground { link });
            }
        }
        for &(a, b) in &self.pairs {
            let hit =
                intersection_test(&poses[a], shape(a), &poses[b], shape(b)).map(|r| r.intersecting).unwrap_or(true);
            if hit {
                return Some(Contact::SelfCollision { a, b });
            }
        }
        None
    }
}

impl Collides for CollisionModel {
    fn contact(&self, o_m_i: &[Se3]) -> Option<Contact> {
        self.check(o_m_i)
    }
}
