//! Self-collision along a trajectory, with the URDF's collision geometry (meshes as convex hulls): a designed motion
//! must not drive the arm into itself. Pairs of bodies that touch by construction are not checked, as MoveIt's
//! allowed-collision matrix leaves them out: bodies joined by one joint, and bodies already in contact at the start
//! pose (where conservative hulls overlap around a joint).

use std::path::Path;

use dynforge_robot::collision::{Placed, pose, shape_of};
use dynforge_robot::model::Geometry;
use dynforge_robot::{Data, Model, forward_kinematics};
use parry3d_f64::query::{distance, intersection_test};

use crate::ExciteError;

/// The bodies of a robot (0: the fixed base; k: link k with what is welded to it) and the pairs to check.
pub struct SelfCollision {
    bodies: Vec<Vec<Placed>>,
    names: Vec<String>,
    pairs: Vec<(usize, usize)>,
    /// Distance below which two bodies count as touching [m] (MoveIt's padding).
    clearance: f64,
}

impl SelfCollision {
    /// The bodies of `model` from `geometry` (`dynforge_robot::urdf::collision_bodies` of the URDF at `urdf`), with
    /// the pairs that are apart at the pose `start`; bodies closer than `clearance` [m] count as touching. The pairs
    /// checked are those apart at the start whatever the clearance (a padding checks more closely, not fewer
    /// pairs), so a start where a checked pair is closer than the clearance is refused, naming it.
    pub fn new(
        model: &Model,
        geometry: &[Vec<Geometry>],
        urdf: &Path,
        start: &[f64],
        clearance: f64,
    ) -> Result<Self, ExciteError> {
        let bodies = geometry
            .iter()
            .map(|g| g.iter().map(|g| shape_of(g, urdf)).collect::<Result<Vec<_>, _>>())
            .collect::<Result<Vec<_>, _>>()?;
        let names =
            std::iter::once(model.base().to_string()).chain(model.links().iter().map(|l| l.name.clone())).collect();
        let n = geometry.len();
        let candidates: Vec<(usize, usize)> = (0..n)
            .flat_map(|a| (a + 2..n).map(move |b| (a, b)))
            .filter(|&(a, b)| !geometry[a].is_empty() && !geometry[b].is_empty())
            .collect();
        let mut c = SelfCollision { bodies, names, pairs: candidates, clearance: 0.0 };
        let mut data = Data::new(model);
        let at_start = c.contacts(model, &mut data, start);
        c.pairs.retain(|p| !at_start.contains(p));
        c.clearance = clearance;
        let close: Vec<String> = (c.contacts(model, &mut data, start).into_iter())
            .map(|p| format!("{} ({:.1} mm)", c.describe(p), 1e3 * c.distance(model, &mut data, start, p)))
            .collect();
        if !close.is_empty() {
            return Err(ExciteError::Option(format!(
                "--clearance {clearance} m: at the start pose {} are closer than that already (they are checked \
                 whatever the clearance); lower --clearance or choose another --start",
                close.join(", ")
            )));
        }
        Ok(c)
    }

    /// Pairs checked, and pairs left out because they touch at the start pose.
    pub fn pairs(&self) -> usize {
        self.pairs.len()
    }

    /// The distance below which bodies count as touching [m].
    pub fn padding(&self) -> f64 {
        self.clearance
    }

    /// Names of bodies `a` and `b`.
    pub fn describe(&self, (a, b): (usize, usize)) -> String {
        format!("{} and {}", self.names[a], self.names[b])
    }

    fn placements(&self, model: &Model, data: &mut Data, q: &[f64]) -> Vec<Vec<parry3d_f64::math::Pose>> {
        forward_kinematics(model, data, q);
        self.bodies
            .iter()
            .enumerate()
            .map(|(k, shapes)| {
                let frame = if k == 0 { dynforge_robot::spatial::Se3::IDENTITY } else { data.o_m_i[k - 1] };
                shapes.iter().map(|s| pose(&frame.compose(&s.offset))).collect()
            })
            .collect()
    }

    /// The checked pairs in contact at `q`.
    pub fn contacts(&self, model: &Model, data: &mut Data, q: &[f64]) -> Vec<(usize, usize)> {
        let at = self.placements(model, data, q);
        self.pairs.iter().copied().filter(|&(a, b)| self.touch(&at, a, b)).collect()
    }

    /// The first checked pair in contact at `q`, if any.
    pub fn first_contact(&self, model: &Model, data: &mut Data, q: &[f64]) -> Option<(usize, usize)> {
        let at = self.placements(model, data, q);
        self.pairs.iter().copied().find(|&(a, b)| self.touch(&at, a, b))
    }

    /// The distance between bodies `a` and `b` at `q` [m] (0 where they intersect).
    fn distance(&self, model: &Model, data: &mut Data, q: &[f64], pair: (usize, usize)) -> f64 {
        self.pair_distance(&self.placements(model, data, q), pair)
    }

    /// The distance between bodies `a` and `b` placed at `at` [m]. Unsupported shape pairs do not occur among
    /// primitives and convex hulls; they count as touching (0).
    fn pair_distance(&self, at: &[Vec<parry3d_f64::math::Pose>], (a, b): (usize, usize)) -> f64 {
        let each = self.bodies[a].iter().zip(&at[a]).flat_map(|(sa, pa)| {
            self.bodies[b]
                .iter()
                .zip(&at[b])
                .map(move |(sb, pb)| distance(pa, sa.shape.as_ref(), pb, sb.shape.as_ref()).map_or(0.0, |d| d.distance))
        });
        each.fold(f64::INFINITY, f64::min)
    }

    /// The smallest distance between checked pairs at `q` [m], and the pair.
    pub fn clearance(&self, model: &Model, data: &mut Data, q: &[f64]) -> Option<(f64, (usize, usize))> {
        let at = self.placements(model, data, q);
        self.pairs.iter().map(|&p| (self.pair_distance(&at, p), p)).min_by(|x, y| x.0.total_cmp(&y.0))
    }

    /// Whether bodies `a` and `b` are closer than the clearance (touching when it is 0). Unsupported shape pairs do
    /// not occur among primitives and convex hulls; they would count as touching.
    fn touch(&self, at: &[Vec<parry3d_f64::math::Pose>], a: usize, b: usize) -> bool {
        self.bodies[a].iter().zip(&at[a]).any(|(sa, pa)| {
            self.bodies[b].iter().zip(&at[b]).any(|(sb, pb)| {
                let (sa, sb) = (sa.shape.as_ref(), sb.shape.as_ref());
                match self.clearance > 0.0 {
                    true => distance(pa, sa, pb, sb).map_or(true, |d| d.distance < self.clearance),
                    false => intersection_test(pa, sa, pb, sb).map_or(true, |r| r.intersecting),
                }
            })
        })
    }
}
