//! URDF in and out, via urdf-rs.
//!
//! Reading accepts any URDF whose moving joints form one serial chain of revolute, continuous and prismatic joints
//! from the root. Fixed joints are welded: a fixed subtree's inertia is merged into the moving link it hangs from (or
//! into the base, where it never moves), so real-world files such as the UR5's (with `base`, `ee_link` and `tool0`
//! frames) load. Mimic joints (a gripper's second finger) and the joints a caller names are welded too, at a given
//! position: what a log that does not move them, or does not have them, shows of the robot. Anything else
//! (floating, planar joints; two moving branches left) is rejected with the element's name.

mod patch;

pub use patch::{Unsplit, patch, patch_welded};

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::Path;

use crate::model::{
    Friction, Geometry, Inertial, Joint, JointKind, Limits, Link, Model, ModelError, ModelProblem, Pose, Shape,
};
use crate::spatial::{Inertia, Se3};

/// Loads a model from a URDF file. Errors name the file and the offending element.
pub fn load(path: impl AsRef<Path>) -> Result<Model, ModelError> {
    let path = path.as_ref();
    let source = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| ModelError { source_name: source.clone(), problem: ModelProblem::Io(e.to_string()) })?;
    parse(&text, &source)
}

/// Joints welded at a position (an angle, or a displacement along a prismatic axis), by name.
pub type Welds = BTreeMap<String, f64>;

/// Parses URDF text; `source_name` labels errors (usually the file path). Mimic joints are welded at 0.
pub fn parse(text: &str, source_name: &str) -> Result<Model, ModelError> {
    parse_welded(text, source_name, &Welds::new())
}

/// [`parse`], with the joints of `welds` welded at their positions (mimic joints not in it at 0).
pub fn parse_welded(text: &str, source_name: &str, welds: &Welds) -> Result<Model, ModelError> {
    build(&read(text, source_name)?, source_name, welds)
}

/// The collision geometry of every body of the model [`parse_welded`] gives, each in its body's frame: body 0 is the
/// fixed base (the root link and everything welded to it), body k the model's link k with what is welded to it (a
/// gripper's hand and fingers on the last link).
pub fn collision_bodies(text: &str, source_name: &str, welds: &Welds) -> Result<Vec<Vec<Geometry>>, ModelError> {
    let err = |problem| ModelError { source_name: source_name.to_string(), problem };
    let robot = read(text, source_name)?;
    let tree = Tree::of(&robot).map_err(err)?;
    let (chain, base) = moving_chain(&tree, welds).map_err(err)?;
    Ok(std::iter::once(base).chain(chain.into_iter().map(|m| m.geometry)).collect())
}

fn read(text: &str, source_name: &str) -> Result<urdf_rs::Robot, ModelError> {
    let err = |problem| ModelError { source_name: source_name.to_string(), problem };
    // The XML reader recurses per element: 20,000 nested elements overflow its stack (an abort, not an error).
    if nesting_exceeds(text, MAX_NESTING) {
        return Err(err(ModelProblem::TooDeep(MAX_NESTING)));
    }
    urdf_rs::read_from_string(&without_comments(text))
        .map_err(|e| err(ModelProblem::Parse(bad_number(text).unwrap_or_else(|| e.to_string()))))
}

/// `text` with its XML comments replaced by the line breaks they held (so that a parser's line numbers still point
/// into the file). The URDF reader copies the document several times over as it parses: a 150 MB comment took
/// 1.2 GB, the comment-free text takes what the robot's elements take.
fn without_comments(text: &str) -> std::borrow::Cow<'_, str> {
    if !text.contains("<!--") {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len().min(1 << 20));
    let mut rest = text;
    loop {
        // A CDATA section's text is not markup, comment marks in it included: copied as it is.
        let (comment, cdata) = (rest.find("<!--"), rest.find("<![CDATA["));
        let (start, close) = match (comment, cdata) {
            (Some(c), Some(d)) if d < c => (d, "]]>"),
            (Some(c), _) => (c, "-->"),
            (None, _) => break,
        };
        let Some(end) = rest[start + 4..].find(close).map(|e| start + 4 + e + close.len()) else { break };
        out.push_str(&rest[..start]);
        match close {
            "-->" => out.extend(rest[start..end].matches('\n')),
            _ => out.push_str(&rest[start..end]),
        }
        rest = &rest[end..];
    }
    out.push_str(rest);
    std::borrow::Cow::Owned(out)
}

/// The joints of the URDF `text` that can move, in document order: those that are degrees of freedom of their own
/// (revolute, continuous, prismatic), and the mimic joints that follow another. What a caller may weld.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MovableJoints {
    pub free: Vec<String>,
    pub mimic: Vec<String>,
}

/// The [`MovableJoints`] of the URDF `text`.
pub fn movable_joints(text: &str, source_name: &str) -> Result<MovableJoints, ModelError> {
    let robot = read(text, source_name)?;
    let names = |keep: &dyn Fn(&urdf_rs::Joint) -> bool| {
        robot.joints.iter().filter(|j| keep(j)).map(|j| j.name.clone()).collect()
    };
    Ok(MovableJoints {
        free: names(&moves),
        mimic: names(&|j| j.mimic.is_some() && j.joint_type != urdf_rs::JointType::Fixed),
    })
}

/// Whether `j` is a degree of freedom of its own.
fn moves(j: &urdf_rs::Joint) -> bool {
    use urdf_rs::JointType::*;
    matches!(j.joint_type, Revolute | Continuous | Prismatic) && j.mimic.is_none()
}

/// Deepest element nesting accepted. Real URDFs nest 3-5 levels (robot, link, inertial, origin); xacro output and
/// vendor extensions (`<gazebo>`, `<ros2_control>`) add a few.
const MAX_NESTING: usize = 256;

/// Whether `text`'s elements nest deeper than `max`, by a scan of its tags (comments, declarations and quoted
/// attribute values skipped). Malformed text is left to the XML reader to report.
fn nesting_exceeds(text: &str, max: usize) -> bool {
    let b = text.as_bytes();
    let (mut i, mut depth) = (0usize, 0usize);
    while let Some(open) = b[i..].iter().position(|&c| c == b'<').map(|p| p + i) {
        let rest = &text[open..];
        if rest.starts_with("<!--") {
            i = rest.find("-->").map_or(b.len(), |e| open + e + 3);
            continue;
        }
        // The tag's end, skipping '>' inside quoted attribute values.
        let (mut end, mut quote) = (open + 1, None);
        while end < b.len() {
            match (b[end], quote) {
                (q @ (b'"' | b'\''), None) => quote = Some(q),
                (c, Some(q)) if c == q => quote = None,
                (b'>', None) => break,
                _ => {}
            }
            end += 1;
        }
        match b.get(open + 1) {
            Some(b'/') => depth = depth.saturating_sub(1),
            Some(b'!' | b'?') => {}
            _ if end > 0 && b.get(end - 1) == Some(&b'/') => {}
            _ => {
                depth += 1;
                if depth > max {
                    return true;
                }
            }
        }
        i = end + 1;
        if i >= b.len() {
            break;
        }
    }
    false
}

/// Where a number attribute of the URDF is not one: the XML reader's own error ("invalid float literal") names no
/// element or line. Only the attributes dynforge reads as numbers are looked at.
fn bad_number(text: &str) -> Option<String> {
    const NUMERIC: [(&str, &[&str]); 6] = [
        ("mass", &["value"]),
        ("inertia", &["ixx", "ixy", "ixz", "iyy", "iyz", "izz"]),
        ("origin", &["xyz", "rpy"]),
        ("axis", &["xyz"]),
        ("limit", &["lower", "upper", "effort", "velocity"]),
        ("dynamics", &["damping", "friction"]),
    ];
    for (line_no, line) in text.lines().enumerate() {
        for tag in line.split('<').skip(1) {
            let tag = tag.split('>').next().unwrap_or(tag);
            let name = tag.split_whitespace().next().unwrap_or("");
            let Some((_, attrs)) = NUMERIC.iter().find(|(n, _)| *n == name) else { continue };
            for attr in attrs.iter() {
                for quote in ['"', '\''] {
                    let key = format!("{attr}={quote}");
                    let Some(start) = tag.find(&key).map(|i| i + key.len()) else { continue };
                    let value = tag[start..].split(quote).next().unwrap_or("");
                    if let Some(bad) = value.split_whitespace().find(|v| v.parse::<f64>().is_err()) {
                        return Some(format!(
                            "line {}: <{name} {attr}=\"{value}\">: '{bad}' is not a number",
                            line_no + 1
                        ));
                    }
                }
            }
        }
    }
    None
}

/// How far beyond its range (a share of it) a joint may be welded: a log's mean position of a joint held at its
/// limit, with encoder noise, sits a hair outside.
const WELD_SLACK: f64 = 0.01;

fn build(robot: &urdf_rs::Robot, source_name: &str, welds: &Welds) -> Result<Model, ModelError> {
    let err = |problem| ModelError { source_name: source_name.to_string(), problem };
    check_unique_names(robot).map_err(err)?;
    if let Some(name) = welds.keys().find(|w| !robot.joints.iter().any(|j| &&j.name == w)) {
        return Err(err(ModelProblem::InvalidJoint { joint: name.clone(), reason: "no such joint to weld".into() }));
    }
    for j in robot.joints.iter().filter(|j| welds.contains_key(&j.name)) {
        use urdf_rs::JointType::{Prismatic, Revolute};
        let (q, (lower, upper)) = (welds[&j.name], (j.limit.lower, j.limit.upper));
        // A log's mean position of a joint held at its limit may sit a hair beyond it (encoder noise).
        let slack = WELD_SLACK * (upper - lower).abs();
        if matches!(j.joint_type, Revolute | Prismatic) && !(q >= lower - slack && q <= upper + slack) {
            let reason = format!("welded at {q}, outside its range [{lower}, {upper}]");
            return Err(err(ModelProblem::InvalidJoint { joint: j.name.clone(), reason }));
        }
    }
    let tree = Tree::of(robot).map_err(err)?;
    let (chain, _) = moving_chain(&tree, welds).map_err(err)?;
    let (joints, links) = chain.into_iter().map(Moving::into_joint_and_link).unzip();
    Model::new(source_name, robot.name.clone(), tree.root, joints, links)
}

/// That no two links and no two joints share a name.
fn check_unique_names(robot: &urdf_rs::Robot) -> Result<(), ModelProblem> {
    let mut seen = HashSet::new();
    for (kind, name) in
        robot.links.iter().map(|l| ("link", &l.name)).chain(robot.joints.iter().map(|j| ("joint", &j.name)))
    {
        if !seen.insert((kind, name.as_str())) {
            return Err(ModelProblem::Duplicate { kind, name: name.clone() });
        }
    }
    Ok(())
}

/// The URDF's links by name, the joints hanging from each link, and its one root link.
struct Tree<'a> {
    links: HashMap<&'a str, &'a urdf_rs::Link>,
    children: HashMap<&'a str, Vec<&'a urdf_rs::Joint>>,
    root: &'a str,
}

impl<'a> Tree<'a> {
    /// The tree of `robot`: every joint joins two defined links, no link has two parents, and one link has none.
    fn of(robot: &'a urdf_rs::Robot) -> Result<Self, ModelProblem> {
        let links: HashMap<&str, &urdf_rs::Link> = robot.links.iter().map(|l| (l.name.as_str(), l)).collect();
        let mut children: HashMap<&str, Vec<&urdf_rs::Joint>> = HashMap::new();
        let mut has_parent: HashMap<&str, &str> = HashMap::new();
        for j in &robot.joints {
            for link in [&j.parent.link, &j.child.link] {
                if !links.contains_key(link.as_str()) {
                    return Err(ModelProblem::UnknownLink { joint: j.name.clone(), link: link.clone() });
                }
            }
            if has_parent.insert(&j.child.link, &j.name).is_some() {
                return Err(ModelProblem::MultipleParents { link: j.child.link.clone() });
            }
            children.entry(&j.parent.link).or_default().push(j);
        }
        let roots: Vec<&str> =
            robot.links.iter().map(|l| l.name.as_str()).filter(|l| !has_parent.contains_key(l)).collect();
        if roots.len() != 1 {
            return Err(ModelProblem::Roots(roots.len()));
        }
        Ok(Tree { links, children, root: roots[0] })
    }
}

/// A moving joint and its link, with the inertia of the links welded to it by fixed joints, and the collision
/// geometry of the link and of those welded to it.
struct Moving {
    joint: Joint,
    link: Link,
    welded: Inertia,
    has_weld: bool,
    geometry: Vec<Geometry>,
}

impl Moving {
    /// Moving joint `j` to link `child`, where `j`'s parent link sits at `x` in the frame of the moving link it is
    /// welded to, and `origin` is `j`'s own placement.
    fn new(j: &urdf_rs::Joint, child: &urdf_rs::Link, x: &Se3, origin: &Se3) -> Self {
        // Keep the file's own numbers when no fixed joint sits in between: lossless round trips.
        let origin_pose = if *x == Se3::IDENTITY {
            Pose { xyz: *j.origin.xyz, rpy: *j.origin.rpy }
        } else {
            Pose::from_se3(&x.compose(origin))
        };
        let link = convert_link(child);
        Moving {
            joint: convert_joint(j, origin_pose),
            geometry: link.collisions.clone(),
            link,
            welded: Inertia::ZERO,
            has_weld: false,
        }
    }

    /// Welds the URDF link `child`, whose frame is at `x` in this link's frame, onto this link.
    fn weld(&mut self, child: &urdf_rs::Link, x: &Se3) {
        let i = convert_inertial(&child.inertial).spatial().transformed(x);
        self.welded = self.welded + i;
        self.has_weld = true;
    }

    /// The model's joint and link, the link carrying the inertia welded to it.
    fn into_joint_and_link(self) -> (Joint, Link) {
        let mut link = self.link;
        if self.has_weld {
            let own = if link.inertial.mass > 0.0 { link.inertial.spatial() } else { Inertia::ZERO };
            link.inertial = Inertial::from_spatial(&(own + self.welded));
        }
        (self.joint, link)
    }
}

/// The collision geometry of the URDF link `link`, whose frame is at `x` in its body's frame, in the body's frame.
fn placed_collisions(link: &urdf_rs::Link, x: &Se3) -> impl Iterator<Item = Geometry> {
    link.collision.iter().map(move |c| {
        let g = convert_geometry(&c.origin, &c.geometry);
        Geometry { origin: Pose::from_se3(&x.compose(&g.origin.se3())), shape: g.shape }
    })
}

/// The joint `j`'s motion at position `q` as a transform (its frame after the motion in its frame before).
fn joint_motion(j: &urdf_rs::Joint, q: f64) -> Se3 {
    let axis = nalgebra::Vector3::from(*j.axis.xyz);
    let Some(axis) = nalgebra::Unit::try_new(axis, 1e-12) else { return Se3::IDENTITY };
    match j.joint_type {
        urdf_rs::JointType::Prismatic => Se3::new(nalgebra::Matrix3::identity(), axis.into_inner() * q),
        urdf_rs::JointType::Fixed => Se3::IDENTITY,
        _ => Se3::revolute(&axis, q),
    }
}

/// The position `j` is welded at, if it is welded: a fixed joint at its origin, a mimic joint or one of `welds` at
/// the given position (mimic joints not given: 0).
fn weld_position(j: &urdf_rs::Joint, welds: &Welds) -> Option<f64> {
    match (j.joint_type == urdf_rs::JointType::Fixed, welds.get(&j.name)) {
        (true, _) => Some(0.0),
        (false, Some(&q)) => Some(q),
        (false, None) => j.mimic.is_some().then_some(0.0),
    }
}

/// The moving joints of `tree` in chain order, found by a walk from the root. On the walk's stack, `body` is the
/// moving link a URDF link is welded to (None: the fixed base) and `x` the URDF link's frame in that body's frame.
/// With the chain, the collision geometry of the fixed base.
fn moving_chain(tree: &Tree, welds: &Welds) -> Result<(Vec<Moving>, Vec<Geometry>), ModelProblem> {
    let mut chain: Vec<Moving> = Vec::new();
    let mut base: Vec<Geometry> = placed_collisions(tree.links[tree.root], &Se3::IDENTITY).collect();
    let mut moving_child_of: HashMap<Option<usize>, String> = HashMap::new();
    let mut stack: Vec<(&str, Option<usize>, Se3)> = vec![(tree.root, None, Se3::IDENTITY)];
    while let Some((link_name, body, x)) = stack.pop() {
        for j in tree.children.get(link_name).map(Vec::as_slice).unwrap_or(&[]) {
            let origin = Se3::from_xyz_rpy(*j.origin.xyz, *j.origin.rpy);
            let child = tree.links[j.child.link.as_str()];
            if let Some(q) = weld_position(j, welds) {
                let xc = x.compose(&origin).compose(&joint_motion(j, q));
                match body {
                    Some(b) => chain[b].geometry.extend(placed_collisions(child, &xc)),
                    None => base.extend(placed_collisions(child, &xc)),
                }
                if let Some(b) = body
                    && child.inertial.mass.value > 0.0
                {
                    chain[b].weld(child, &xc);
                }
                stack.push((&j.child.link, body, xc));
                continue;
            }
            match j.joint_type {
                urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous | urdf_rs::JointType::Prismatic => {
                    check_serial(tree.root, &chain, &mut moving_child_of, body, j)?;
                    let index = chain.len();
                    chain.push(Moving::new(j, child, &x, &origin));
                    stack.push((&j.child.link, Some(index), Se3::IDENTITY));
                }
                ref other => {
                    return Err(ModelProblem::UnsupportedJoint {
                        joint: j.name.clone(),
                        kind: format!("{other:?}").to_lowercase(),
                    });
                }
            }
        }
    }
    Ok((chain, base))
}

/// That the moving joint `j`, below the moving link `body` (None: the base, named `root`), continues the serial
/// chain found so far: it is `body`'s only moving child, and `body` is the chain's last link.
fn check_serial(
    root: &str,
    chain: &[Moving],
    moving_child_of: &mut HashMap<Option<usize>, String>,
    body: Option<usize>,
    j: &urdf_rs::Joint,
) -> Result<(), ModelProblem> {
    if let Some(other) = moving_child_of.insert(body, j.name.clone()) {
        let parent = body.map_or(root.to_string(), |b| chain[b].link.name.clone());
        return Err(ModelProblem::Branching { link: parent, joints: format!("'{other}', '{}'", j.name) });
    }
    let index = chain.len();
    if body.is_some_and(|b| b + 1 != index) || (body.is_none() && index != 0) {
        return Err(ModelProblem::Branching {
            link: j.parent.link.clone(),
            joints: format!("'{}' and an earlier branch", j.name),
        });
    }
    Ok(())
}

fn convert_inertial(i: &urdf_rs::Inertial) -> Inertial {
    let t = &i.inertia;
    Inertial {
        origin: Pose { xyz: *i.origin.xyz, rpy: *i.origin.rpy },
        mass: i.mass.value,
        inertia: [t.ixx, t.ixy, t.ixz, t.iyy, t.iyz, t.izz],
    }
}

fn convert_joint(j: &urdf_rs::Joint, origin: Pose) -> Joint {
    let kind = match j.joint_type {
        urdf_rs::JointType::Continuous => JointKind::Continuous,
        urdf_rs::JointType::Prismatic => JointKind::Prismatic,
        _ => JointKind::Revolute,
    };
    let continuous = kind == JointKind::Continuous;
    let (lower, upper) = if continuous { (f64::NEG_INFINITY, f64::INFINITY) } else { (j.limit.lower, j.limit.upper) };
    let friction =
        j.dynamics.as_ref().map_or(Friction::default(), |d| Friction { coulomb: d.friction, viscous: d.damping });
    Joint {
        name: j.name.clone(),
        kind,
        origin,
        axis: *j.axis.xyz,
        limits: Limits { lower, upper, effort: j.limit.effort, velocity: j.limit.velocity },
        friction,
    }
}

fn convert_geometry(origin: &urdf_rs::Pose, g: &urdf_rs::Geometry) -> Geometry {
    let shape = match g {
        urdf_rs::Geometry::Box { size } => Shape::Box { size: **size },
        urdf_rs::Geometry::Cylinder { radius, length } => Shape::Cylinder { radius: *radius, length: *length },
        urdf_rs::Geometry::Capsule { radius, length } => Shape::Capsule { radius: *radius, length: *length },
        urdf_rs::Geometry::Sphere { radius } => Shape::Sphere { radius: *radius },
        urdf_rs::Geometry::Mesh { filename, scale } => {
            Shape::Mesh { filename: filename.clone(), scale: scale.map(|s| *s) }
        }
    };
    Geometry { origin: Pose { xyz: *origin.xyz, rpy: *origin.rpy }, shape }
}

fn convert_link(l: &urdf_rs::Link) -> Link {
    Link {
        name: l.name.clone(),
        inertial: convert_inertial(&l.inertial),
        visuals: l.visual.iter().map(|v| convert_geometry(&v.origin, &v.geometry)).collect(),
        collisions: l.collision.iter().map(|c| convert_geometry(&c.origin, &c.geometry)).collect(),
    }
}

fn pose(p: &Pose) -> urdf_rs::Pose {
    urdf_rs::Pose { xyz: urdf_rs::Vec3(p.xyz), rpy: urdf_rs::Vec3(p.rpy) }
}

fn geometry(g: &Geometry) -> (urdf_rs::Pose, urdf_rs::Geometry) {
    let geom = match &g.shape {
        Shape::Box { size } => urdf_rs::Geometry::Box { size: urdf_rs::Vec3(*size) },
        Shape::Cylinder { radius, length } => urdf_rs::Geometry::Cylinder { radius: *radius, length: *length },
        Shape::Capsule { radius, length } => urdf_rs::Geometry::Capsule { radius: *radius, length: *length },
        Shape::Sphere { radius } => urdf_rs::Geometry::Sphere { radius: *radius },
        Shape::Mesh { filename, scale } => {
            urdf_rs::Geometry::Mesh { filename: filename.clone(), scale: scale.map(urdf_rs::Vec3) }
        }
    };
    (pose(&g.origin), geom)
}

/// Extra content for the base link of a written URDF (the model itself does not store the base's geometry).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BaseLink {
    pub visuals: Vec<Geometry>,
    pub collisions: Vec<Geometry>,
}

/// Writes a model as URDF text. Every parameter is written with round-trip precision, so [`parse`] of the result
/// gives back an identical model.
pub fn to_string(model: &Model, base: &BaseLink) -> String {
    let visual = |g: &Geometry| {
        let (origin, geometry) = geometry(g);
        urdf_rs::Visual { name: None, origin, geometry, material: None }
    };
    let collision = |g: &Geometry| {
        let (origin, geometry) = geometry(g);
        urdf_rs::Collision { name: None, origin, geometry }
    };
    let mut links = vec![urdf_rs::Link {
        name: model.base().to_string(),
        // A fixed base needs no mass; write a tiny positive one because some loaders reject massless links.
        inertial: urdf_rs::Inertial {
            origin: urdf_rs::Pose::default(),
            mass: urdf_rs::Mass { value: 1.0 },
            inertia: urdf_rs::Inertia { ixx: 1e-3, ixy: 0.0, ixz: 0.0, iyy: 1e-3, iyz: 0.0, izz: 1e-3 },
        },
        visual: base.visuals.iter().map(visual).collect(),
        collision: base.collisions.iter().map(collision).collect(),
    }];
    let mut joints = Vec::with_capacity(model.dof());
    for (i, (j, l)) in model.joints().iter().zip(model.links()).enumerate() {
        let [ixx, ixy, ixz, iyy, iyz, izz] = l.inertial.inertia;
        links.push(urdf_rs::Link {
            name: l.name.clone(),
            inertial: urdf_rs::Inertial {
                origin: pose(&l.inertial.origin),
                mass: urdf_rs::Mass { value: l.inertial.mass },
                inertia: urdf_rs::Inertia { ixx, ixy, ixz, iyy, iyz, izz },
            },
            visual: l.visuals.iter().map(visual).collect(),
            collision: l.collisions.iter().map(collision).collect(),
        });
        let parent = if i == 0 { model.base().to_string() } else { model.links()[i - 1].name.clone() };
        let lim = &j.limits;
        joints.push(urdf_rs::Joint {
            name: j.name.clone(),
            joint_type: match j.kind {
                JointKind::Revolute => urdf_rs::JointType::Revolute,
                JointKind::Continuous => urdf_rs::JointType::Continuous,
                JointKind::Prismatic => urdf_rs::JointType::Prismatic,
            },
            origin: pose(&j.origin),
            parent: urdf_rs::LinkName { link: parent },
            child: urdf_rs::LinkName { link: l.name.clone() },
            axis: urdf_rs::Axis { xyz: urdf_rs::Vec3(j.axis) },
            limit: urdf_rs::JointLimit {
                lower: lim.lower,
                upper: lim.upper,
                effort: lim.effort,
                velocity: lim.velocity,
                ..urdf_rs::JointLimit::default()
            },
            calibration: None,
            dynamics: Some(urdf_rs::Dynamics { damping: j.friction.viscous, friction: j.friction.coulomb }),
            mimic: None,
            safety_controller: None,
        });
    }
    let robot = urdf_rs::Robot { name: model.name().to_string(), version: None, links, joints, materials: vec![] };
    // Serialising plain numbers and strings into a String cannot fail.
    let body = urdf_rs::write_to_string(&robot).expect("URDF serialisation of a validated model");
    format!("<?xml version=\"1.0\"?>\n{body}\n")
}
