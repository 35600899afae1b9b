//! A model as a person reads it: joints, links with COM and inertia, and the paper's labels (`dynforge robot
//! --inspect`).

use dynforge_proto::LABELS;

use crate::{Model, parameters};

/// Joints (type, axis, limits, friction), links (mass, COM, inertia about the COM) and, for a 6-joint arm, the 38
/// labels.
pub fn describe(model: &Model) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let prismatic = (0..model.dof()).filter(|&i| model.is_prismatic(i)).count();
    let kinds = match prismatic {
        0 => format!("{} revolute joints", model.dof()),
        p => format!("{} revolute and {p} prismatic joints", model.dof() - p),
    };
    let _ = writeln!(s, "robot '{}': {kinds}, base '{}'", model.name(), model.base());
    let _ = writeln!(
        s,
        "\njoints (prismatic: limits in m, effort in N, friction in N and N s/m):\n  {:<4} {:<20} {:<10} {:<18} {:>17} \
         {:>9} {:>8} {:>9} {:>10}",
        "#", "name", "type", "axis", "limits [rad]", "effort", "vel", "coulomb", "viscous"
    );
    for (i, j) in model.joints().iter().enumerate() {
        let axis = model.axis(i);
        let _ = writeln!(
            s,
            "  {:<4} {:<20} {:<10} [{:>4.1} {:>4.1} {:>4.1}]  [{:>7.3}, {:>7.3}] {:>9.1} {:>8.2} {:>9.4} {:>10.4}",
            i,
            j.name,
            j.kind.urdf_name(),
            axis.x,
            axis.y,
            axis.z,
            j.limits.lower,
            j.limits.upper,
            j.limits.effort,
            j.limits.velocity,
            j.friction.coulomb,
            j.friction.viscous
        );
    }
    let _ = writeln!(s, "\nlinks (COM in the link frame; inertia about the COM, link axes):");
    let _ = writeln!(
        s,
        "  {:<4} {:<20} {:>9} {:>28} {:>33} {:>33}",
        "#", "name", "mass", "com [m]", "Ixx Iyy Izz [kg m^2]", "Ixy Ixz Iyz"
    );
    for i in 0..model.dof() {
        let inertia = model.inertia(i);
        let (c, ic) = (inertia.com(), inertia.i_com());
        let _ = writeln!(
            s,
            "  {:<4} {:<20} {:>9.4} [{:>8.4} {:>8.4} {:>8.4}] [{:>10.3e} {:>10.3e} {:>10.3e}] [{:>10.3e} {:>10.3e} {:>10.3e}]",
            i + 1,
            model.links()[i].name,
            inertia.mass,
            c.x,
            c.y,
            c.z,
            ic[(0, 0)],
            ic[(1, 1)],
            ic[(2, 2)],
            ic[(0, 1)],
            ic[(0, 2)],
            ic[(1, 2)]
        );
    }
    if let Ok(y) = parameters::labels_of(model) {
        let _ = writeln!(s, "\nlabels (the paper's 38 targets):");
        for (l, v) in LABELS.iter().zip(y) {
            let _ = writeln!(s, "  {:<12} {:>12.6} {}", l.name, v, l.kind.unit());
        }
    }
    s
}
