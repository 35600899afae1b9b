//! New dynamic parameters written into the user's own URDF document: only the `<inertial>` of each moving link and
//! the `<dynamics>` of each moving joint change; visuals, collisions, materials, fixed frames, `<ros2_control>`,
//! `<gazebo>`, comments and formatting are kept byte for byte, so the file still drives the user's simulator and
//! controllers.
//!
//! A link with fixed children (a flange, a tool) is one rigid body to the dynamics, and every loader (ours, KDL,
//! Pinocchio, MuJoCo's compiler) adds the children's inertia to the link's. The estimate is of that sum, so the link
//! is given the estimate less its welded children's inertia as the document states them, and the children keep
//! theirs: a loader sums them back to the estimate.

use std::collections::HashMap;

use quick_xml::events::{BytesStart, Event};
use quick_xml::reader::Reader;

use super::{Welds, convert_inertial, parse_welded, weld_position};
use crate::model::{Inertial, Model, ModelError, ModelProblem, check_physical};
use crate::spatial::Inertia;

/// A direct child of `<robot>` (a link or a joint), with its own direct children, as byte ranges of the document.
struct Element {
    tag: String,
    name: String,
    /// Where the element's closing tag starts (`None`: a self-closing element).
    close: Option<usize>,
    start: usize,
    children: Vec<(String, std::ops::Range<usize>)>,
}

fn tag_and_name(e: &BytesStart) -> (String, String) {
    let tag = String::from_utf8_lossy(e.local_name().as_ref()).into_owned();
    let name = e
        .try_get_attribute("name")
        .ok()
        .flatten()
        .map(|a| String::from_utf8_lossy(&a.value).into_owned())
        .unwrap_or_default();
    (tag, name)
}

/// Where and why the XML reader stopped.
#[derive(Debug, thiserror::Error)]
#[error("at byte {at}: {error}")]
struct XmlError {
    at: u64,
    #[source]
    error: quick_xml::Error,
}

/// The links and joints of `doc` with their byte ranges.
fn elements(doc: &str) -> Result<Vec<Element>, XmlError> {
    let mut reader = Reader::from_str(doc);
    let (mut depth, mut out, mut open) = (0usize, Vec::new(), None::<Element>);
    loop {
        let before = reader.buffer_position() as usize;
        let event = reader.read_event().map_err(|error| XmlError { at: reader.error_position(), error })?;
        let after = reader.buffer_position() as usize;
        match event {
            Event::Start(e) => {
                depth += 1;
                let (tag, name) = tag_and_name(&e);
                match (depth, open.as_mut()) {
                    (2, _) => open = Some(Element { tag, name, close: None, start: before, children: Vec::new() }),
                    (3, Some(parent)) => parent.children.push((tag, before..usize::MAX)),
                    _ => {}
                }
            }
            Event::Empty(e) => {
                let (tag, name) = tag_and_name(&e);
                match (depth + 1, open.as_mut()) {
                    (2, _) => out.push(Element { tag, name, close: None, start: before, children: Vec::new() }),
                    (3, Some(parent)) => parent.children.push((tag, before..after)),
                    _ => {}
                }
            }
            Event::End(_) => {
                match (depth, open.as_mut()) {
                    (2, Some(element)) => {
                        element.close = Some(before);
                        out.extend(open.take());
                    }
                    (3, Some(parent)) => {
                        if let Some((_, range)) = parent.children.last_mut() {
                            range.end = after;
                        }
                    }
                    _ => {}
                }
                depth = depth.saturating_sub(1);
            }
            Event::Eof => return Ok(out),
            _ => {}
        }
    }
}

/// The whitespace that starts the line `at` is on.
fn indent_at(doc: &str, at: usize) -> &str {
    let line = doc[..at].rfind('\n').map_or(0, |i| i + 1);
    let rest = &doc[line..at];
    &rest[..rest.len() - rest.trim_start().len()]
}

fn inertial_xml(i: &Inertial, indent: &str) -> String {
    let [ixx, ixy, ixz, iyy, iyz, izz] = i.inertia;
    let (x, r) = (i.origin.xyz, i.origin.rpy);
    format!(
        "<inertial>\n{indent}  <origin xyz=\"{:?} {:?} {:?}\" rpy=\"{:?} {:?} {:?}\"/>\n{indent}  <mass value=\"{:?}\"/>\n\
         {indent}  <inertia ixx=\"{ixx:?}\" ixy=\"{ixy:?}\" ixz=\"{ixz:?}\" iyy=\"{iyy:?}\" iyz=\"{iyz:?}\" \
         izz=\"{izz:?}\"/>\n{indent}</inertial>",
        x[0], x[1], x[2], r[0], r[1], r[2], i.mass
    )
}

/// The edit that puts `text(indent)` in place of `element`'s child `child`, or appends it as a new last child.
fn put(
    document: &str,
    element: &Element,
    child: &str,
    text: impl Fn(&str) -> String,
) -> Option<(std::ops::Range<usize>, String)> {
    if let Some((_, range)) = element.children.iter().find(|(t, _)| t == child) {
        return Some((range.clone(), text(indent_at(document, range.start))));
    }
    let close = element.close?;
    let indent = format!("{}  ", indent_at(document, element.start));
    // Before the closing tag's own indentation, so that it keeps it.
    let at = document[..close].trim_end_matches([' ', '\t']).len();
    Some((at..at, format!("{indent}{}\n", text(&indent))))
}

/// `i` with the entries that are only the subtraction's rounding (below 1e-14 of the largest of their kind, e.g. a
/// product of inertia of 1e-22 next to moments of 1e-4) set to zero, as the document would state them.
fn without_residue(mut i: Inertial) -> Inertial {
    fn clean(v: &mut [f64]) {
        let scale = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        v.iter_mut().filter(|x| x.abs() < 1e-14 * scale).for_each(|x| *x = 0.0);
    }
    clean(&mut i.origin.xyz);
    clean(&mut i.inertia);
    i
}

fn difference(a: &Inertia, b: &Inertia) -> Inertia {
    Inertia { mass: a.mass - b.mass, h: a.h - b.h, i_o: a.i_o - b.i_o }
}

/// An edit of the document: the byte range replaced, and its replacement.
type Edit = (std::ops::Range<usize>, String);

/// The user's document as the patch reads it: its URDF, its links' and joints' elements, and each link's children
/// through fixed joints.
struct Document<'a> {
    robot: &'a urdf_rs::Robot,
    elements: &'a [Element],
    fixed_children: HashMap<&'a str, Vec<&'a str>>,
}

impl<'a> Document<'a> {
    fn new(robot: &'a urdf_rs::Robot, elements: &'a [Element], welds: &Welds) -> Self {
        let fixed_children: HashMap<&str, Vec<&str>> =
            robot.joints.iter().filter(|j| weld_position(j, welds).is_some()).fold(HashMap::new(), |mut m, j| {
                m.entry(j.parent.link.as_str()).or_default().push(j.child.link.as_str());
                m
            });
        Document { robot, elements, fixed_children }
    }

    /// The element `<tag name="name">`.
    fn find(&self, tag: &str, name: &str) -> Option<&'a Element> {
        self.elements.iter().find(|e| e.tag == tag && e.name == name)
    }

    /// The links welded to `link`, as the document has them.
    fn welded_to(&self, link: &str) -> Vec<&'a str> {
        let mut welded = Vec::new();
        let mut stack = vec![link];
        while let Some(l) = stack.pop() {
            for c in self.fixed_children.get(l).into_iter().flatten() {
                welded.push(*c);
                stack.push(c);
            }
        }
        welded
    }

    /// `link`'s own inertia as the document states it (zero if it has none).
    fn own_inertia(&self, link: &str) -> Inertia {
        self.robot
            .links
            .iter()
            .find(|l| l.name == link)
            .map(|l| convert_inertial(&l.inertial))
            .filter(|i| i.mass > 0.0)
            .map_or(Inertia::ZERO, |i| i.spatial())
    }

    /// The `<inertial>` to write on the moving link `name` for the estimate `estimate`, given the inertia `loaded`
    /// that a loader gives the link (its own and its welded links'). The welded links keep theirs as the file states
    /// them; when the estimate less theirs is not a body, `unsplit` decides.
    fn link_inertial(
        &self,
        name: &str,
        (loaded, estimate): (&Inertial, &Inertial),
        unsplit: Unsplit,
        edits: &mut Vec<Edit>,
        notes: &mut Vec<String>,
    ) -> Inertial {
        let children = difference(&loaded.spatial(), &self.own_inertia(name));
        if children.mass <= 0.0 {
            return *estimate;
        }
        let whole = estimate.spatial();
        let own = difference(&whole, &children);
        let Err(why) = check_physical(&own) else { return without_residue(Inertial::from_spatial(&own)) };
        let welded = self.welded_to(name);
        match unsplit {
            Unsplit::Exact => {
                notes.push(format!(
                    "link '{name}': the estimate less its welded links ({}) is not a body ({why}); the whole \
                     estimate is written on '{name}' and their <inertial> elements are removed",
                    welded.join(", ")
                ));
                for w in &welded {
                    let element = self.find("link", w);
                    if let Some((_, range)) = element.and_then(|e| e.children.iter().find(|(t, _)| t == "inertial")) {
                        edits.push((range.clone(), String::new()));
                    }
                }
                *estimate
            }
            Unsplit::KeepWelded => {
                // Lengths in the estimate's own radius of gyration about the link origin, the floor a thousandth of
                // its mass: a small body, but one every simulator takes.
                let length = (whole.pseudo().fixed_view::<3, 3>(0, 0).trace() / whole.mass).sqrt().max(1e-3);
                let near = own.nearest_body(length, NEAREST_FLOOR * whole.mass);
                let written = near + children;
                notes.push(format!(
                    "link '{name}': the estimate less its welded links ({}) is not a body ({why}); '{name}' gets the \
                     nearest body and the welded links keep their <inertial>, so the file's total for them is {:.4} \
                     kg where the estimate is {:.4} kg (centres of mass {:.4} m apart); the JSON and --mjcf hold the \
                     estimate",
                    welded.join(", "),
                    written.mass,
                    whole.mass,
                    (written.com() - whole.com()).norm(),
                ));
                without_residue(Inertial::from_spatial(&near))
            }
        }
    }
}

/// How a patch writes an estimate that cannot be split between a moving link and the links welded to it (the
/// estimate less the welded links' inertia is no physical body).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unsplit {
    /// The file's dynamics are the model's exactly: the whole estimate on the moving link, the welded links'
    /// `<inertial>` removed. For files that must be the model (a family's variant, whose labels its URDF states).
    Exact,
    /// The user's file kept: the welded links keep their `<inertial>` (a tool's, a hand's from CAD), the moving link
    /// gets the nearest body ([`Inertia::nearest_body`]), and a note says what the file's total then is.
    KeepWelded,
}

/// Smallest eigenvalue of a nearest body's scaled pseudo-inertia, as a share of the link's estimated mass.
const NEAREST_FLOOR: f64 = 1e-3;

/// That `document`'s model `original` has the moving joints of `model`, the robot estimated.
fn check_same_joints(original: &Model, model: &Model) -> Result<(), ModelProblem> {
    let names = |m: &Model| m.joints().iter().map(|j| j.name.clone()).collect::<Vec<_>>();
    if names(original) != names(model) {
        return Err(ModelProblem::Parse(format!(
            "its moving joints ({}) are not those of the robot estimated ({})",
            names(original).join(", "),
            names(model).join(", ")
        )));
    }
    Ok(())
}

/// The start tag `tag` (`<name a="1" b='2'/>` or `<name ...>`) with each attribute of `values` set: its value
/// replaced where the tag has it, else the attribute added at the end; every other byte kept.
fn with_attributes(tag: &str, values: &[(&str, String)]) -> String {
    let mut out = tag.to_string();
    for (name, value) in values {
        let found = [b'"', b'\''].iter().find_map(|&quote| {
            let pattern = format!("{name}={}", quote as char);
            out.match_indices(&pattern)
                .find(|(k, _)| out[..*k].ends_with(char::is_whitespace))
                .map(|(k, _)| (k + pattern.len(), quote as char))
        });
        match found {
            Some((start, quote)) => {
                let end = out[start..].find(quote).map_or(out.len(), |k| start + k);
                out.replace_range(start..end, value);
            }
            None => {
                let close = out.trim_end_matches('>').trim_end_matches('/').trim_end().len();
                out.insert_str(close, &format!(" {name}=\"{value}\""));
            }
        }
    }
    out
}

/// `document` with `edits` (of disjoint ranges) made.
fn apply(document: &str, edits: Vec<Edit>) -> String {
    // Edits at one place go in the reverse of their order (each inserted before the one made there before it).
    let mut edits: Vec<(usize, Edit)> = edits.into_iter().enumerate().collect();
    edits.sort_by_key(|(k, (range, _))| (range.start, std::cmp::Reverse(*k)));
    let mut out = String::with_capacity(document.len() + edits.iter().map(|(_, (_, text))| text.len()).sum::<usize>());
    let mut at = 0;
    for (_, (range, text)) in edits {
        out.push_str(&document[at..range.start]);
        out.push_str(&text);
        at = range.end;
    }
    out.push_str(&document[at..]);
    out
}

/// `document` (the URDF `source`, with the kinematics of `model`) with `model`'s inertia and friction written into
/// it, and notes on what could not be written as asked. Everything but the moving links' `<inertial>` and the moving
/// joints' `<dynamics>` is kept as it was.
pub fn patch(document: &str, source: &str, model: &Model) -> Result<(String, Vec<String>), ModelError> {
    patch_welded(document, source, model, &Welds::new(), Unsplit::KeepWelded)
}

/// [`patch`] for a `model` read with the joints of `welds` welded ([`super::parse_welded`]): the links they carry
/// keep their own inertia, as fixed ones do; an estimate that cannot be split is written as `unsplit` says.
pub fn patch_welded(
    document: &str,
    source: &str,
    model: &Model,
    welds: &Welds,
    unsplit: Unsplit,
) -> Result<(String, Vec<String>), ModelError> {
    let err = |problem| ModelError { source_name: source.to_string(), problem };
    let original = parse_welded(document, source, welds)?;
    check_same_joints(&original, model).map_err(err)?;
    let robot = super::read(document, source)?;
    let elements = elements(document).map_err(|e| err(ModelProblem::Parse(e.to_string())))?;
    let doc = Document::new(&robot, &elements, welds);
    let mut edits: Vec<Edit> = Vec::new();
    let mut notes = Vec::new();
    for (k, (joint, link)) in model.joints().iter().zip(model.links()).enumerate() {
        let element = doc
            .find("joint", &joint.name)
            .ok_or_else(|| err(ModelProblem::Parse(format!("no joint '{}'", joint.name))))?;
        let f = joint.friction;
        let values = [("damping", format!("{:?}", f.viscous)), ("friction", format!("{:?}", f.coulomb))];
        match element.children.iter().find(|(t, _)| t == "dynamics") {
            // The element's other attributes (a simulator's own: Gazebo's, a driver's) are kept as written.
            Some((_, range)) => {
                let end = document[range.clone()].find('>').map_or(range.end, |k| range.start + k + 1);
                edits.push((range.start..end, with_attributes(&document[range.start..end], &values)));
            }
            None => edits.extend(put(document, element, "dynamics", |_| {
                format!("<dynamics damping=\"{}\" friction=\"{}\"/>", values[0].1, values[1].1)
            })),
        }

        let name = &original.links()[k].name;
        let element = doc.find("link", name).ok_or_else(|| err(ModelProblem::Parse(format!("no link '{name}'"))))?;
        let loaded = &original.links()[k].inertial;
        let inertial = doc.link_inertial(name, (loaded, &link.inertial), unsplit, &mut edits, &mut notes);
        edits.extend(put(document, element, "inertial", |indent| inertial_xml(&inertial, indent)));
    }
    Ok((apply(document, edits), notes))
}
