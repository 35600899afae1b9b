//! `urdf::patch`: new parameters written into a user's own URDF, everything else kept.

mod common;

use common::robot;
use dynforge_proto::NUM_LABELS;
use dynforge_robot::model::Model;
use dynforge_robot::parameters::{dynamic_parameters, labels_of, model_with_labels};
use dynforge_robot::urdf;

/// A generated robot's URDF as a user's file looks: a material, comments, a joint without `<dynamics>`, a tool
/// welded to the last link through a massless flange frame, `<ros2_control>` (whose `<joint>` elements are not the
/// robot's joints) and `<gazebo>`.
fn user_document() -> String {
    let plain = robot(3).urdf();
    let dynamics_j2 = {
        let at = plain.find("<joint name=\"joint_2\"").unwrap();
        let start = at + plain[at..].find("<dynamics").unwrap();
        let end = start + plain[start..].find("/>").unwrap() + 2;
        (start, end)
    };
    let mut doc = format!("{}{}", &plain[..dynamics_j2.0], &plain[dynamics_j2.1..]);
    doc = doc.replacen(
        "<link name=\"base_link\">",
        "<material name=\"grey\">\n    <color rgba=\"0.5 0.5 0.5 1\"/>\n  </material>\n  <!-- the arm -->\n  \
         <link name=\"base_link\">",
        1,
    );
    let extras = r#"  <joint name="flange_joint" type="fixed">
    <parent link="link_6"/>
    <child link="flange"/>
    <origin xyz="0 0 0.05" rpy="0 0 0"/>
  </joint>
  <link name="flange"/>
  <joint name="tool_joint" type="fixed">
    <parent link="flange"/>
    <child link="tool0"/>
    <origin xyz="0 0.01 0.02" rpy="0 0 1.5707963267948966"/>
  </joint>
  <link name="tool0">
    <inertial>
      <origin xyz="0.01 0 0.03" rpy="0 0 0"/>
      <mass value="0.3"/>
      <inertia ixx="0.0004" ixy="0" ixz="0" iyy="0.0005" iyz="0" izz="0.0002"/>
    </inertial>
    <visual>
      <geometry><box size="0.05 0.05 0.06"/></geometry>
      <material name="grey"/>
    </visual>
  </link>
  <ros2_control name="arm" type="system">
    <hardware><plugin>mock_components/GenericSystem</plugin></hardware>
    <joint name="joint_0">
      <command_interface name="position"/>
      <state_interface name="position"/>
    </joint>
  </ros2_control>
  <gazebo>
    <plugin filename="libgz_ros2_control-system.so" name="gz_ros2_control::GazeboSimROS2ControlPlugin"/>
  </gazebo>
</robot>"#;
    doc.replacen("</robot>", extras, 1)
}

/// The document without its `<inertial>` and `<dynamics>` elements and blank lines: what a patch must keep.
fn kept(doc: &str) -> String {
    let mut s = doc.to_string();
    while let Some(a) = s.find("<inertial>") {
        let b = a + s[a..].find("</inertial>").unwrap() + "</inertial>".len();
        s.replace_range(a..b, "");
    }
    while let Some(a) = s.find("<dynamics") {
        let b = a + s[a..].find("/>").unwrap() + 2;
        s.replace_range(a..b, "");
    }
    s.lines().filter(|l| !l.trim().is_empty()).collect::<Vec<_>>().join("\n")
}

fn assert_same_parameters(a: &Model, b: &Model) {
    let (pa, pb) = (dynamic_parameters(a), dynamic_parameters(b));
    for (link, (x, y)) in pa.chunks(10).zip(pb.chunks(10)).enumerate() {
        let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (k, (u, v)) in x.iter().zip(y).enumerate() {
            // Two decimal round trips and one subtraction of the welded inertia: a few ulps of the link's largest.
            assert!((u - v).abs() <= 1e-12 * scale, "link {link} parameter {k}: {u} vs {v}");
        }
    }
    for (ja, jb) in a.joints().iter().zip(b.joints()) {
        assert_eq!(ja.friction, jb.friction, "{}", ja.name);
    }
}

fn target(doc_model: &Model, change: impl Fn(&str, f64) -> f64) -> Model {
    let y0 = labels_of(doc_model).unwrap();
    let y: [f64; NUM_LABELS] = std::array::from_fn(|k| change(dynforge_proto::LABELS[k].name, y0[k]));
    let (m, projections) = model_with_labels(doc_model, &y).unwrap();
    assert!(projections.is_empty(), "{projections:?}");
    m
}

#[test]
fn a_patch_changes_only_inertials_and_dynamics_and_loads_as_the_estimate() {
    let doc = user_document();
    let original = urdf::parse(&doc, "user.urdf").unwrap();
    let estimate = target(&original, |name, v| match &name[..4] {
        "mass" => v * 1.1,
        "coul" | "visc" => v * 1.3 + 0.01,
        _ => v * 1.05,
    });
    let (text, notes) = urdf::patch(&doc, "user.urdf", &estimate).unwrap();
    assert!(notes.is_empty(), "{notes:?}");
    assert_same_parameters(&urdf::parse(&text, "patched.urdf").unwrap(), &estimate);
    assert_eq!(kept(&text), kept(&doc), "something besides <inertial> and <dynamics> changed");
    assert_eq!(text.matches("<dynamics").count(), 6, "one per moving joint, none in <ros2_control>");
    // The tool keeps its own inertia; link 6 carries the estimate less the tool's.
    let tool = |d: &str| d[d.find("<link name=\"tool0\">").unwrap()..].split("</inertial>").next().unwrap().to_string();
    assert_eq!(tool(&text), tool(&doc));
    let lumped = urdf::parse(&doc, "x").unwrap().links()[5].inertial.mass;
    let own = |d: &str| {
        let l = &d[d.find("<link name=\"link_6\">").unwrap()..];
        let m = &l[l.find("<mass value=\"").unwrap() + 13..];
        m[..m.find('"').unwrap()].parse::<f64>().unwrap()
    };
    assert!((own(&doc) + 0.3 - lumped).abs() < 1e-12);
    assert!((own(&text) + 0.3 - estimate.links()[5].inertial.mass).abs() < 1e-12);
    // A second patch with the same values changes nothing.
    assert_eq!(urdf::patch(&text, "patched.urdf", &estimate).unwrap().0, text);
}

/// An estimate lighter than the tool welded to its link cannot be split: in a user's file the tool keeps its
/// `<inertial>` as written (the file changes only in the moving links' inertials), the link gets the nearest body, and
/// a note says how far the file's total then is from the estimate.
#[test]
fn an_estimate_lighter_than_the_welded_tool_keeps_the_tool_and_says_what_the_file_holds() {
    let doc = user_document();
    let original = urdf::parse(&doc, "user.urdf").unwrap();
    let estimate = target(&original, |name, v| if name == "mass_l6" { 0.2 } else { v });
    let (text, notes) = urdf::patch(&doc, "user.urdf", &estimate).unwrap();
    assert_eq!(notes.len(), 1, "{notes:?}");
    assert!(
        notes[0].contains("link_6") && notes[0].contains("tool0") && notes[0].contains("nearest body"),
        "{notes:?}"
    );
    assert_eq!(kept(&text), kept(&doc), "something besides <inertial> and <dynamics> changed");
    let tool = |d: &str| d[d.find("<link name=\"tool0\">").unwrap()..].split("</inertial>").next().unwrap().to_string();
    assert_eq!(tool(&text), tool(&doc), "the tool's <inertial> changed");
    let written = urdf::parse(&text, "patched.urdf").unwrap();
    let link6 = written.links()[5].inertial;
    // The link's own share is a physical body (the parse would refuse one that is not) and a light one: the nearest
    // to a remainder of -0.1 kg, not a body of the tool's size. The file's total is the tool's 0.3 kg plus it.
    let total = link6.mass;
    assert!(total > 0.3 && total < 0.3 + 0.1, "{total}");
    let said: f64 = notes[0].split("total for them is ").nth(1).unwrap().split(' ').next().unwrap().parse().unwrap();
    assert!((said - total).abs() < 1e-4, "the note says {said} kg, the file holds {total}");
    // Every other link is the estimate's.
    let (pw, pe) = (dynamic_parameters(&written), dynamic_parameters(&estimate));
    for k in 0..50 {
        assert!((pw[k] - pe[k]).abs() <= 1e-12 * pe[k].abs().max(1.0), "parameter {k}: {} vs {}", pw[k], pe[k]);
    }
    // A file that must be the model (a family's variant) takes the whole estimate on the link instead, the tool's
    // <inertial> removed so that no loader counts it twice.
    let welds = urdf::Welds::new();
    let (text, notes) = urdf::patch_welded(&doc, "user.urdf", &estimate, &welds, urdf::Unsplit::Exact).unwrap();
    assert!(notes.len() == 1 && notes[0].contains("whole estimate"), "{notes:?}");
    assert_same_parameters(&urdf::parse(&text, "patched.urdf").unwrap(), &estimate);
    let tool = &text[text.find("<link name=\"tool0\">").unwrap()..];
    assert!(!tool[..tool.find("</link>").unwrap()].contains("<inertial>"), "the tool's inertia would count twice");
}

#[test]
fn a_document_of_another_robot_is_refused() {
    let doc = user_document();
    let other = urdf::parse(&robot(3).urdf().replace("joint_5", "wrist_3"), "other").unwrap();
    let e = urdf::patch(&doc, "user.urdf", &other).unwrap_err().to_string();
    assert!(e.contains("user.urdf") && e.contains("wrist_3"), "{e}");
}

/// A `<dynamics>` with a simulator's own attributes (the Panda's description has `D`, `K`, `mu_coulomb`,
/// `mu_viscous`) keeps them, in their order and quoting; only `damping` and `friction` change, and one that lacks
/// `friction` gains it.
#[test]
fn a_joint_s_other_dynamics_attributes_are_kept() {
    let plain = robot(3).urdf();
    let at = plain.find("<joint name=\"joint_1\"").unwrap();
    let start = at + plain[at..].find("<dynamics").unwrap();
    let end = start + plain[start..].find("/>").unwrap() + 2;
    let own = "<dynamics D='1' K=\"7000\" damping=\"0.5\" mu_coulomb=\"0\"/>";
    let doc = format!("{}{own}{}", &plain[..start], &plain[end..]);
    let original = urdf::parse(&doc, "user.urdf").unwrap();
    let estimate = target(&original, |name, v| match &name[..4] {
        "coul" | "visc" => v * 1.3 + 0.01,
        _ => v,
    });
    let (text, _) = urdf::patch(&doc, "user.urdf", &estimate).unwrap();
    let f = estimate.joints()[1].friction;
    let written = format!(
        "<dynamics D='1' K=\"7000\" damping=\"{:?}\" mu_coulomb=\"0\" friction=\"{:?}\"/>",
        f.viscous, f.coulomb
    );
    assert!(text.contains(&written), "{}", &text[text.find("<joint name=\"joint_1\"").unwrap()..][..400]);
    assert_same_parameters(&urdf::parse(&text, "patched.urdf").unwrap(), &estimate);
}
