//! Helpers shared by dynforge's test suites.

pub mod arms;

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};

/// The Python of the reference-tool venv (`DYNFORGE_PYTHON`, set by `scripts/test.sh`). Without it, tests that
/// compare against independent references report that they were skipped, unless `DYNFORGE_REQUIRE_REFERENCE=1`
/// (also set by the test script), where a missing venv is an error.
pub fn reference_python() -> Option<String> {
    match std::env::var("DYNFORGE_PYTHON") {
        Ok(p) => Some(p),
        Err(_) if std::env::var("DYNFORGE_REQUIRE_REFERENCE").is_ok_and(|v| v == "1") => {
            panic!("DYNFORGE_REQUIRE_REFERENCE=1 but DYNFORGE_PYTHON is not set")
        }
        Err(_) => {
            eprintln!("SKIPPED: this reference test needs DYNFORGE_PYTHON (scripts/test.sh sets it)");
            None
        }
    }
}

/// Runs `python script args...` with `stdin`, panicking with its stderr if it fails; returns its stdout.
pub fn run_python(python: &str, script: &Path, args: &[&str], stdin: &str) -> String {
    let mut child = Command::new(python)
        .arg(script)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {python}: {e}"));
    child.stdin.take().expect("piped").write_all(stdin.as_bytes()).expect("stdin accepted");
    let out = child.wait_with_output().expect("python finishes");
    assert!(out.status.success(), "{} failed:\n{}", script.display(), String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).expect("UTF-8 output")
}

/// A recording of `model` following `q_j(t) = a_j sin(w_j t + p_j)` (a different set of amplitudes, frequencies and
/// phases for each `variant`), `samples` samples at step `dt`, logged as our shards and a motor driver log it: the
/// effort of sample `i` is the torque held over the step after it, here the torque of exact inverse dynamics plus
/// friction at the step's midpoint (the step's mean torque to `O(dt^2)`). The reference motion of the torque check
/// and identification tests.
pub fn sinusoid_recording(
    model: &dynforge_robot::Model,
    variant: u32,
    dt: f64,
    samples: usize,
) -> dynforge_recording::JointTrajectory {
    use dynforge_robot::{Data, friction_torque, rnea};
    let n = model.dof();
    let v = variant as f64;
    let a = |j: usize| 0.4 + 0.1 * j as f64 + 0.05 * v;
    let w = |j: usize| 1.0 + 0.3 * j as f64 + 0.37 * v;
    let p = |j: usize| 0.7 * j as f64 + 1.3 * v;
    let state = |t: f64| -> [Vec<f64>; 3] {
        [
            (0..n).map(|j| a(j) * (w(j) * t + p(j)).sin()).collect(),
            (0..n).map(|j| a(j) * w(j) * (w(j) * t + p(j)).cos()).collect(),
            (0..n).map(|j| -a(j) * w(j) * w(j) * (w(j) * t + p(j)).sin()).collect(),
        ]
    };
    let mut data = Data::new(model);
    let mut out = dynforge_recording::JointTrajectory {
        names: model.joints().iter().map(|j| j.name.clone()).collect(),
        ..Default::default()
    };
    let mut fr = vec![0.0; n];
    for i in 0..samples {
        let t = i as f64 * dt;
        let [q, qd, _] = state(t);
        let [qm, qdm, qddm] = state(t + dt / 2.0);
        friction_torque(model, &qdm, &mut fr);
        out.tau.extend(rnea(model, &mut data, &qm, &qdm, &qddm).iter().zip(&fr).map(|(x, f)| x + f));
        out.t.push(t);
        out.q.extend(q);
        out.qd.extend(qd);
    }
    out
}

/// Writes `traj` (joints in the order of its names) as a ROS 2-style bag at `path`, with `urdf` as its
/// `/robot_description`: what a user's log of that robot is.
pub fn write_bag(path: &Path, urdf: &str, traj: &dynforge_recording::JointTrajectory) {
    let n = traj.joints();
    let names: std::sync::Arc<[String]> = traj.names.as_slice().into();
    let joint_states: Vec<dynforge_proto::shard::JointState> = (0..traj.len())
        .map(|i| {
            let ns = (traj.t[i] * 1e9).round() as i64;
            let (q, qd, tau) = traj.sample(i);
            dynforge_proto::shard::JointState {
                sec: (ns / 1_000_000_000) as i32,
                nanosec: (ns % 1_000_000_000) as u32,
                frame_id: String::new(),
                name: names.clone(),
                position: q.to_vec(),
                velocity: qd.to_vec(),
                effort: tau.to_vec(),
            }
        })
        .collect();
    assert_eq!(joint_states.first().map_or(n, |m| m.name.len()), n);
    let content = dynforge_shard::ShardContent { urdf, joint_states: &joint_states, metadata: &Default::default() };
    dynforge_shard::write(path, &content).expect("the bag is written");
}

/// Every parameter's JSON object of an `identify --json` or `calibrate --json` output, in the order
/// `Identification::parameters` gives them (each link's mass, COM, inertia; then each joint's Coulomb and viscous
/// friction); `None` when the output lacks links or joints.
pub fn json_parameters(v: &serde_json::Value) -> Option<Vec<&serde_json::Value>> {
    let mut out = Vec::new();
    for l in v["links"].as_array()? {
        out.push(&l["mass"]);
        out.extend(l["com"].as_array()?.iter().chain(l["inertia"].as_array()?));
    }
    for j in v["joints"].as_array()? {
        out.extend([&j["coulomb"], &j["viscous"]]);
    }
    Some(out)
}
