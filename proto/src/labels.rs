//! The 38 regression targets of the paper, in a fixed order with stable names.
//!
//! Order follows the paper's result tables: friction per joint (Coulomb then viscous), then mass and centre of mass
//! of links 2-6, then the inertia of link 1 (Izz only: link 1 spins about its own vertical axis, so the other
//! moments never enter the dynamics) and Ixx, Iyy, Izz of links 2-6.
//!
//! Joints are numbered 0-5 from the base (J0..J5, as in the paper); link k (1-6) is the child of joint k-1. "COM" is
//! the coordinate of the link's centre of mass along the link frame's z axis, which is the direction along which
//! the generated links extend. Inertia moments are about the centre of mass, in the link frame's axes.

/// What physical quantity a label is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LabelKind {
    /// Joint Coulomb friction torque magnitude `mu_c` [N m].
    Coulomb,
    /// Joint viscous friction coefficient `mu_v` [N m s / rad].
    Viscous,
    /// Link mass [kg].
    Mass,
    /// Link centre of mass along the link frame's z axis [m].
    Com,
    /// Moment of inertia about the COM around the link frame's x axis [kg m^2].
    Ixx,
    /// Moment of inertia about the COM around the link frame's y axis [kg m^2].
    Iyy,
    /// Moment of inertia about the COM around the link frame's z axis [kg m^2].
    Izz,
}

impl LabelKind {
    /// SI unit, for printing.
    pub const fn unit(self) -> &'static str {
        match self {
            LabelKind::Coulomb => "N m",
            LabelKind::Viscous => "N m s/rad",
            LabelKind::Mass => "kg",
            LabelKind::Com => "m",
            LabelKind::Ixx | LabelKind::Iyy | LabelKind::Izz => "kg m^2",
        }
    }

    /// Whether `index` counts joints (0-based) rather than links (1-based).
    pub const fn is_joint(self) -> bool {
        matches!(self, LabelKind::Coulomb | LabelKind::Viscous)
    }
}

/// One regression target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Label {
    /// Stable name used in shards, checkpoints and reports, e.g. `viscous_j3`, `com_l6`.
    pub name: &'static str,
    pub kind: LabelKind,
    /// Joint index 0-5 for friction labels, link index 1-6 for inertial labels.
    pub index: usize,
}

impl Label {
    const fn new(name: &'static str, kind: LabelKind, index: usize) -> Self {
        Label { name, kind, index }
    }
}

/// Number of regression targets.
pub const NUM_LABELS: usize = 38;

use LabelKind::*;

/// The label layout. Never reorder: shards and checkpoints store values in this order.
pub const LABELS: [Label; NUM_LABELS] = [
    Label::new("coulomb_j0", Coulomb, 0),
    Label::new("coulomb_j1", Coulomb, 1),
    Label::new("coulomb_j2", Coulomb, 2),
    Label::new("coulomb_j3", Coulomb, 3),
    Label::new("coulomb_j4", Coulomb, 4),
    Label::new("coulomb_j5", Coulomb, 5),
    Label::new("viscous_j0", Viscous, 0),
    Label::new("viscous_j1", Viscous, 1),
    Label::new("viscous_j2", Viscous, 2),
    Label::new("viscous_j3", Viscous, 3),
    Label::new("viscous_j4", Viscous, 4),
    Label::new("viscous_j5", Viscous, 5),
    Label::new("mass_l2", Mass, 2),
    Label::new("mass_l3", Mass, 3),
    Label::new("mass_l4", Mass, 4),
    Label::new("mass_l5", Mass, 5),
    Label::new("mass_l6", Mass, 6),
    Label::new("com_l2", Com, 2),
    Label::new("com_l3", Com, 3),
    Label::new("com_l4", Com, 4),
    Label::new("com_l5", Com, 5),
    Label::new("com_l6", Com, 6),
    Label::new("izz_l1", Izz, 1),
    Label::new("ixx_l2", Ixx, 2),
    Label::new("iyy_l2", Iyy, 2),
    Label::new("izz_l2", Izz, 2),
    Label::new("ixx_l3", Ixx, 3),
    Label::new("iyy_l3", Iyy, 3),
    Label::new("izz_l3", Izz, 3),
    Label::new("ixx_l4", Ixx, 4),
    Label::new("iyy_l4", Iyy, 4),
    Label::new("izz_l4", Izz, 4),
    Label::new("ixx_l5", Ixx, 5),
    Label::new("iyy_l5", Iyy, 5),
    Label::new("izz_l5", Izz, 5),
    Label::new("ixx_l6", Ixx, 6),
    Label::new("iyy_l6", Iyy, 6),
    Label::new("izz_l6", Izz, 6),
];

/// Position of a label by name.
pub fn index_of(name: &str) -> Option<usize> {
    LABELS.iter().position(|l| l.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn names_are_unique_and_follow_kind_and_index() {
        let names: HashSet<_> = LABELS.iter().map(|l| l.name).collect();
        assert_eq!(names.len(), NUM_LABELS);
        for l in LABELS {
            let (prefix, suffix) = l.name.split_once('_').expect("name has a kind prefix");
            let expected_prefix = format!("{:?}", l.kind).to_lowercase();
            assert_eq!(prefix, expected_prefix, "{}", l.name);
            let tag = if l.kind.is_joint() { 'j' } else { 'l' };
            assert_eq!(suffix, format!("{tag}{}", l.index), "{}", l.name);
        }
    }

    #[test]
    fn layout_counts_match_the_paper() {
        let count = |k| LABELS.iter().filter(|l| l.kind == k).count();
        assert_eq!(count(Coulomb), 6);
        assert_eq!(count(Viscous), 6);
        assert_eq!(count(Mass), 5);
        assert_eq!(count(Com), 5);
        assert_eq!(count(Ixx) + count(Iyy) + count(Izz), 16);
        assert_eq!(index_of("izz_l1"), Some(22));
        assert_eq!(index_of("nope"), None);
    }
}
