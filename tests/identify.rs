//! End to end: `dynforge identify` calibrates a wrong URDF of the right arm to simulated logs of another robot.

mod common;

use common::dynforge;
use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::{LABELS, LabelKind};
use dynforge_robot::generator::generate;
use dynforge_robot::parameters::labels_of;

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn identify_calibrates_a_wrong_urdf_to_the_logs_of_the_robot() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let mut logs = Vec::new();
    for t in ["0", "1"] {
        let o = dynforge(&["simulate", "--seed", "3", "--robot", "1", "--trajectory", t, "--out", d]);
        assert!(o.status.success(), "{}", stderr(&o));
        logs.push(dir.path().join(format!("r000001-t0{t}-native.mcap")));
    }
    // Another robot of the same family: same kinematics and joint names, other masses, inertias and friction.
    let wrong = dir.path().join("wrong.urdf");
    assert!(dynforge(&["robot", "--seed", "3", "--id", "2", "--out", wrong.to_str().unwrap()]).status.success());
    // As a user's file: with elements the calibration must leave as they are.
    let extras = "  <ros2_control name=\"arm\" type=\"system\">\n    <joint name=\"joint_0\"><state_interface \
                  name=\"position\"/></joint>\n  </ros2_control>\n  <gazebo reference=\"link_1\"><material>Gazebo/Grey\
                  </material></gazebo>\n</robot>";
    let user = std::fs::read_to_string(&wrong).unwrap().replace("</robot>", extras);
    std::fs::write(&wrong, &user).unwrap();
    let out = dir.path().join("calibrated.urdf");
    let mut args = vec!["identify", "--urdf", wrong.to_str().unwrap(), "--out", out.to_str().unwrap(), "--json"];
    args.extend(logs.iter().map(|p| p.to_str().unwrap()));
    let o = dynforge(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let (after, before) = (v["nrmse_calibrated"].as_f64().unwrap(), v["nrmse_urdf"].as_f64().unwrap());
    // The calibrated robot predicts the logs' torques to the pairing's error of the simulation (~1e-5 of the torque
    // spread); the wrong URDF is off by tens of percent.
    assert!(after < 1e-3 && after < before / 10.0, "{after} {before}");
    let rank = v["rank"].as_u64().unwrap();
    assert!(rank > 12 && rank < 72, "{rank}");
    // Friction has regressor columns of its own: the calibrated coefficients are the simulated robot's, not the
    // URDF's (off by 4-280 %). Coulomb's column, sign(qd), is excited by every move: within 1 % (0.2 % measured).
    // Viscous competes with the inertial terms in slow moves, and its precision follows how fast its joint moves:
    // within 10 % (0.0-2 % measured, 6 % on joint 3, from two 7 s logs).
    let truth = labels_of(&generate(&GeneratorConfig::default(), 3, 1).unwrap().model).unwrap();
    let calibrated = labels_of(&dynforge_robot::urdf::load(&out).unwrap()).unwrap();
    let written = std::fs::read_to_string(&out).unwrap();
    assert!(written.ends_with(&format!("{extras}\n")) || written.ends_with(extras), "the user's elements were lost");
    assert_eq!(written.lines().count(), user.lines().count(), "only <inertial> and <dynamics> contents change");
    for (k, l) in LABELS.iter().enumerate() {
        let bound = match l.kind {
            LabelKind::Coulomb => 0.01,
            LabelKind::Viscous => 0.1,
            _ => continue,
        };
        let which = if l.kind == LabelKind::Coulomb { "coulomb" } else { "viscous" };
        let urdf = v["joints"][l.index][which]["urdf"].as_f64().unwrap();
        assert!(
            (calibrated[k] - truth[k]).abs() < bound * truth[k],
            "{}: calibrated {} truth {} urdf {urdf}",
            l.name,
            calibrated[k],
            truth[k]
        );
    }

    // Bad inputs are refused with the reason, and write nothing.
    let none = dir.path().join("none.urdf");
    let log = logs[0].to_str().unwrap();
    let o = dynforge(&["identify", log, "--spread", "0", "--out", none.to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("--spread"), "{}", stderr(&o));
    let o = dynforge(&["identify", dir.path().join("missing.mcap").to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("missing.mcap"), "{}", stderr(&o));
    let renamed = dir.path().join("renamed.urdf");
    std::fs::write(&renamed, std::fs::read_to_string(&wrong).unwrap().replace("\"joint_1\"", "\"shoulder\"")).unwrap();
    let o = dynforge(&["identify", log, "--urdf", renamed.to_str().unwrap(), "--out", none.to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains(log), "{}", stderr(&o));
    // Logs of two robots, each with its own /robot_description: refused, naming the odd one.
    let o = dynforge(&["simulate", "--seed", "3", "--robot", "2", "--trajectory", "0", "--out", d]);
    assert!(o.status.success(), "{}", stderr(&o));
    let other = dir.path().join("r000002-t00-native.mcap");
    let o = dynforge(&["identify", log, other.to_str().unwrap(), "--out", none.to_str().unwrap()]);
    let said = stderr(&o);
    assert!(!o.status.success() && said.contains("r000002-t00-native.mcap: a log of another robot"), "{said}");
    assert!(!none.exists());
}
