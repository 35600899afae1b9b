//! Kinematic enrichment: the paper's Jacobian features. For every link, the geometric Jacobian (linear and angular
//! velocity per unit joint speed, base axes) of the link's tip, the origin of the next joint, evaluated at each
//! sample's configuration. The last link has no next joint: its frame origin is used. Only kinematics enter (tips
//! are joint origins, never the centres of mass the model must estimate), so no label leaks into the inputs.
//!
//! Pruning is decided from the kinematics, not by hand-picked indices: an entry that takes the same value over a
//! deterministic sweep of configurations across the joint ranges (a link tip on its own joint's axis, a base axis
//! that never turns) carries no information and is dropped.

use dynforge_robot::rng::Rng;
use dynforge_robot::{Data, Model, forward_kinematics, point_jacobian};
use nalgebra::Vector3;

/// Rows of a point Jacobian: linear then angular velocity, base axes.
const ROWS: [&str; 6] = ["vx", "vy", "vz", "wx", "wy", "wz"];
/// Configurations of the pruning sweep.
const SWEEP: usize = 256;

/// One kept Jacobian entry.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    /// Link index (0-based: link 1 of the paper is 0).
    pub link: usize,
    pub row: usize,
    pub joint: usize,
    /// Stable name, e.g. `J_l2_vz_q1` (paper numbering: links from 1, joints from 0).
    pub name: String,
}

/// The Jacobian features of a model: which entries, and how to evaluate them.
#[derive(Debug, Clone)]
pub struct JacobianFeatures {
    tips: Vec<Vector3<f64>>,
    pub entries: Vec<Entry>,
}

impl JacobianFeatures {
    /// Selects the informative entries for `model`.
    pub fn new(model: &Model) -> Self {
        let n = model.dof();
        let tips: Vec<Vector3<f64>> =
            (0..n).map(|k| if k + 1 < n { model.placement(k + 1).trans } else { Vector3::zeros() }).collect();
        let mut all = JacobianFeatures { tips, entries: Vec::new() };
        for link in 0..n {
            for (row, label) in ROWS.iter().enumerate() {
                for joint in 0..=link {
                    all.entries.push(Entry { link, row, joint, name: format!("J_l{}_{label}_q{joint}", link + 1) });
                }
            }
        }
        let mut data = Data::new(model);
        let mut rng = Rng::stream(0x4a41_434f, &[]);
        let mut lo = vec![f64::INFINITY; all.entries.len()];
        let mut hi = vec![f64::NEG_INFINITY; all.entries.len()];
        let mut values = Vec::new();
        for _ in 0..SWEEP {
            let q: Vec<f64> = model
                .joints()
                .iter()
                .map(|j| {
                    rng.uniform(j.limits.lower.max(-std::f64::consts::PI), j.limits.upper.min(std::f64::consts::PI))
                })
                .collect();
            all.evaluate(model, &mut data, &q, &mut values);
            for (i, v) in values.iter().enumerate() {
                lo[i] = lo[i].min(*v);
                hi[i] = hi[i].max(*v);
            }
        }
        // Constant to rounding (1e-9 of the arm's metre scale) over the sweep: no information.
        let keep: Vec<bool> = lo.iter().zip(&hi).map(|(l, h)| h - l > 1e-9).collect();
        let mut k = keep.iter();
        all.entries.retain(|_| *k.next().expect("one flag per entry"));
        all
    }

    /// Number of features.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// The columns of a window's time step for `model`, one line per kind: q, qd, tau of each joint, then these
    /// features.
    pub fn describe(&self, model: &Model) -> String {
        let joints: Vec<&str> = model.joints().iter().map(|j| j.name.as_str()).collect();
        let mut out = format!(
            "features per time step: {} = q, qd, tau of {} joints + {} Jacobian entries\n",
            3 * joints.len() + self.len(),
            joints.len(),
            self.len()
        );
        for kind in ["q", "qd", "tau"] {
            out.push_str(&format!("  {kind}: {}\n", joints.join(" ")));
        }
        let names: Vec<&str> = self.entries.iter().map(|e| e.name.as_str()).collect();
        out.push_str(&format!("  jacobian: {}\n", names.join(" ")));
        out
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The features at configuration `q`, into `out` (cleared first).
    pub fn evaluate(&self, model: &Model, data: &mut Data, q: &[f64], out: &mut Vec<f64>) {
        out.clear();
        forward_kinematics(model, data, q);
        let mut current = usize::MAX;
        for e in &self.entries {
            if e.link != current {
                point_jacobian(model, data, e.link, &self.tips[e.link]);
                current = e.link;
            }
            out.push(data.jacobian[(e.row, e.joint)]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynforge_proto::generator::GeneratorConfig;
    use dynforge_robot::generator::generate;

    #[test]
    fn features_are_the_robot_crates_jacobian_entries_at_the_link_tips() {
        let model = generate(&GeneratorConfig::default(), 2, 5).unwrap().model;
        let f = JacobianFeatures::new(&model);
        let mut data = Data::new(&model);
        let mut values = Vec::new();
        let q = [0.4, -0.7, 1.2, 0.3, -0.5, 0.9];
        f.evaluate(&model, &mut data, &q, &mut values);
        assert_eq!(values.len(), f.len());
        for (e, v) in f.entries.iter().zip(&values) {
            forward_kinematics(&model, &mut data, &q);
            let tip = if e.link + 1 < 6 { model.placement(e.link + 1).trans } else { Vector3::zeros() };
            point_jacobian(&model, &mut data, e.link, &tip);
            assert_eq!(*v, data.jacobian[(e.row, e.joint)], "{}", e.name);
        }
    }

    #[test]
    fn pruning_follows_from_the_kinematics() {
        let model = generate(&GeneratorConfig::default(), 2, 5).unwrap().model;
        let f = JacobianFeatures::new(&model);
        let names: Vec<&str> = f.entries.iter().map(|e| e.name.as_str()).collect();
        // Link 1's tip (the shoulder joint) sits on joint 0's axis: it never moves, so no linear entry survives.
        assert!(!names.iter().any(|n| n.starts_with("J_l1_v")), "{names:?}");
        // Joint 0 turns about the fixed base z axis: its angular column is the constant (0, 0, 1) for every link.
        assert!(!names.iter().any(|n| n.starts_with('J') && n.contains("_w") && n.ends_with("_q0")), "{names:?}");
        // Turning about the vertical base axis never moves a point vertically, and joints 1-3 turn about
        // horizontal axes: those entries are identically zero.
        assert!(
            !names.iter().any(|n| n.contains("_vz_q0") || n.ends_with("_wz_q1") || n.ends_with("_wz_q3")),
            "{names:?}"
        );
        // Joint 1's axis turns with joint 0, and the wrist moves with everything before it: those stay.
        assert!(names.contains(&"J_l2_wx_q1") && names.contains(&"J_l6_vx_q0") && names.contains(&"J_l6_wz_q5"));
        // No entry for a joint after the link (always zero) is even considered.
        assert!(f.entries.iter().all(|e| e.joint <= e.link));
        // The selection is deterministic and the same for every robot of the distribution (same kinematics).
        let other = generate(&GeneratorConfig::default(), 9, 77).unwrap().model;
        assert_eq!(JacobianFeatures::new(&other).entries, f.entries);
    }
}
