//! `dynforge identify` on real arms' logs: example-robot-data's UR5 and Panda simulated by MuJoCo (an independent
//! engine, hard Coulomb and viscous friction known), logged as drivers write them, calibrated from a "nominal" URDF
//! whose every inertial is off by 20-30 % and which states no friction.
//!
//! What the issue asks, per log kind: clean logs (either effort convention) give friction within 0.1 % and a
//! held-out torque NRMSE of at most 0.001; logs with 1 % effort noise, 2^17-count encoders and velocities from
//! encoder differences give Coulomb within 1 %, viscous within 3 %, and a held-out NRMSE (on a noise-free log of
//! another motion) of at most 1.2 times the true URDF's plus 0.001.

mod common;

use std::path::{Path, PathBuf};

use common::dynforge;
use dynforge_identify::calibrate::{Identification, Options, held_out, identify_logs};
use dynforge_identify::signals::{Conditioning, EffortConvention};
use dynforge_recording::Reading;
use dynforge_recording::log::read_log;
use dynforge_robot::drive::{Drive, identified};
use dynforge_robot::parameters::dynamic_parameters;
use dynforge_testkit::arms::{Arm, Harness, LogKind, PANDA, UR5};
use serde_json::{Value, json};

/// A log of `arm`: the harness's, its effort convention named as `identify` names it.
fn log(f: &Harness, arm: &Arm, seed: u64, seconds: f64, effort: EffortConvention, kind: LogKind, rate: f64) -> PathBuf {
    f.log(arm, seed, seconds, effort.name(), kind, rate)
}

/// Identifies `log` from `nominal`, checks friction against `arm`'s within `coulomb` / `viscous` (relative), and
/// returns the identification with its held-out torque NRMSE and the true robot's (its URDF and `drives`, per joint
/// `(name, armature, offset)`) on `held`.
fn calibrate(
    f: &Harness,
    (arm, drives): (&Arm, &[(&str, f64, f64)]),
    log: &Path,
    nominal: &Path,
    held: &Path,
    effort: Option<EffortConvention>,
    (coulomb, viscous): (f64, f64),
) -> (Identification, f64, f64) {
    let text = std::fs::read_to_string(nominal).unwrap();
    let options = Options {
        conditioning: Conditioning { effort, ..Conditioning::default() },
        reading: Reading::welding(&arm.fixed.iter().map(|s| s.to_string()).collect::<Vec<_>>()),
        ..Options::default()
    };
    let (id, _) = identify_logs(&[log.to_path_buf()], Some((&text, "nominal.urdf")), &options)
        .unwrap_or_else(|e| panic!("{}: {e}", log.display()));
    for (name, c, v) in arm.friction {
        let j = id.joints.iter().find(|j| j.name == *name).unwrap();
        let (ec, ev) = (j.coulomb.value / c - 1.0, j.viscous.value / v - 1.0);
        assert!(
            ec.abs() < coulomb && ev.abs() < viscous,
            "{}: {name}: Coulomb {ec:+.4} viscous {ev:+.4}",
            log.display()
        );
    }
    let truth = std::fs::read_to_string(&f.urdf).unwrap();
    let ne = held_out(&[held.to_path_buf()], Some((&truth, "true.urdf")), &options, &id).unwrap();
    let true_model = read_log(held, Some((&truth, "true.urdf")), &options.reading).unwrap().model;
    let true_drives: Vec<Drive> = true_model
        .joints()
        .iter()
        .map(|j| match drives.iter().find(|d| d.0 == j.name) {
            Some(&(_, armature, offset)) => Drive { armature, offset },
            None => Drive::default(),
        })
        .collect();
    let truth = identified(&dynamic_parameters(&true_model), &true_drives);
    (id.clone(), ne.mean_nrmse(&id.identified()), ne.mean_nrmse(&truth))
}

/// Both conventions, clean and noisy, on one arm.
fn arm_from_its_logs(arm: &Arm, seconds: f64) {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let f = Harness::new(py, tmp.path(), arm);
    let nominal = f.nominal(3);
    for effort in EffortConvention::ALL {
        let fit = log(&f, arm, 1, seconds, effort, LogKind::Clean, 1000.0);
        let held = log(&f, arm, 2, 20.0, effort, LogKind::Clean, 1000.0);
        let noisy = log(&f, arm, 1, seconds, effort, LogKind::Noisy, 1000.0);
        // Clean: the convention is found from the data.
        let (id, nrmse, truth) = calibrate(&f, (arm, &[]), &fit, &nominal, &held, None, (1e-3, 1e-3));
        assert_eq!(id.effort, effort, "{}", id.effort_reason);
        assert!(nrmse <= 1e-3, "{} {}: held-out NRMSE {nrmse:.2e} (true URDF {truth:.2e})", arm.name, effort.name());
        // Noisy: named (the data cannot tell the conventions apart through a 20 Hz filter and 1 % noise).
        let (_, nrmse, truth) = calibrate(&f, (arm, &[]), &noisy, &nominal, &held, Some(effort), (0.01, 0.03));
        assert!(
            nrmse <= 1.2 * truth + 1e-3,
            "{} {} noisy: held-out NRMSE {nrmse:.2e}, true URDF {truth:.2e}",
            arm.name,
            effort.name()
        );
    }
}

#[test]
fn the_ur5_is_calibrated_from_clean_and_noisy_logs_of_either_effort_convention() {
    arm_from_its_logs(&UR5, 30.0);
}

#[test]
fn the_panda_with_its_seven_joints_and_welded_fingers_is_calibrated_likewise() {
    arm_from_its_logs(&PANDA, 30.0);
}

/// An arm whose joints have rotor inertia (`drives`: MuJoCo's armature, 0.1-1 kg m^2) and a torque offset (a
/// sensor's bias, added to the logged effort), from a noisy log (1 % effort noise, 2^17-count encoders): friction and
/// held-out NRMSE as the arms without drives, every rotor inertia and offset within three of its printed standard
/// deviations of the truth (a Gaussian error's 99.7 %) and within 5 % of it; from a clean log, within 2 % and 1 %.
/// (Measured: rotor inertia within 2.0 %, offsets within 2.6 %; the UR5's shoulder-lift rotor has the same column as
/// its link's inertia about that axis, so the nominal URDF's error in that inertia is what its 2.0 % is.)
fn drives_of(arm: &Arm, drives: &[(&str, f64, f64)]) {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let f = Harness::new(py, tmp.path(), arm);
    let nominal = f.nominal(3);
    let effort = EffortConvention::Sampled;
    let fit = f.log_with_drives(arm, drives, (1, 30.0), effort.name(), LogKind::Noisy, 1000.0);
    let held = f.log_with_drives(arm, drives, (2, 20.0), effort.name(), LogKind::Clean, 1000.0);
    let (id, nrmse, truth) = calibrate(&f, (arm, drives), &fit, &nominal, &held, Some(effort), (0.01, 0.03));
    let mut errors = Vec::new();
    let mut worst: f64 = 0.0;
    for &(name, armature, offset) in drives {
        let j = id.joints.iter().find(|j| j.name == name).unwrap();
        let (ea, eo) = (j.armature.value / armature - 1.0, j.offset.value / offset - 1.0);
        let (za, zo) = (j.armature.z(armature), j.offset.z(offset));
        errors.push(format!("{name}: armature {ea:+.4} (z {za:+.2}) offset {eo:+.4} (z {zo:+.2})"));
        worst = worst.max(za.abs()).max(zo.abs());
        assert!(ea.abs() < 0.05 && eo.abs() < 0.05, "{}: {}", arm.name, errors.join(", "));
    }
    assert!(worst < 3.0, "{}: {}", arm.name, errors.join(", "));
    assert!(nrmse <= 1.2 * truth + 1e-3, "{}: held-out NRMSE {nrmse:.2e}, true robot {truth:.2e}", arm.name);
    // Without noise what is left is the model's own error: rotor inertia within 2 % and offsets within 1 % (the noisy
    // log's 2.6 % is its noise: 1 % of torques of 10-60 N m against offsets of 0.2-3 N m). Measured: rotor inertia
    // within 1.02 % (the UR5's shoulder pan, whose column a link's inertia shares), offsets within 0.02 %.
    let clean = f.log_with_drives(arm, drives, (1, 30.0), effort.name(), LogKind::Clean, 1000.0);
    let (id, _, _) = calibrate(&f, (arm, drives), &clean, &nominal, &held, Some(effort), (1e-3, 1e-3));
    for &(name, armature, offset) in drives {
        let j = id.joints.iter().find(|j| j.name == name).unwrap();
        let (ea, eo) = (j.armature.value / armature - 1.0, j.offset.value / offset - 1.0);
        assert!(ea.abs() < 0.02 && eo.abs() < 0.01, "{} clean: {name}: armature {ea:+.4} offset {eo:+.4}", arm.name);
    }
    // The command writes the same robot as a MuJoCo model: MuJoCo's inverse dynamics of it is Pinocchio's of the
    // URDF written plus the JSON's rotor inertia and viscous friction (both sum the same terms in another order:
    // rounding, ~1e-15 of the torque); its Coulomb friction and offsets are the JSON's.
    let (urdf, mjcf, json) = (f.dir.join("drives.urdf"), f.dir.join("drives.xml"), f.dir.join("drives.json"));
    let mut args: Vec<String> = ["identify", path(&fit), "--urdf", path(&nominal), "--effort", "sampled"]
        .iter()
        .map(|s| s.to_string())
        .chain(["--out", path(&urdf), "--mjcf", path(&mjcf), "--json"].iter().map(|s| s.to_string()))
        .collect();
    args.extend(arm.fixed.iter().flat_map(|j| ["--fix".to_string(), j.to_string()]));
    let run = dynforge(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    std::fs::write(&json, &run.stdout).unwrap();
    let check: Value = serde_json::from_str(&dynforge_testkit::run_python(
        &f.python,
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/reference/check_mjcf.py"),
        &[],
        &json!({"mjcf": mjcf, "urdf": urdf, "json": json, "states": 50, "seed": 1}).to_string(),
    ))
    .unwrap();
    assert!(check["relative"].as_f64().unwrap() < 1e-6, "{}: {check}", arm.name);
    assert!(check["coulomb"].as_f64().unwrap() < 1e-12 && check["offset"].as_f64().unwrap() < 1e-12, "{check}");
    // The URDF written is the nominal one but for the moving links' <inertial> and the moving joints' damping and
    // friction: the welded hand's and fingers' inertials, the Panda's own <dynamics> attributes, all kept.
    let v: Value = serde_json::from_slice(&run.stdout).unwrap();
    let names = |key: &str| -> Vec<String> {
        v[key].as_array().unwrap().iter().map(|e| e["name"].as_str().unwrap().to_string()).collect()
    };
    let (links, joints) = (names("links"), names("joints"));
    let (before, after) = (std::fs::read_to_string(&nominal).unwrap(), std::fs::read_to_string(&urdf).unwrap());
    assert_eq!(uncalibrated(&after, &links, &joints), uncalibrated(&before, &links, &joints), "{}", arm.name);
}

/// `doc` without what a calibration writes: the `<inertial>` of each link of `links`, the `damping` and `friction`
/// values of each joint of `joints`.
fn uncalibrated(doc: &str, links: &[String], joints: &[String]) -> String {
    let mut s = doc.to_string();
    for link in links {
        let at = s.find(&format!("<link name=\"{link}\"")).unwrap();
        let end = at + s[at..].find("</link>").unwrap();
        if let Some(a) = s[at..end].find("<inertial>").map(|k| at + k) {
            let b = a + s[a..].find("</inertial>").unwrap() + "</inertial>".len();
            s.replace_range(a..b, "");
        }
    }
    for joint in joints {
        let at = s.find(&format!("<joint name=\"{joint}\"")).unwrap();
        let end = at + s[at..].find("</joint>").unwrap();
        for attribute in ["damping=\"", "friction=\""] {
            if let Some(a) = s[at..end].find(attribute).map(|k| at + k + attribute.len()) {
                let b = a + s[a..].find('"').unwrap();
                s.replace_range(a..b, "");
            }
        }
    }
    s
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn the_ur5_s_rotor_inertia_and_torque_offsets_are_identified() {
    drives_of(
        &UR5,
        &[
            ("shoulder_pan_joint", 0.8, 2.0),
            ("shoulder_lift_joint", 1.0, -3.0),
            ("elbow_joint", 0.5, 1.5),
            ("wrist_1_joint", 0.15, 0.5),
            ("wrist_2_joint", 0.12, -0.4),
            ("wrist_3_joint", 0.1, 0.3),
        ],
    );
}

#[test]
fn the_panda_s_rotor_inertia_and_torque_offsets_are_identified() {
    drives_of(
        &PANDA,
        &[
            ("panda_joint1", 0.6, 0.8),
            ("panda_joint2", 0.5, -1.0),
            ("panda_joint3", 0.4, 0.6),
            ("panda_joint4", 0.4, -0.7),
            ("panda_joint5", 0.15, 0.3),
            ("panda_joint6", 0.12, -0.25),
            ("panda_joint7", 0.1, 0.2),
        ],
    );
}

/// The UR5's posterior can have two optima about a unit of the objective apart: the forearm's COM near its joint and
/// the wrist at its far end twice as heavy, or both where they are. The nominal URDF and log are the coverage bench's
/// nominal 9 (`dynforge-bench-identify-coverage`: a draw of the prior at spread 0.5 about the truth, whose forearm
/// COM is stated 0.55 m from the joint, so that the prior lets it wander; 30 s, 1 % effort noise, 2^17 encoders).
/// Searched from the nominal alone, identify ended at the higher optimum: wrist 1's mass 2.70 kg (true 1.22) at
/// z = +9.5, the forearm's COM 0.043 m (true 0.25) at z = -12.4. Searched from prior draws too, it takes the lower
/// optimum and its spreads include the distance to the other, which it says. With the joints' rotor inertia and
/// offsets identified too, the noisy log's search ends at the lower optimum alone (the other no longer within the
/// gap) and the clean log's still finds both: the lower is taken on both, and one of them says so.
#[test]
fn a_posterior_with_two_optima_is_reported_with_both() {
    use dynforge_proto::spread::Spread;
    use dynforge_robot::prior::CoordinatePrior;
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let f = Harness::new(py, tmp.path(), &UR5);
    let noisy = f.log(&UR5, 10, 30.0, "held", LogKind::Noisy, 1000.0);
    let truth_text = std::fs::read_to_string(&f.urdf).unwrap();
    let truth = read_log(&noisy, Some((&truth_text, "true.urdf")), &Reading::default()).unwrap();
    let spread = Spread::uniform(0.5);
    let mut rng = dynforge_robot::rng::Rng::stream(7, &[9]);
    let nominal = CoordinatePrior::of(&truth.model, spread).unwrap().draw(&truth.model, || rng.normal()).unwrap();
    let text = truth.urdf_of(&nominal).unwrap();
    let options = Options {
        spread,
        conditioning: Conditioning { effort: Some(EffortConvention::Held), ..Conditioning::default() },
        ..Options::default()
    };
    let (id, _) = identify_logs(&[noisy], Some((&text, "nominal.urdf")), &options).unwrap();
    // The same two on the noise-free log of the same motion, and no more: the searches that stop on the wall of a
    // clean log's narrow valley in the coordinates (a unit or less above the optimum they were crawling toward) are
    // not counted as optima of their own.
    let clean = f.log(&UR5, 10, 30.0, "held", LogKind::Clean, 1000.0);
    let mut notes = Vec::new();
    for id in [id, identify_logs(&[clean], Some((&text, "nominal.urdf")), &options).unwrap().0] {
        let mut at_truth = id.clone();
        at_truth.report_values_of(&truth.model);
        for name in ["wrist_1_link.mass", "forearm_link.com_z"] {
            let (p, t) = id.parameters().into_iter().zip(at_truth.parameters()).find(|(p, _)| p.name == name).unwrap();
            let z = p.estimate.z(t.estimate.value);
            assert!(z.abs() < 2.0, "{name}: z = {z:.2} ({:?})", id.notes);
        }
        notes.extend(id.notes);
    }
    assert!(notes.iter().any(|n| n.contains("leave 2 optima")), "{notes:?}");
}

/// The command itself on a 125 Hz bag split in two files (its /robot_description in the first): the values printed
/// are the written URDF's, which Pinocchio and MuJoCo load with our dynamics; logs that cannot support a
/// calibration are refused, naming the joint and the reason, and write nothing.
#[test]
fn identify_writes_what_it_prints_and_refuses_logs_it_cannot_use() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let f = Harness::new(py.clone(), tmp.path(), &UR5);
    let nominal = f.nominal(5);
    let split = f.dir.join("ur5-125hz");
    f.run(
        &[],
        &json!({
            "urdf": f.urdf, "friction": UR5.friction_json(), "seed": 4, "duration": 30.0, "rate": 125.0, "effort": "held",
            "out": split, "split": 2,
        }),
    );
    let held = log(&f, &UR5, 2, 20.0, EffortConvention::Held, LogKind::Clean, 125.0);
    // `info` reads the split directory as identify will: both files, its rate, its velocity.
    let info = dynforge(&["info", split.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&info.stdout);
    assert!(
        said.contains("identify: yes: 6 joints, 3751 samples in 1 stretch(es) at 125.0 Hz; velocity as logged")
            && said.contains("estimate: yes: a 6-joint robot"),
        "{said}"
    );
    let out = f.dir.join("calibrated.urdf");
    let (s, n, o, h) =
        (split.to_str().unwrap(), nominal.to_str().unwrap(), out.to_str().unwrap(), held.to_str().unwrap());
    let run = dynforge(&["identify", s, "--urdf", n, "--out", o, "--holdout", h, "--json"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let v: Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(v["rate"].as_f64().unwrap().round(), 125.0);
    // Friction at 125 Hz (a zero-order hold at the log's rate): within 1 % (0.6 % measured).
    for (j, (name, c, vis)) in UR5.friction.iter().enumerate() {
        let (ec, ev) = (
            v["joints"][j]["coulomb"]["value"].as_f64().unwrap() / c - 1.0,
            v["joints"][j]["viscous"]["value"].as_f64().unwrap() / vis - 1.0,
        );
        assert!(ec.abs() < 0.01 && ev.abs() < 0.01, "{name}: {ec:+.4} {ev:+.4}");
    }
    assert!(v["held_out"]["nrmse_calibrated"].as_f64().unwrap() < 0.01 * v["held_out"]["nrmse_urdf"].as_f64().unwrap());
    // Printed is written: every reported value is the written URDF's, to the last digit.
    let written = dynforge_robot::urdf::load(&out).unwrap();
    let p = dynforge_robot::parameters::dynamic_parameters(&written);
    for (l, link) in v["links"].as_array().unwrap().iter().enumerate() {
        let inertia = written.inertia(l);
        assert_eq!(link["mass"]["value"].as_f64().unwrap(), inertia.mass, "{}", link["name"]);
        let c = inertia.com();
        for (k, ck) in [c.x, c.y, c.z].iter().enumerate() {
            assert_eq!(link["com"][k]["value"].as_f64().unwrap(), *ck, "{} com {k}", link["name"]);
        }
    }
    for (j, joint) in v["joints"].as_array().unwrap().iter().enumerate() {
        let at = dynforge_proto::params::friction_index(6, j);
        assert_eq!(joint["coulomb"]["value"].as_f64().unwrap(), p[at]);
        assert_eq!(joint["viscous"]["value"].as_f64().unwrap(), p[at + 1]);
    }
    // The written URDF loads in MuJoCo with the calibrated masses: its total is the nominal's (whose fixed base
    // the calibration leaves as it is) with the moving links' masses replaced.
    let load = |path: &str| -> Value { serde_json::from_str(&f.run(&["--load", path], &json!({}))).unwrap() };
    let (loaded, before) = (load(o), load(n));
    let moving = |m: &dynforge_robot::Model| (0..6).map(|l| m.inertia(l).mass).sum::<f64>();
    let nominal_model = dynforge_robot::urdf::load(&nominal).unwrap();
    let want = before["mass"].as_f64().unwrap() - moving(&nominal_model) + moving(&written);
    assert_eq!(loaded["nv"], 6);
    assert!((loaded["mass"].as_f64().unwrap() - want).abs() < 1e-9 * want, "{loaded} vs {want}");

    // And in Pinocchio, with our inverse dynamics.
    let pinocchio = concat!(env!("CARGO_MANIFEST_DIR"), "/robot/tests/reference/pinocchio_dynamics.py");
    let states: Vec<Value> = (0..3)
        .map(|k| {
            let x = |a: f64| (0..6).map(|j| a * ((j + k) as f64 * 0.7).sin()).collect::<Vec<f64>>();
            json!({"q": x(1.0), "qd": x(0.5), "qdd": x(2.0), "tau": x(0.0)})
        })
        .collect();
    let reply =
        dynforge_testkit::run_python(&py, Path::new(pinocchio), &[], &json!({"urdf": o, "states": states}).to_string());
    let reply: Value = serde_json::from_str(&reply).unwrap();
    let mut data = dynforge_robot::Data::new(&written);
    for (state, theirs) in states.iter().zip(reply.as_array().unwrap()) {
        let v = |k: &str| state[k].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect::<Vec<f64>>();
        let ours = dynforge_robot::rnea(&written, &mut data, &v("q"), &v("qd"), &v("qdd")).to_vec();
        for (a, b) in ours.iter().zip(theirs["rnea"].as_array().unwrap()) {
            // Two evaluations of the same sums: agreement to rounding of the largest torque (~100 N m).
            assert!((a - b.as_f64().unwrap()).abs() < 1e-9, "{ours:?} vs {}", theirs["rnea"]);
        }
    }

    // A URDF whose elbow turns about another axis leaves the elbow's torque unexplained by far more than its noise,
    // and not as a function of its velocity: a warning names the joint and the kinematics. (A link's length is no
    // such case: a UR5 upper arm 17.5 cm too long is absorbed by the shoulder lift's rotor inertia and the links'
    // first moments, which the torques cannot tell from it, and leaves 0.3 % of the torque unexplained.)
    let wrong = f.dir.join("wrong.urdf");
    let text = std::fs::read_to_string(&nominal).unwrap();
    let elbow = "xyz=\"0.0 -0.1197 0.425\"/>\n    <axis xyz=\"0 1 0\"/>";
    assert!(text.contains(elbow), "the nominal URDF's elbow is not as written here");
    std::fs::write(&wrong, text.replace(elbow, "xyz=\"0.0 -0.1197 0.425\"/>\n    <axis xyz=\"0 0 1\"/>")).unwrap();
    let none = f.dir.join("none.urdf");
    let (w, e) = (wrong.to_str().unwrap(), none.to_str().unwrap());
    let warned = dynforge(&["identify", s, "--urdf", w, "--out", e, "--accept-unconverged", "--json"]);
    assert!(warned.status.success(), "{}", String::from_utf8_lossy(&warned.stderr));
    let v: Value = serde_json::from_slice(&warned.stdout).unwrap();
    let warnings: Vec<&str> = v["warnings"].as_array().unwrap().iter().filter_map(Value::as_str).collect();
    assert!(
        warnings.iter().any(|w| w.contains("joint 'elbow_joint'") && w.contains("check the URDF's kinematics")),
        "{warnings:?}"
    );
    assert!(!warnings.iter().any(|w| w.contains("friction the")), "nothing is called friction: {warnings:?}");
    std::fs::remove_file(&none).unwrap();
    // Joints named otherwise in the URDF than in the log: refused, naming both.
    std::fs::write(&wrong, text.replace("\"elbow_joint\"", "\"elbow\"")).unwrap();
    let refused = dynforge(&["identify", s, "--urdf", wrong.to_str().unwrap(), "--out", none.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && said.contains("\"elbow_joint\"") && said.contains("\"elbow\""), "{said}");
    assert!(!none.exists(), "a refused calibration writes nothing");
}

/// A joint with friction the model does not hold (a Stribeck rise of 3.5 N m below ~0.3 rad/s on the elbow, which no
/// Coulomb, viscous and offset terms follow: it leaves 10 % of the elbow's torque) is calibrated, not refused: a
/// warning names the joint, the share of its torque left and that it is friction; the other joints come out as they
/// would without it.
#[test]
fn a_joint_with_unmodelled_friction_is_calibrated_and_its_share_printed() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let f = Harness::new(py, tmp.path(), &UR5);
    let nominal = f.nominal(5);
    let (bag, out) = (f.dir.join("stribeck.mcap"), f.dir.join("stribeck.urdf"));
    f.run(
        &[],
        &json!({
            "urdf": f.urdf, "friction": UR5.friction_json(), "seed": 1, "duration": 30.0, "rate": 1000.0,
            "effort": "sampled", "noise": 0.01, "counts": 131072, "velocity": "encoder",
            "stribeck": {"elbow_joint": [3.5, 0.3]}, "out": bag,
        }),
    );
    let run = dynforge(&["identify", path(&bag), "--urdf", path(&nominal), "--out", path(&out), "--json"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let v: Value = serde_json::from_slice(&run.stdout).unwrap();
    let warnings: Vec<&str> = v["warnings"].as_array().unwrap().iter().filter_map(Value::as_str).collect();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    let elbow = &v["joints"][2];
    let (share, of_velocity) = (elbow["nrmse"].as_f64().unwrap(), elbow["velocity_share"].as_f64().unwrap());
    // The hump is 3.5 N m against the elbow's 16 N m RMS torque; what no monotone friction follows of it is left.
    assert!(
        (0.05..0.2).contains(&share) && of_velocity > 0.9,
        "elbow: {share} unexplained, {of_velocity} of it friction"
    );
    let printed = format!("joint 'elbow_joint' leaves {share:.3} of its torque's spread unexplained");
    assert!(
        warnings[0].contains(&printed) && warnings[0].contains("function of its velocity: friction"),
        "{warnings:?}"
    );
    // The other joints' friction within 1 % (0.3 % measured), as from a log without the hump.
    for (j, (name, c, vis)) in UR5.friction.iter().enumerate().filter(|(j, _)| *j != 2) {
        let (ec, ev) = (
            v["joints"][j]["coulomb"]["value"].as_f64().unwrap() / c - 1.0,
            v["joints"][j]["viscous"]["value"].as_f64().unwrap() / vis - 1.0,
        );
        assert!(ec.abs() < 0.01 && ev.abs() < 0.01, "{name}: {ec:+.4} {ev:+.4}");
    }
    assert!(out.exists());
}

/// A joint the logs hold still (the Panda's gripper, its mimic finger with it) is welded at its mean logged position,
/// which `info` says before and `identify` says in a note, and the arm is calibrated on the joints that move.
#[test]
fn a_joint_the_logs_hold_still_is_welded_with_a_note() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let f = Harness::new(py, tmp.path(), &PANDA);
    let still = log(&f, &PANDA, 1, 10.0, EffortConvention::Held, LogKind::Clean, 1000.0);
    let info = dynforge(&["info", still.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&info.stdout);
    assert!(
        said.contains("identify: yes: 7 joints")
            && said.contains("panda_finger_joint1 move too little (under 100 moving samples): welded"),
        "{said}"
    );
    let out = f.dir.join("welded.urdf");
    let run = dynforge(&["identify", still.to_str().unwrap(), "--out", out.to_str().unwrap(), "--json"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let v: Value = serde_json::from_slice(&run.stdout).unwrap();
    let notes: Vec<&str> = v["notes"].as_array().unwrap().iter().filter_map(Value::as_str).collect();
    assert!(notes.iter().any(|n| n.contains("'panda_finger_joint1'") && n.contains("welded")), "{notes:?}");
    assert_eq!(v["joints"].as_array().map(Vec::len), Some(7), "the seven arm joints, the finger welded");
    assert!(out.exists());
}

/// Logs of one Panda whose fingers are held a little apart from log to log (as a gripper is) are one robot: the
/// fingers are welded where the first log holds them, and a second log that holds them elsewhere says so.
#[test]
fn logs_whose_welded_fingers_sit_apart_are_one_robot() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let f = Harness::new(py, tmp.path(), &PANDA);
    let bag =
        |seed: u64, finger: f64| {
            let out = tmp.path().join(format!("held-{seed}.mcap"));
            f.run(&[], &json!({
            "urdf": f.urdf, "friction": PANDA.friction_json(), "seed": seed, "duration": 4.0, "rate": 1000.0,
            "effort": "held", "hold": {"panda_finger_joint1": finger, "panda_finger_joint2": finger}, "out": out,
        }));
            out.display().to_string()
        };
    let (a, b, c) = (bag(1, 0.02), bag(2, 0.0201), bag(3, 0.03));
    let out = tmp.path().join("out.urdf");
    let o = dynforge(&["identify", &a, &b, "--fix", "panda_finger_joint1", "--out", out.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!said.contains("as in the first log"), "{said}");
    let o = dynforge(&["identify", &a, &c, "--fix", "panda_finger_joint1", "--out", out.to_str().unwrap()]);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let note = said.lines().find(|l| l.contains("held-3") && l.contains("'panda_finger_joint1' welded at"));
    assert!(note.is_some_and(|n| n.contains("as in the first log, though its mean here is 0.0")), "{said}");
}

/// `estimate` reads robots of the family its model was trained on: a UR5's or a Panda's log is refused, naming the
/// command that serves them, and nothing is written.
#[test]
fn estimate_refuses_a_real_arm_and_names_identify() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let (data, run) = (tmp.path().join("data"), tmp.path().join("run"));
    let generated =
        dynforge(&["generate", "--out", data.to_str().unwrap(), "--robots", "6", "--trajectories", "2", "--seed", "7"]);
    assert!(generated.status.success(), "{}", String::from_utf8_lossy(&generated.stderr));
    let small = ["--epochs", "1", "--generated", "256", "--dim", "16", "--validation", "0.34"];
    let mut train = vec!["train", data.to_str().unwrap(), "--out", run.to_str().unwrap()];
    train.extend(small);
    let trained = dynforge(&train);
    assert!(trained.status.success(), "{}", String::from_utf8_lossy(&trained.stderr));
    for arm in [&UR5, &PANDA] {
        let f = Harness::new(py.clone(), tmp.path(), arm);
        let log = log(&f, arm, 1, 10.0, EffortConvention::Held, LogKind::Clean, 1000.0);
        let out = tmp.path().join(format!("{}.estimated.urdf", arm.name));
        let refused = dynforge(&[
            "estimate",
            "--checkpoint",
            run.to_str().unwrap(),
            log.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        let said = String::from_utf8_lossy(&refused.stderr);
        assert!(
            !refused.status.success() && said.contains("not of the family") && said.contains("dynforge identify"),
            "{}: {said}",
            arm.name
        );
        assert!(!out.exists(), "{}: a refused estimate writes nothing", arm.name);
    }
}
