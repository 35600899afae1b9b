//! Shards: written atomically and reproducibly, read back field by field by our reader and by the official MCAP
//! readers, and nothing written for a discarded run.

use std::path::Path;

use dynforge_proto::LABELS;
use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::job::Job;
use dynforge_proto::shard::{META_JOB, META_LABELS, META_TRAJECTORY};
use dynforge_proto::sim::SimConfig;
use dynforge_robot::parameters::labels_of;
use dynforge_robot::urdf;
use dynforge_worker::job::Runner;
use dynforge_worker::output::Outcome;
use dynforge_worker::simulate::Discard;

const JOB: Job = Job { seed: 3, robot: 2, trajectory: 5 };

fn written(outcome: Outcome) -> std::path::PathBuf {
    match outcome {
        Outcome::Written { path, .. } => path,
        Outcome::Discarded(d) => panic!("unexpected discard: {d}"),
    }
}

#[test]
fn shard_reads_back_every_field() {
    let dir = tempfile::tempdir().unwrap();
    let mut runner = Runner::new(GeneratorConfig::default(), SimConfig::default());
    let sim = runner.simulate(&JOB).unwrap();
    let (robot, (mv, rec)) = (sim.robot, sim.result.unwrap());
    let path = written(runner.run(&JOB, dir.path()).unwrap());
    assert_eq!(path.file_name().unwrap(), "r000002-t05-native.mcap");
    let bag = dynforge_shard::read(&path).unwrap();

    let model = urdf::parse(bag.robot_description.as_deref().expect("URDF rides along"), "shard").unwrap();
    assert_eq!(model, robot.model);
    assert_eq!(bag.joint_states.len(), rec.len());
    for (k, m) in bag.joint_states.iter().enumerate() {
        assert_eq!(m.stamp_ns(), k as i64 * 1_000_000, "1 kHz sim-time stamps");
        assert_eq!(m.name[..], ["joint_0", "joint_1", "joint_2", "joint_3", "joint_4", "joint_5"]);
        assert_eq!(m.position, rec.q[k]);
        assert_eq!(m.velocity, rec.qd[k]);
        assert_eq!(m.effort, rec.tau[k]);
    }
    let want = labels_of(&robot.model).unwrap();
    let got = &bag.metadata[META_LABELS];
    assert_eq!(got.len(), LABELS.len());
    for (l, v) in LABELS.iter().zip(want) {
        assert_eq!(got[l.name].parse::<f64>().unwrap(), v, "{}", l.name);
    }
    let job = &bag.metadata[META_JOB];
    assert_eq!((job["seed"].as_str(), job["robot"].as_str(), job["trajectory"].as_str()), ("3", "2", "5"));
    assert_eq!((job["engine"].as_str(), job["dt"].as_str()), ("native", "0.001"));
    let traj = &bag.metadata[META_TRAJECTORY];
    assert_eq!(traj["move_end"].parse::<f64>().unwrap(), mv.duration);
    let start: Vec<f64> = traj["start"].split(' ').map(|v| v.parse().unwrap()).collect();
    assert_eq!(start, mv.start);
}

#[test]
fn rerunning_a_job_rewrites_a_byte_identical_shard() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let pa = written(Runner::new(GeneratorConfig::default(), SimConfig::default()).run(&JOB, a.path()).unwrap());
    let pb = written(Runner::new(GeneratorConfig::default(), SimConfig::default()).run(&JOB, b.path()).unwrap());
    assert_eq!(std::fs::read(&pa).unwrap(), std::fs::read(&pb).unwrap());
    // Only the shard is left: no temporary file.
    assert_eq!(std::fs::read_dir(a.path()).unwrap().count(), 1);
}

#[test]
fn a_discarded_run_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    // A goal tolerance no controller meets turns the run into a waypoint timeout.
    let sim = SimConfig { goal_tolerance: 1e-12, ..SimConfig::default() };
    let outcome = Runner::new(GeneratorConfig::default(), sim).run(&JOB, dir.path()).unwrap();
    assert!(matches!(outcome, Outcome::Discarded(Discard::Timeout { .. })), "{outcome:?}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn a_robot_the_generator_rejects_is_a_discard_not_a_failure() {
    // A failure is retried on every resume; a rejection is as deterministic as a collision and must be final.
    let dir = tempfile::tempdir().unwrap();
    let mut generator = GeneratorConfig::default();
    generator.kinematics.axes[2] = [0.0; 3];
    let outcome = Runner::new(generator, SimConfig::default()).run(&JOB, dir.path()).unwrap();
    match outcome {
        Outcome::Discarded(d) => assert_eq!(d.code(), "rejected", "{d}"),
        other => panic!("expected a discard, got {other:?}"),
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn truncated_or_corrupt_shards_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = written(Runner::new(GeneratorConfig::default(), SimConfig::default()).run(&JOB, dir.path()).unwrap());
    let bytes = std::fs::read(&path).unwrap();
    let bad = Path::new("/data/bad.mcap");
    for cut in [10, bytes.len() / 3, bytes.len() - 20] {
        let e = dynforge_shard::read_bytes(&bytes[..cut], bad).unwrap_err();
        // Said to be cut short (a recording killed before it closed the file), not a bad magic number.
        assert!(e.to_string().starts_with("/data/bad.mcap: an MCAP file cut short"), "{e}");
    }
    let mut flipped = bytes.clone();
    let mid = bytes.len() / 2;
    flipped[mid] ^= 0xff;
    assert!(dynforge_shard::read_bytes(&flipped, bad).is_err(), "a flipped byte inside a chunk fails its CRC");
}

#[test]
fn official_mcap_readers_decode_the_shard() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let mut runner = Runner::new(GeneratorConfig::default(), SimConfig::default());
    let sim = runner.simulate(&JOB).unwrap();
    let (robot, (_, rec)) = (sim.robot, sim.result.unwrap());
    let path = written(runner.run(&JOB, dir.path()).unwrap());
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/reference/read_shard.py");
    let out = dynforge_testkit::run_python(&py, &script, &[path.to_str().unwrap()], "");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["profile"], "ros2");
    assert_eq!(v["message_count"], rec.len() + 1);
    assert_eq!(v["compression"], serde_json::json!(["zstd"]));
    let schemas: Vec<(String, String)> = serde_json::from_value(v["schemas"].clone()).unwrap();
    assert!(schemas.contains(&("sensor_msgs/msg/JointState".into(), "ros2msg".into())));
    assert!(schemas.contains(&("std_msgs/msg/String".into(), "ros2msg".into())));
    assert_eq!(v["robot_description"].as_str().unwrap(), robot.urdf());
    let js = v["joint_states"].as_array().unwrap();
    assert_eq!(js.len(), rec.len());
    for k in [0, 1, rec.len() / 2, rec.len() - 1] {
        let m = &js[k];
        let f = |key: &str| -> Vec<f64> { m[key].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect() };
        assert_eq!(f("position"), rec.q[k]);
        assert_eq!(f("velocity"), rec.qd[k]);
        assert_eq!(f("effort"), rec.tau[k]);
        assert_eq!(m["log_time"].as_u64().unwrap(), k as u64 * 1_000_000);
        assert_eq!(m["stamp"], serde_json::json!([k / 1000, (k % 1000) * 1_000_000]));
    }
    assert_eq!(v["metadata"][META_LABELS].as_object().unwrap().len(), 38);
}
