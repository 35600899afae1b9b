//! `dynforge excite` on example-robot-data's UR5: the written trajectories keep the URDF's limits sample by sample
//! (read back from the CSV, the efforts recomputed by inverse dynamics), start and end at rest, are what their
//! seed makes them, and identify the base parameters better than random multi-sines within the same limits.

mod common;

use common::dynforge;
use dynforge_robot::{Data, rnea};
use dynforge_testkit::arms::{Harness, UR5};

const ACCELERATION: f64 = 4.0;
const SHARE: f64 = 0.8;

/// Rows of a written CSV: time, then positions, velocities and accelerations of the `n` joints.
fn rows(csv: &str, n: usize) -> Vec<Vec<f64>> {
    let mut lines = csv.lines();
    let header = lines.next().unwrap();
    assert_eq!(header.split(',').count(), 1 + 3 * n, "{header}");
    lines.map(|l| l.split(',').map(|v| v.parse::<f64>().unwrap()).collect()).collect()
}

#[test]
fn the_ur5s_excitation_keeps_its_limits_and_beats_random_multisines() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let f = Harness::new(py, tmp.path(), &UR5);
    let model = dynforge_robot::urdf::parse(&std::fs::read_to_string(&f.urdf).unwrap(), &f.urdf).unwrap();
    let n = model.dof();
    let design = |out: &std::path::Path| {
        let args = [
            "excite",
            "--urdf",
            &f.urdf,
            "--out",
            out.to_str().unwrap(),
            "--count",
            "2",
            "--duration",
            "6",
            "--evaluations",
            "150",
            "--rate",
            "1000",
            "--acceleration",
            "4",
            "--seed",
            "5",
        ];
        let o = dynforge(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8(o.stdout).unwrap()
    };
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let printed = design(&a);
    // A base covariance trace at least 2x smaller than the best of the random sets of multi-sines within the same
    // limits (the first ratio printed), and at least 5x smaller than the dataset generator's waypoint tours for the
    // same total time (the second).
    let ratios: Vec<f64> = printed
        .split("base covariance trace ")
        .skip(1)
        .map(|s| s.split('x').next().and_then(|s| s.parse().ok()).unwrap_or_else(|| panic!("{printed}")))
        .collect();
    assert!(ratios.len() == 3 && printed.contains("waypoint tours'"), "{printed}");
    assert!(ratios[0] >= 2.0 && ratios[1] >= 5.0, "{printed}");
    // The same against the benchmark's independent multi-sines (Pinocchio's regressor at 1 kHz, drawn and scaled by
    // bench/excitation.py), each trajectory alone and the set, in trace and in information per dimension.
    let scored = tmp.path().join("scored.json");
    let bench = concat!(env!("CARGO_MANIFEST_DIR"), "/bench/excitation.py");
    let o = std::process::Command::new(&f.python)
        .args([bench, "--urdf", &f.urdf, "--acceleration", "4", "--draws", "10", "--json"])
        .arg(&scored)
        .arg("--design")
        .arg(&a)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let scored: serde_json::Value = serde_json::from_slice(&std::fs::read(&scored).unwrap()).unwrap();
    let gain = |q: &serde_json::Value, best: &serde_json::Value| {
        let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
        (f(best, "trace") / f(q, "trace"), (f(q, "log_det") - f(best, "log_det")).exp())
    };
    let mut gains: Vec<(f64, f64)> =
        scored["alone"].as_array().unwrap().iter().map(|q| gain(q, &scored["multisine"]["best"])).collect();
    gains.push(gain(&scored["set"], &scored["multisine_sets"]["best"]));
    assert!(gains.iter().all(|&(trace, det)| trace >= 2.0 && det >= 2.0), "{gains:?}");
    let mut data = Data::new(&model);
    for k in 0..2 {
        let csv = std::fs::read_to_string(a.join(format!("excitation-{k}.csv"))).unwrap();
        let rows = rows(&csv, n);
        assert_eq!(rows.len(), 6001, "6 s at 1 kHz, both ends");
        let (first, last) = (&rows[0], &rows[rows.len() - 1]);
        for j in 0..n {
            assert!((first[1 + j] - last[1 + j]).abs() < 1e-9, "joint {j} ends where it started");
            for r in [first, last] {
                assert!(r[1 + n + j].abs() < 1e-9 && r[1 + 2 * n + j].abs() < 1e-9, "joint {j} at rest at the ends");
            }
        }
        let dt = 1e-3;
        for (i, r) in rows.iter().enumerate() {
            let (q, qd, qdd) = (&r[1..1 + n], &r[1 + n..1 + 2 * n], &r[1 + 2 * n..]);
            for (j, joint) in model.joints().iter().enumerate() {
                let l = &joint.limits;
                assert!(q[j] >= l.lower && q[j] <= l.upper, "row {i} joint {j}: {} outside its range", q[j]);
                assert!(qd[j].abs() <= SHARE * l.velocity + 1e-9, "row {i} joint {j}: speed {}", qd[j]);
                assert!(qdd[j].abs() <= ACCELERATION + 1e-9, "row {i} joint {j}: acceleration {}", qdd[j]);
            }
            if i > 0 && i + 1 < rows.len() {
                // The CSV's velocity is its positions' derivative: central differences err by dt^2/6 |q'''|, with
                // |q'''| under the acceleration limit times the highest harmonic's 2 pi 5/6 rad/s: < 1e-6.
                for j in 0..n {
                    let diff = (rows[i + 1][1 + j] - rows[i - 1][1 + j]) / (2.0 * dt);
                    assert!((diff - qd[j]).abs() < 1e-5, "row {i} joint {j}: {diff} vs {}", qd[j]);
                }
            }
            if i % 10 == 0 {
                let tau = rnea(&model, &mut data, q, qd, qdd).to_vec();
                for (j, joint) in model.joints().iter().enumerate() {
                    let friction = joint.friction.coulomb * qd[j].signum() + joint.friction.viscous * qd[j];
                    let effort = (tau[j] + friction).abs();
                    assert!(effort <= SHARE * joint.limits.effort * (1.0 + 1e-9), "row {i} joint {j}: {effort} N m");
                }
            }
        }
    }
    // The MCAP holds the same trajectory as one JointTrajectory, read by the official ROS 2 MCAP decoder.
    let script = r#"
import json, sys
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
with open(sys.argv[1], "rb") as f:
    msgs = [(ch.topic, sch.name, m) for sch, ch, _, m in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]
(topic, schema, m), = msgs
p = m.points
print(json.dumps({"topic": topic, "schema": schema, "names": list(m.joint_names), "count": len(p),
    "last_t": p[-1].time_from_start.sec + 1e-9 * p[-1].time_from_start.nanosec,
    "q1000": list(p[1000].positions), "qd1000": list(p[1000].velocities), "qdd1000": list(p[1000].accelerations)}))
"#;
    let py = std::env::var("DYNFORGE_PYTHON").unwrap();
    let o = std::process::Command::new(&py).args(["-c", script]).arg(a.join("excitation-0.mcap")).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let decoded: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(decoded["topic"], "/joint_trajectory_controller/joint_trajectory");
    assert_eq!(decoded["schema"], "trajectory_msgs/msg/JointTrajectory");
    let names: Vec<&str> = model.joints().iter().map(|j| j.name.as_str()).collect();
    assert_eq!(decoded["names"], serde_json::json!(names));
    assert_eq!(decoded["count"], 6001);
    assert!((decoded["last_t"].as_f64().unwrap() - 6.0).abs() < 1e-9);
    let csv = std::fs::read_to_string(a.join("excitation-0.csv")).unwrap();
    let row = &rows(&csv, n)[1000];
    for (what, at) in [("q1000", 1), ("qd1000", 1 + n), ("qdd1000", 1 + 2 * n)] {
        for j in 0..n {
            // The CSV rounds to 1e-9.
            let v = decoded[what][j].as_f64().unwrap();
            assert!((v - row[at + j]).abs() < 1e-8, "{what} joint {j}: {v} vs {}", row[at + j]);
        }
    }
    // The same seed, the same trajectories.
    design(&b);
    for k in 0..2 {
        let name = format!("excitation-{k}.json");
        assert_eq!(std::fs::read(a.join(&name)).unwrap(), std::fs::read(b.join(&name)).unwrap());
    }
    let report = std::fs::read_to_string(a.join("report.md")).unwrap();
    assert!(report.contains("48 of 72 parameter combinations"), "{report}");
}

#[test]
fn bad_requests_are_refused_naming_the_problem() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let o = dynforge(&["excite", "--urdf", "/nonexistent/robot.urdf", "--out", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent/robot.urdf"));
    let urdf = tmp.path().join("two.urdf");
    std::fs::write(
        &urdf,
        r#"<robot name="two"><link name="base"/>
           <link name="a"><inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
           <joint name="j0" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
             <limit lower="-1" upper="1" effort="10" velocity="1"/></joint></robot>"#,
    )
    .unwrap();
    let o = dynforge(&["excite", "--urdf", urdf.to_str().unwrap(), "--out", out.to_str().unwrap(), "--start", "0,0"]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("start pose has 2 values for 1 joints"), "{e}");
    let o = dynforge(&["excite", "--urdf", urdf.to_str().unwrap(), "--out", out.to_str().unwrap(), "--start", "0.99"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("'j0'") && e.contains("not inside its range"), "{e}");
    let o = dynforge(&["excite", "--urdf", urdf.to_str().unwrap(), "--out", out.to_str().unwrap(), "--fix", "j0=100"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("'j0'") && e.contains("welded at 100, outside its range [-1, 1]"), "{e}");
    // Work without bound is refused before any is done, naming the flag.
    let (u, d) = (urdf.to_str().unwrap(), out.to_str().unwrap());
    let cases: [(&[&str], &str); 4] = [
        (&["--duration", "0.001"], "past the 10 Hz an arm's joints follow: give a longer --duration"),
        (&["--rate", "1e9"], "give a lower --rate"),
        (&["--duration", "1e9"], "or a shorter --duration"),
        (&["--duration", "1e6", "--rate", "1"], "samples per trajectory at the design's 50 Hz"),
    ];
    for (flags, says) in cases {
        let mut args = vec!["excite", "--urdf", u, "--out", d, "--no-collision"];
        args.extend_from_slice(flags);
        let o = dynforge(&args);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && e.contains(says), "{flags:?}: {e}");
    }
    assert!(!out.exists(), "nothing written for a refused request");
}

/// A URDF named relative to the working directory finds its `package://` meshes above it, as an absolute path does
/// (its parent was the empty path, which has no ancestors to search).
#[test]
fn a_relative_urdf_finds_its_package_meshes() {
    let tmp = tempfile::tempdir().unwrap();
    let package = tmp.path().join("my_arm");
    std::fs::create_dir_all(package.join("urdf")).unwrap();
    std::fs::create_dir_all(package.join("meshes")).unwrap();
    // A binary STL of one tetrahedron: 80-byte header, a count, 50 bytes per triangle.
    let v = [[0.0f32, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.05, 0.0], [0.0, 0.0, 0.05]];
    let mut stl = vec![0u8; 80];
    stl.extend(4u32.to_le_bytes());
    for t in [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]] {
        stl.extend([0u8; 12]);
        t.iter().flat_map(|&k| v[k]).for_each(|x| stl.extend(x.to_le_bytes()));
        stl.extend([0u8; 2]);
    }
    std::fs::write(package.join("meshes/part.stl"), stl).unwrap();
    let mesh = r#"<collision><geometry><mesh filename="package://my_arm/meshes/part.stl"/></geometry></collision>"#;
    let inertial =
        r#"<inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>"#;
    let urdf = format!(
        r#"<robot name="two"><link name="base">{mesh}</link><link name="a">{inertial}{mesh}</link>
           <joint name="j0" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
             <limit lower="-1" upper="1" effort="10" velocity="1"/></joint></robot>"#
    );
    std::fs::write(package.join("urdf/arm.urdf"), urdf).unwrap();
    let out = tmp.path().join("out");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_dynforge"))
        .args(["excite", "--urdf", "arm.urdf", "--out", out.to_str().unwrap()])
        .args(["--count", "1", "--duration", "2", "--evaluations", "5", "--harmonics", "2"])
        .current_dir(package.join("urdf"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("excitation-0.json").exists());
}

/// An arm whose upper arm can swing down into its base column: the designed motion is free of self-collision by
/// Pinocchio's and coal's account, row by row of the CSV, with the same geometry (primitives, so both check the
/// same shapes); designed without the check, the same request drives the arm into its column.
#[test]
fn the_design_is_free_of_self_collision_by_pinocchios_account() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let urdf = tmp.path().join("column.urdf");
    let inertial =
        r#"<inertial><mass value="2"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.01"/></inertial>"#;
    let limit = r#"effort="200" velocity="4""#;
    std::fs::write(
        &urdf,
        format!(
            r#"<robot name="column">
  <link name="base"><collision><origin xyz="0 0 0.225"/><geometry><cylinder radius="0.1" length="0.45"/></geometry></collision></link>
  <link name="turret">{inertial}<collision><origin xyz="0 0 0.025"/><geometry><cylinder radius="0.06" length="0.05"/></geometry></collision></link>
  <link name="upper">{inertial}<collision><origin xyz="0 0 0.25"/><geometry><box size="0.06 0.06 0.5"/></geometry></collision></link>
  <link name="fore">{inertial}<collision><origin xyz="0 0 0.225"/><geometry><box size="0.05 0.05 0.45"/></geometry></collision></link>
  <link name="tool"><collision><geometry><sphere radius="0.05"/></geometry></collision></link>
  <joint name="yaw" type="revolute"><parent link="base"/><child link="turret"/><origin xyz="0 0 0.45"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" {limit}/></joint>
  <joint name="shoulder" type="revolute"><parent link="turret"/><child link="upper"/><origin xyz="0 0 0.05"/><axis xyz="0 1 0"/><limit lower="-2.9" upper="2.9" {limit}/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/><origin xyz="0 0 0.5"/><axis xyz="0 1 0"/><limit lower="-2.9" upper="2.9" {limit}/></joint>
  <joint name="flange" type="fixed"><parent link="fore"/><child link="tool"/><origin xyz="0 0 0.45"/></joint>
</robot>"#
        ),
    )
    .unwrap();
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/reference/self_collision.py");
    let check = |out: &std::path::Path, extra: &[&str]| {
        let mut args = vec!["excite", "--urdf", urdf.to_str().unwrap(), "--out", out.to_str().unwrap()];
        args.extend(["--count", "2", "--duration", "8", "--evaluations", "200", "--rate", "200", "--seed", "3"]);
        args.extend(extra);
        let o = dynforge(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let csvs: Vec<String> = (0..2).map(|k| out.join(format!("excitation-{k}.csv")).display().to_string()).collect();
        let mut argv = vec![urdf.display().to_string()];
        argv.extend(csvs);
        let argv: Vec<&str> = argv.iter().map(String::as_str).collect();
        let said = dynforge_testkit::run_python(&py, &script, &argv, "");
        (String::from_utf8(o.stdout).unwrap(), serde_json::from_str::<serde_json::Value>(&said).unwrap())
    };
    // A set of three, then two into the same directory: the directory holds the two, and its manifest lists them.
    let rerun = tmp.path().join("checked");
    let mut three = vec!["excite", "--urdf", urdf.to_str().unwrap(), "--out", rerun.to_str().unwrap()];
    three.extend(["--count", "3", "--duration", "8", "--evaluations", "50", "--rate", "200", "--seed", "4"]);
    assert!(dynforge(&three).status.success());
    assert!(rerun.join("excitation-2.json").exists());
    let (printed, checked) = check(&rerun, &[]);
    for ext in ["csv", "mcap", "json"] {
        assert!(!rerun.join(format!("excitation-2.{ext}")).exists(), "a stale excitation-2.{ext} is left");
    }
    let set: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rerun.join("excitation-set.json")).unwrap()).unwrap();
    assert_eq!(set["hashes"].as_array().map(Vec::len), Some(2), "{set}");
    // Pinocchio pairs geometry objects: base-upper, base-fore, base-tool, turret-fore, turret-tool; the design pairs
    // bodies (the tool welded to the forearm): base-upper, base-forearm, turret-forearm.
    assert_eq!(checked["pairs"], 5, "{checked}");
    assert_eq!(checked["colliding"], serde_json::json!([0, 0]), "{checked}");
    assert!(printed.contains("free of self-collision (3 body pairs checked"), "{printed}");
    let report = std::fs::read_to_string(tmp.path().join("checked/report.md")).unwrap();
    assert!(report.contains("Self-collision: checked"), "{report}");
    // With a padding of 2 cm the bodies keep that far apart (the upper arm starts 5 cm above the column).
    let (printed, padded) = check(&tmp.path().join("padded"), &["--clearance", "0.02"]);
    assert_eq!(padded["colliding"], serde_json::json!([0, 0]), "{padded}");
    assert!(printed.contains("free of self-collision (3 body pairs checked"), "the same pairs as unpadded: {printed}");
    // A padding the start pose itself breaks is refused, naming the pair and its distance, and nothing is written.
    let far = tmp.path().join("far");
    let mut args = vec!["excite", "--urdf", urdf.to_str().unwrap(), "--out", far.to_str().unwrap()];
    args.extend(["--count", "1", "--duration", "8", "--evaluations", "20", "--clearance", "10"]);
    let o = dynforge(&args);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("at the start pose base and upper (") && e.contains(" mm)"), "{e}");
    assert!(!far.exists(), "nothing written for a refused request");
    let report = std::fs::read_to_string(tmp.path().join("padded/report.md")).unwrap();
    let closest: Vec<f64> = report
        .lines()
        .filter_map(|l| l.strip_prefix("- trajectory ").and_then(|l| l.split(": ").nth(1)))
        .filter_map(|l| l.split(" mm").next().and_then(|v| v.parse().ok()))
        .collect();
    assert!(closest.len() == 2 && closest.iter().all(|&d| d >= 20.0), "{report}");
    let (_, unchecked) = check(&tmp.path().join("unchecked"), &["--no-collision"]);
    let hits: u64 = unchecked["colliding"].as_array().unwrap().iter().map(|c| c.as_u64().unwrap()).sum();
    assert!(hits > 0, "without the check the motion hits the column: {unchecked}");
}
