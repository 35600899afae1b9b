//! A ROS 2-style bag written by an independent writer (the official Python `mcap` + `mcap-ros2-support`), with
//! irregular timestamps, shuffled joint order and an extra joint, gives the same windows as our regular shard of
//! the same motion. Needs the reference venv (see `dynforge_testkit::reference_python`).

#[path = "../../dataset/tests/common/mod.rs"]
mod common;

use common::write_shard;
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::window::WindowSpec;
use dynforge_dataset::windows::windows;
use dynforge_proto::job::Job;
use dynforge_proto::shard::JOINT_STATE_DEFINITION;
use dynforge_recording::read;
use dynforge_robot::rng::Rng;
use serde_json::json;

#[test]
fn an_irregular_shuffled_ros2_bag_gives_the_windows_of_the_regular_recording() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (shard, _) = write_shard(&Job { seed: 8, robot: 2, trajectory: 1 }, dir.path());
    let bag = dynforge_shard::read(&shard).unwrap();
    let urdf = bag.robot_description.clone().unwrap();

    // The same motion as a logger with jitter would record it: every 1 kHz sample, plus extra samples at irregular
    // times between them (values on the straight line between the neighbours, which is what linear resampling
    // assumes), each message with the joints in a shuffled order and a gripper joint the robot does not have.
    let mut rng = Rng::stream(99, &[]);
    let mut messages = Vec::new();
    let states = &bag.joint_states;
    for k in 0..states.len() {
        let mut stamps = vec![(states[k].stamp_ns(), 0.0)];
        if k + 1 < states.len() && rng.unit() < 0.3 {
            let w = rng.uniform(0.05, 0.95);
            stamps.push((states[k].stamp_ns() + (w * 1e6).round() as i64, (w * 1e6).round() / 1e6));
        }
        for (t_ns, w) in stamps {
            let lerp = |a: &[f64], b: &[f64], j: usize| a[j] + w * (b[j] - a[j]);
            let next = &states[(k + 1).min(states.len() - 1)];
            let mut order: Vec<usize> = (0..6).collect();
            for i in (1..6).rev() {
                order.swap(i, rng.below(i + 1));
            }
            let mut name: Vec<String> = order.iter().map(|&j| states[k].name[j].clone()).collect();
            let pick = |a: &[f64], b: &[f64]| order.iter().map(|&j| lerp(a, b, j)).collect::<Vec<f64>>();
            let (mut position, mut velocity, mut effort) = (
                pick(&states[k].position, &next.position),
                pick(&states[k].velocity, &next.velocity),
                pick(&states[k].effort, &next.effort),
            );
            name.insert(2, "gripper_finger".into());
            position.insert(2, 0.01);
            velocity.insert(2, 0.0);
            effort.insert(2, 5.0);
            messages.push(
                json!({"t_ns": t_ns, "name": name, "position": position, "velocity": velocity, "effort": effort}),
            );
        }
    }
    // Shuffle the message order too: a bag is not guaranteed to be sorted by header stamp.
    for i in (1..messages.len()).rev() {
        messages.swap(i, rng.below(i + 1));
    }
    let bag_path = dir.path().join("robot_log.mcap");
    let request =
        json!({"path": bag_path, "joint_state_schema": JOINT_STATE_DEFINITION, "urdf": urdf, "messages": messages});
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/reference/write_bag.py");
    dynforge_testkit::run_python(&py, &script, &[], &request.to_string());

    let regular = read(&shard, None).unwrap();
    let logged = read(&bag_path, None).unwrap();
    assert_eq!(logged.model, regular.model);
    assert!(logged.labels.is_none(), "a robot's own log has no labels");
    assert_eq!(logged.trajectory.len(), regular.trajectory.len());
    let spec = WindowSpec::default();
    let features = JacobianFeatures::new(&regular.model);
    let (n_regular, w_regular) = windows(&regular, &spec, &features);
    let (n_logged, w_logged) = windows(&logged, &spec, &features);
    assert_eq!(n_logged, n_regular);
    // Resampling the 1 kHz stamps back onto the grid reproduces them to rounding; as f32 that is equality up to
    // one unit in the last place.
    for (i, (a, b)) in w_logged.iter().zip(&w_regular).enumerate() {
        assert!((a - b).abs() <= 2.0 * f32::EPSILON * b.abs().max(1e-3), "value {i}: {a} vs {b}");
    }
}
