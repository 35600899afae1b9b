//! End-to-end tests of `dynforge robot`, spawning the real binary.

mod common;

use common::dynforge;

use dynforge_robot::generator::generate;

use dynforge_proto::generator::GeneratorConfig;
use dynforge_robot::urdf;

#[test]
fn robot_out_writes_a_urdf_that_loads_back_identically() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("r.urdf");
    let out = dynforge(&["robot", "--seed", "1", "--id", "7", "--out", path.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let loaded = urdf::load(&path).unwrap();
    let want = generate(&GeneratorConfig::default(), 1, 7).unwrap();
    assert_eq!(loaded, want.model);
    // Only the URDF is left behind: no temporary file.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    // Without --out the same URDF goes to standard output.
    let stdout = dynforge(&["robot", "--seed", "1", "--id", "7"]).stdout;
    assert_eq!(String::from_utf8(stdout).unwrap(), std::fs::read_to_string(&path).unwrap());
}

#[test]
fn inspect_prints_the_model_and_its_labels() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("r.urdf");
    assert!(dynforge(&["robot", "--seed", "3", "--id", "2", "-o", path.to_str().unwrap()]).status.success());
    let out = dynforge(&["robot", "--inspect", path.to_str().unwrap()]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    let model = generate(&GeneratorConfig::default(), 3, 2).unwrap().model;
    assert!(text.contains("6 revolute joints"), "{text}");
    let mass_line = text.lines().find(|l| l.trim_start().starts_with("mass_l2")).expect("labels are printed");
    let printed: f64 = mass_line.split_whitespace().nth(1).unwrap().parse().unwrap();
    assert!((printed - model.inertia(1).mass).abs() < 1e-6, "{mass_line}");
}

#[test]
fn bad_inputs_fail_with_a_message_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.urdf");
    std::fs::write(&bad, "<robot name='x'><link name='a'/><link name='b'/><joint name='j' type='planar'><parent link='a'/><child link='b'/></joint></robot>").unwrap();
    let out = dynforge(&["robot", "--inspect", bad.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("bad.urdf") && err.contains("'j'") && err.contains("unsupported type planar"), "{err}");
    assert_eq!(err.matches("bad.urdf").count(), 1, "the file named once: {err}");
    // A prismatic joint moves, but only within limits that bound a range.
    std::fs::write(&bad, "<robot name='x'><link name='a'/><link name='b'/><joint name='j' type='prismatic'><parent link='a'/><child link='b'/></joint></robot>").unwrap();
    let out = dynforge(&["robot", "--inspect", bad.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("bad.urdf") && err.contains("'j'") && err.contains("do not bound a range"), "{err}");

    let cfg = dir.path().join("gen.toml");
    std::fs::write(&cfg, "tube_wall_fraction = [0.1, 0.7]\n").unwrap();
    let out = dynforge(&["robot", "--config", cfg.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("gen.toml") && err.contains("tube_wall_fraction"), "{err}");

    // Bounds are said in words (not the 309 digits of the largest f64); a zero joint axis is refused up front.
    std::fs::write(&cfg, "coulomb = [[1.0, 0.5], [0, 1], [0, 1], [0, 1], [0, 1], [0, 1]]\n").unwrap();
    let err = String::from_utf8(dynforge(&["robot", "--config", cfg.to_str().unwrap()]).stderr).unwrap();
    assert!(err.contains("coulomb[0]") && err.contains("non-negative numbers") && err.len() < 300, "{err}");
    let mut k = dynforge_proto::generator::GeneratorConfig::default();
    k.kinematics.axes[3] = [0.0; 3];
    std::fs::write(&cfg, toml::to_string(&k).unwrap()).unwrap();
    let out = dynforge(&["robot", "--config", cfg.to_str().unwrap()]);
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(!out.status.success() && err.contains("axes[3]") && err.contains("not a direction"), "{err}");

    // An OS error is said once, after the file it concerns.
    let missing = dir.path().join("missing.mcap");
    let out = dynforge(&["identify", missing.to_str().unwrap()]);
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(!out.status.success() && err.contains(missing.to_str().unwrap()), "{err}");
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
    // The same log twice, however spelt, is refused before it is read.
    std::fs::create_dir(dir.path().join("logs")).unwrap();
    let log = dir.path().join("logs/twice.mcap");
    std::fs::write(&log, b"not read").unwrap();
    let again = dir.path().join("logs/./twice.mcap");
    let out = dynforge(&["identify", log.to_str().unwrap(), again.to_str().unwrap()]);
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(!out.status.success() && err.contains("twice.mcap: given twice (also as"), "{err}");
    // A --cutoff at or above the log's Nyquist frequency is refused, naming both.
    let tmp = tempfile::tempdir().unwrap();
    let bag = tmp.path().join("one.mcap");
    let model = generate(&GeneratorConfig::default(), 5, 1).unwrap().model;
    let traj = dynforge_testkit::sinusoid_recording(&model, 0, 1e-3, 500);
    dynforge_testkit::write_bag(&bag, &urdf::to_string(&model, &Default::default()), &traj);
    let out = dynforge(&["identify", bag.to_str().unwrap(), "--cutoff", "600"]);
    let err = String::from_utf8(out.stderr).unwrap();
    let said = "--cutoff 600 Hz is at or above the log's Nyquist frequency (500.0 Hz)";
    assert!(!out.status.success() && err.contains(said), "{err}");
    // A bag without joint states says so (not that the URDF has no moving joint).
    let empty = tmp.path().join("empty.mcap");
    let none = dynforge_recording::JointTrajectory { names: traj.names.clone(), ..Default::default() };
    dynforge_testkit::write_bag(&empty, &urdf::to_string(&model, &Default::default()), &none);
    let out = dynforge(&["identify", empty.to_str().unwrap()]);
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(!out.status.success() && err.contains("empty.mcap: no joint state in the file"), "{err}");
    // So is a held-out log that is one of the logs calibrated from, however spelt.
    let out = dynforge(&["identify", log.to_str().unwrap(), "--holdout", again.to_str().unwrap()]);
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(!out.status.success() && err.contains("twice.mcap: held out and also calibrated from"), "{err}");
    // A directory is read as a rosbag2 bag, and one without an MCAP file says so.
    let out = dynforge(&["identify", dir.path().to_str().unwrap()]);
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(!out.status.success() && err.contains("a directory with no .mcap or .db3 file"), "{err}");

    // An unwritable destination fails cleanly and leaves nothing behind.
    let out = dynforge(&["robot", "--out", dir.path().join("missing/dir/r.urdf").to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8(out.stderr).unwrap().contains("missing/dir/r.urdf"));
}
