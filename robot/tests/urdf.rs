//! URDF reading and writing: lossless round trips and clear errors.

mod common;

use common::{joint_xml, link_xml, robot};
use dynforge_robot::model::ModelProblem;
use dynforge_robot::urdf;

#[test]
fn write_then_read_preserves_every_parameter() {
    for id in 0..200 {
        let r = robot(id);
        let text = r.urdf();
        let back = urdf::parse(&text, "roundtrip.urdf").expect("written URDF loads");
        // Model equality covers names, joint origins, axes, limits, friction, inertials, visuals and collisions.
        assert_eq!(back, r.model, "robot {id}");
        assert_eq!(urdf::to_string(&back, &r.base), text, "robot {id}: second write differs");
    }
}

#[test]
fn fixed_joints_are_welded_into_the_moving_link() {
    // The same two-link arm, once plain and once with a fixed "flange" body and a massless tool frame hanging off
    // link 2, and an extra fixed link between the world and the base: the welded link 2 must carry the flange's
    // mass, COM and inertia by the parallel-axis theorem, and joint 0 the composed base offset.
    let plain = format!(
        r#"<robot name="a"><link name="base"/>{}{}{}{}</robot>"#,
        link_xml("l1", 2.0, 0.2, [0.02, 0.02, 0.01]),
        link_xml("l2", 1.0, 0.15, [0.01, 0.01, 0.005]),
        joint_xml("j0", "base", "l1", 0.3, "0 0 1"),
        joint_xml("j1", "l1", "l2", 0.4, "0 1 0"),
    );
    let welded = format!(
        r#"<robot name="a"><link name="world"/><link name="base"/>
           <joint name="world_fix" type="fixed"><parent link="world"/><child link="base"/><origin xyz="0 0 0.1"/></joint>
           {}{}{}{}
           <link name="flange"><inertial><origin xyz="0 0 0.02"/><mass value="0.5"/>
             <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.0005"/></inertial></link>
           <joint name="flange_fix" type="fixed"><parent link="l2"/><child link="flange"/><origin xyz="0 0 0.3" rpy="0 0 0.7"/></joint>
           <link name="tool0"/>
           <joint name="tool_fix" type="fixed"><parent link="flange"/><child link="tool0"/><origin xyz="0 0 0.05"/></joint>
           </robot>"#,
        link_xml("l1", 2.0, 0.2, [0.02, 0.02, 0.01]),
        link_xml("l2", 1.0, 0.15, [0.01, 0.01, 0.005]),
        joint_xml("j0", "base", "l1", 0.2, "0 0 1"),
        joint_xml("j1", "l1", "l2", 0.4, "0 1 0"),
    );
    let a = urdf::parse(&plain, "plain.urdf").unwrap();
    let b = urdf::parse(&welded, "welded.urdf").unwrap();
    assert_eq!(b.dof(), 2);
    assert_eq!(b.base(), "world");
    // Base offsets compose: 0.1 (world->base) + 0.2 = 0.3.
    assert!((b.placement(0).trans.z - 0.3).abs() < 1e-15);
    let (ia, ib) = (a.inertia(1), b.inertia(1));
    assert!((ib.mass - 1.5).abs() < 1e-15);
    // COM of the combination: (1.0 * 0.15 + 0.5 * (0.3 + 0.02)) / 1.5.
    assert!((ib.com().z - (0.15 + 0.5 * 0.32) / 1.5).abs() < 1e-15);
    // The flange's inertia is symmetric about z, so its 0.7 rad yaw leaves it unchanged; parallel axis along z.
    let c = (0.15 + 0.5 * 0.32) / 1.5;
    let ixx = 0.01 + 1.0 * (0.15 - c) * (0.15 - c) + 0.001 + 0.5 * (0.32 - c) * (0.32 - c);
    let ic = ib.i_com();
    assert!((ic[(0, 0)] - ixx).abs() < 1e-15 && (ic[(1, 1)] - ixx).abs() < 1e-15, "{ic}");
    assert!((ic[(2, 2)] - 0.0055).abs() < 1e-15 && ic[(0, 1)].abs() < 1e-15, "{ic}");
    assert_eq!(ia.mass, 1.0);
}

fn problem(xml: &str) -> (String, ModelProblem) {
    let e = urdf::parse(xml, "bad.urdf").expect_err("must be rejected");
    assert_eq!(e.source_name, "bad.urdf");
    (e.to_string(), e.problem)
}

#[test]
fn malformed_urdfs_are_rejected_naming_file_and_element() {
    let l1 = link_xml("l1", 1.0, 0.1, [0.01, 0.01, 0.01]);
    let l2 = link_xml("l2", 1.0, 0.1, [0.01, 0.01, 0.01]);
    let j0 = joint_xml("j0", "base", "l1", 0.1, "0 0 1");

    let (msg, p) = problem("<robot name='x'><link name='base'/><link");
    assert!(matches!(p, ModelProblem::Parse(_)) && msg.starts_with("bad.urdf: cannot parse URDF"), "{msg}");

    let xml = format!("<robot name='x'><link name='base'/><link name='l1'/>{j0}</robot>");
    let (msg, p) = problem(&xml);
    assert_eq!(p, ModelProblem::MissingInertia { link: "l1".into() }, "{msg}");
    assert!(msg.contains("bad.urdf") && msg.contains("'l1'"));

    let xml = format!(
        "<robot name='x'><link name='base'/>{l1}<joint name='plane' type='planar'><parent link='base'/><child link='l1'/>
         <limit lower='0' upper='1' effort='1' velocity='1'/></joint></robot>"
    );
    assert_eq!(problem(&xml).1, ModelProblem::UnsupportedJoint { joint: "plane".into(), kind: "planar".into() });
    // A prismatic joint moves (and needs a range as a revolute one does).
    let slide = xml.replace("planar", "prismatic");
    assert!(urdf::parse(&slide, "ok.urdf").unwrap().is_prismatic(0));
    let (_, p) = problem(&slide.replace("upper='1'", "upper='0'"));
    assert!(matches!(p, ModelProblem::InvalidJoint { ref joint, .. } if joint == "plane"), "{p:?}");

    let xml = format!(
        "<robot name='x'><link name='base'/>{l1}<joint name='free' type='floating'><parent link='base'/><child link='l1'/></joint></robot>"
    );
    assert_eq!(problem(&xml).1, ModelProblem::UnsupportedJoint { joint: "free".into(), kind: "floating".into() });

    let xml = format!(
        "<robot name='x'><link name='base'/>{l1}{l2}{j0}{}</robot>",
        joint_xml("j1", "base", "l2", 0.1, "0 1 0")
    );
    let (msg, p) = problem(&xml);
    assert!(matches!(p, ModelProblem::Branching { ref link, .. } if link == "base"), "{msg}");
    assert!(msg.contains("'j0'") && msg.contains("'j1'"), "{msg}");

    let xml =
        format!("<robot name='x'><link name='base'/>{l1}{}</robot>", joint_xml("j0", "base", "ghost", 0.1, "0 0 1"));
    assert_eq!(problem(&xml).1, ModelProblem::UnknownLink { joint: "j0".into(), link: "ghost".into() });

    let bad_inertia = link_xml("l1", 1.0, 0.1, [0.01, 0.01, 0.05]);
    let (msg, p) = problem(&format!("<robot name='x'><link name='base'/>{bad_inertia}{j0}</robot>"));
    assert!(
        matches!(p, ModelProblem::InvalidInertia { ref link, .. } if link == "l1") && msg.contains("triangle"),
        "{msg}"
    );

    let no_range = j0.replace("lower=\"-3\" upper=\"3\"", "lower=\"1\" upper=\"1\"");
    let (msg, p) = problem(&format!("<robot name='x'><link name='base'/>{l1}{no_range}</robot>"));
    assert!(matches!(p, ModelProblem::InvalidJoint { ref joint, .. } if joint == "j0"), "{msg}");

    assert_eq!(problem("<robot name='x'><link name='base'/></robot>").1, ModelProblem::NoMovingJoint);

    // An infinite effort or velocity limit is no joint's: refused, naming the joint.
    for (from, to) in [("effort=\"100\"", "effort=\"inf\""), ("velocity=\"5\"", "velocity=\"inf\"")] {
        let unbounded = j0.replace(from, to);
        assert_ne!(unbounded, j0);
        let (msg, p) = problem(&format!("<robot name='x'><link name='base'/>{l1}{unbounded}</robot>"));
        assert!(matches!(p, ModelProblem::InvalidJoint { ref joint, .. } if joint == "j0") && msg.contains("finite"));
    }
    // So is a placeholder for none: 1e308 as an effort, a speed or a range.
    let placeholders = [
        ("effort=\"100\"", "effort=\"1e308\"", "real limits"),
        ("velocity=\"5\"", "velocity=\"1e308\"", "real limits"),
        ("lower=\"-3\" upper=\"3\"", "lower=\"-1e308\" upper=\"1e308\"", "no joint's range"),
    ];
    for (from, to, why) in placeholders {
        let placeholder = j0.replace(from, to);
        assert_ne!(placeholder, j0);
        let (msg, p) = problem(&format!("<robot name='x'><link name='base'/>{l1}{placeholder}</robot>"));
        assert!(
            matches!(p, ModelProblem::InvalidJoint { ref joint, .. } if joint == "j0") && msg.contains(why),
            "{msg}"
        );
    }

    // A number that is not one names its element and line (the XML reader's error names neither).
    let (msg, _) = problem(&format!(
        "<robot name='x'>\n<link name='base'/>\n{}{j0}</robot>",
        l1.replacen("value=\"1\"", "value=\"abc\"", 1)
    ));
    assert!(msg.contains("line 3: <mass value=\"abc\">: 'abc' is not a number"), "{msg}");

    // Two joints of one name (the second a fixed tool joint, so the chain itself is valid).
    let (msg, p) = problem(&format!(
        "<robot name='x'><link name='base'/>{l1}<link name='tool'/>{j0}<joint name='j0' type='fixed'><parent link='l1'/><child link='tool'/></joint></robot>"
    ));
    assert_eq!(p, ModelProblem::Duplicate { kind: "joint", name: "j0".into() }, "{msg}");
    // Nesting deep enough to overflow the XML reader's stack (it aborts the process) is an error; a normal file's
    // tags in comments and attribute values do not count.
    let deep = format!("<robot name='x'>{}{}</robot>", "<a>".repeat(20_000), "</a>".repeat(20_000));
    assert_eq!(problem(&deep).1, ModelProblem::TooDeep(256));
    let shallow = format!(
        "<robot name='x'><!-- <a><a><a> -->{}{}<link name='base'/>{l1}{j0}</robot>",
        "<gazebo reference='x'><a b='c>d'>".repeat(100),
        "</a></gazebo>".repeat(100)
    );
    assert!(urdf::parse(&shallow, "ok.urdf").is_ok(), "{:?}", urdf::parse(&shallow, "ok.urdf").err());
    let e = urdf::load("/nonexistent/robot.urdf").unwrap_err();
    assert!(e.to_string().starts_with("/nonexistent/robot.urdf: "), "{e}");
}

#[test]
fn parameter_vector_round_trips_through_the_model() {
    use dynforge_robot::parameters::{dynamic_parameters, with_dynamic_parameters};
    let model = robot(8).model;
    let pi = dynamic_parameters(&model);
    let back = with_dynamic_parameters(&model, &pi).unwrap();
    let pi2 = dynamic_parameters(&back);
    let worst = pi.iter().zip(&pi2).map(|(a, b)| (a - b).abs() / a.abs().max(1e-3)).fold(0.0, f64::max);
    assert!(worst < 1e-12, "relative change {worst}");
    // A non-physical estimate (negative mass of link 3) and a vector of the wrong size are errors, not panics.
    let mut bad = pi.clone();
    bad[20] = -1.0;
    assert!(matches!(with_dynamic_parameters(&model, &bad).unwrap_err().problem, ModelProblem::InvalidInertia { .. }));
    assert!(with_dynamic_parameters(&model, &pi[1..]).is_err());
}
