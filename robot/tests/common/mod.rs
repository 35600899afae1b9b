//! Helpers shared by the robot crate's integration tests.
#![allow(dead_code)]

use dynforge_robot::generator::{GeneratedRobot, generate};

use dynforge_proto::generator::GeneratorConfig;
use dynforge_robot::rng::Rng;
use dynforge_robot::{Model, urdf};

pub fn robot(id: u64) -> GeneratedRobot {
    generate(&GeneratorConfig::default(), 42, id).expect("default config generates valid robots")
}

/// A random state inside the joint limits, with speeds and accelerations of a few rad/s (rad/s^2).
pub fn random_state(model: &Model, rng: &mut Rng) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let q = model
        .joints()
        .iter()
        .map(|j| {
            let (lo, hi) = (j.limits.lower.max(-3.0), j.limits.upper.min(3.0));
            rng.uniform(lo, hi)
        })
        .collect();
    let qd = (0..model.dof()).map(|_| rng.uniform(-2.0, 2.0)).collect();
    let qdd = (0..model.dof()).map(|_| rng.uniform(-5.0, 5.0)).collect();
    (q, qd, qdd)
}

/// Link XML for a body whose COM sits at `com_z` on the link's z axis, with a diagonal inertia about the COM.
pub fn link_xml(name: &str, mass: f64, com_z: f64, i: [f64; 3]) -> String {
    format!(
        r#"<link name="{name}"><inertial><origin xyz="0 0 {com_z}"/><mass value="{mass}"/>
           <inertia ixx="{}" ixy="0" ixz="0" iyy="{}" iyz="0" izz="{}"/></inertial></link>"#,
        i[0], i[1], i[2]
    )
}

pub fn joint_xml(name: &str, parent: &str, child: &str, z: f64, axis: &str) -> String {
    format!(
        r#"<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>
           <origin xyz="0 0 {z}"/><axis xyz="{axis}"/><limit lower="-3" upper="3" effort="100" velocity="5"/></joint>"#
    )
}

pub fn parse(xml_body: &str) -> Model {
    urdf::parse(&format!(r#"<robot name="t"><link name="base"/>{xml_body}</robot>"#), "test.urdf")
        .expect("test URDF is valid")
}
