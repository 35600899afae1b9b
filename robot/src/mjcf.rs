//! A chain as a MuJoCo model (MJCF): one body per moving link, nested as the chain is, each with its joint, its
//! inertial (about its centre of mass, in the link's axes) and its friction; and what a URDF cannot state but MuJoCo can, each joint's rotor inertia reflected
//! through its gearbox (`armature`). Most sim-to-real work happens in MuJoCo, so a calibrated arm is written there
//! as well as to its URDF.
//!
//! Dynamics only: no geometry (a link's meshes live beside its URDF, which keeps them). Coulomb friction is MuJoCo's
//! `frictionloss`, a soft constraint by default (MuJoCo's `dof_solref`/`dof_solimp` make it hard); viscous friction
//! its `damping`. Every joint gets a motor of unit gear limited to its effort limit.

use std::fmt::Write;

use nalgebra::{Matrix3, UnitQuaternion};

use crate::model::{JointKind, Model, Pose};

/// Values MuJoCo keeps for the user (`<custom><numeric>`, read as `model.numeric(name)`): e.g. a constant torque
/// offset per joint, which a MuJoCo joint cannot hold.
pub type Numeric = (String, Vec<f64>);

/// The MJCF text of `model` with each joint's `armature` (reflected rotor inertia [kg m^2; prismatic: kg]) and the
/// user's `numeric` values.
pub fn to_mjcf(model: &Model, armature: &[f64], numeric: &[Numeric]) -> String {
    let mut s = String::new();
    let g = model.gravity();
    let _ = writeln!(s, "<mujoco model=\"{}\">", escape(model.name()));
    let _ = writeln!(s, "  <compiler angle=\"radian\" balanceinertia=\"false\" autolimits=\"true\"/>");
    let _ = writeln!(s, "  <option gravity=\"{} {} {}\"/>", g.x, g.y, g.z);
    if !numeric.is_empty() {
        let _ = writeln!(s, "  <custom>");
        for (name, data) in numeric {
            let data: Vec<String> = data.iter().map(|v| format!("{v:?}")).collect();
            let _ = writeln!(s, "    <numeric name=\"{}\" data=\"{}\"/>", escape(name), data.join(" "));
        }
        let _ = writeln!(s, "  </custom>");
    }
    let _ = writeln!(s, "  <worldbody>");
    let n = model.dof();
    for (j, (joint, link)) in model.joints().iter().zip(model.links()).enumerate() {
        let pad = "  ".repeat(j + 2);
        let _ = writeln!(s, "{pad}<body name=\"{}\" {}>", escape(&link.name), placement(&joint.origin));
        let kind = match joint.kind {
            JointKind::Prismatic => "slide",
            JointKind::Revolute | JointKind::Continuous => "hinge",
        };
        let range = match joint.kind {
            JointKind::Continuous => String::new(),
            _ => format!(" range=\"{:?} {:?}\"", joint.limits.lower, joint.limits.upper),
        };
        let [x, y, z] = joint.axis;
        let _ = writeln!(
            s,
            "{pad}  <joint name=\"{}\" type=\"{kind}\" axis=\"{x:?} {y:?} {z:?}\"{range} armature=\"{:?}\" \
             damping=\"{:?}\" frictionloss=\"{:?}\"/>",
            escape(&joint.name),
            armature.get(j).copied().unwrap_or(0.0),
            joint.friction.viscous,
            joint.friction.coulomb
        );
        // MuJoCo takes a full inertia tensor in the body's axes only (no frame of its own): the URDF's COM frame's
        // tensor turned into the link's.
        let i = &link.inertial;
        let [ixx, ixy, ixz, iyy, iyz, izz] = i.inertia;
        let r = crate::spatial::rpy_rotation(i.origin.rpy);
        let m = r * Matrix3::new(ixx, ixy, ixz, ixy, iyy, iyz, ixz, iyz, izz) * r.transpose();
        let [x, y, z] = i.origin.xyz;
        let _ = writeln!(
            s,
            "{pad}  <inertial pos=\"{x:?} {y:?} {z:?}\" mass=\"{:?}\" fullinertia=\"{:?} {:?} {:?} {:?} {:?} {:?}\"/>",
            i.mass,
            m[(0, 0)],
            m[(1, 1)],
            m[(2, 2)],
            m[(0, 1)],
            m[(0, 2)],
            m[(1, 2)]
        );
    }
    for j in (0..n).rev() {
        let _ = writeln!(s, "{}</body>", "  ".repeat(j + 2));
    }
    let _ = writeln!(s, "  </worldbody>\n  <actuator>");
    for joint in model.joints() {
        let effort = joint.limits.effort;
        let limit = match effort.is_finite() {
            true => format!(" ctrlrange=\"{:?} {effort:?}\"", -effort),
            false => String::new(),
        };
        let name = escape(&joint.name);
        let _ = writeln!(s, "    <motor name=\"{name}\" joint=\"{name}\"{limit}/>");
    }
    let _ = writeln!(s, "  </actuator>\n</mujoco>");
    s
}

/// `pos` and `quat` (MuJoCo's order: w x y z) of a URDF pose.
fn placement(p: &Pose) -> String {
    let q = UnitQuaternion::from_euler_angles(p.rpy[0], p.rpy[1], p.rpy[2]);
    let [x, y, z] = p.xyz;
    format!("pos=\"{x:?} {y:?} {z:?}\" quat=\"{:?} {:?} {:?} {:?}\"", q.w, q.i, q.j, q.k)
}

/// `text` as an XML attribute value.
fn escape(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A two-link arm, one revolute joint with a COM frame turned, one continuous; the text names both joints with
    /// their axes, ranges (none for the continuous one), armature and friction, nests the second body in the first,
    /// and escapes what XML cannot hold.
    #[test]
    fn bodies_nest_and_carry_their_joint_inertial_and_drive() {
        let text = r#"<robot name="a&amp;b"><link name="base"/>
            <link name="l1"><inertial><origin xyz="0.1 0 0" rpy="0 0 1.5707963267948966"/><mass value="2"/>
              <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.03"/></inertial></link>
            <link name="l2"><inertial><mass value="1"/>
              <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
            <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
              <limit lower="-2" upper="2" effort="50" velocity="3"/><dynamics damping="0.5" friction="1.5"/></joint>
            <joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.3"/>
              <axis xyz="0 1 0"/><limit effort="10" velocity="3"/></joint></robot>"#;
        let model = crate::urdf::parse(text, "two.urdf").expect("a valid URDF");
        let mjcf = to_mjcf(&model, &[0.25, 0.125], &[("offset".into(), vec![1.0, -2.0])]);
        assert!(mjcf.starts_with("<mujoco model=\"a&amp;b\">"), "{mjcf}");
        assert!(mjcf.contains(
            "<joint name=\"j1\" type=\"hinge\" axis=\"0.0 0.0 1.0\" range=\"-2.0 2.0\" armature=\"0.25\" \
             damping=\"0.5\" frictionloss=\"1.5\"/>"
        ));
        assert!(mjcf.contains("<joint name=\"j2\" type=\"hinge\" axis=\"0.0 1.0 0.0\" armature=\"0.125\""));
        assert!(mjcf.contains("<numeric name=\"offset\" data=\"1.0 -2.0\"/>"));
        assert!(mjcf.contains("<motor name=\"j1\" joint=\"j1\" ctrlrange=\"-50.0 50.0\"/>"));
        // Body l2 opens after l1 and closes before it.
        let (open1, open2) = (mjcf.find("<body name=\"l1\"").unwrap(), mjcf.find("<body name=\"l2\"").unwrap());
        assert!(open1 < open2 && mjcf.matches("</body>").count() == 2);
        assert!(mjcf.contains("pos=\"0.0 0.0 0.3\" quat=\"1.0 0.0 0.0 0.0\""));
        // The COM frame's yaw of pi/2 turns its ixx into the link's iyy and back; izz stays.
        let start = mjcf.find("<inertial pos=\"0.1 0.0 0.0\" mass=\"2.0\" fullinertia=\"").expect("l1's inertial");
        let values: Vec<f64> =
            mjcf[start..].split('"').nth(5).unwrap().split(' ').map(|v| v.parse().unwrap()).collect();
        for (got, want) in values.iter().zip([0.02, 0.01, 0.03, 0.0, 0.0, 0.0]) {
            assert!((got - want).abs() < 1e-15, "{values:?}");
        }
    }
}
