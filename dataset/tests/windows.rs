//! The data pipeline on real shards written by the worker.

mod common;

use common::write_shard;
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::window::WindowSpec;
use dynforge_dataset::windows::{row_width, stats, windows};
use dynforge_proto::job::Job;
use dynforge_recording::read;
use dynforge_robot::Data;
use dynforge_robot::parameters::labels_of;

#[test]
fn a_shard_becomes_windows_of_state_torque_and_jacobian_features() {
    let dir = tempfile::tempdir().unwrap();
    let (path, robot) = write_shard(&Job { seed: 6, robot: 3, trajectory: 2 }, dir.path());
    let p = read(&path, None).unwrap();
    assert_eq!(p.model, robot.model, "the robot comes from /robot_description");
    assert_eq!(p.labels.unwrap(), labels_of(&robot.model).unwrap());
    assert_eq!(p.robot, Some(3));
    let bag = dynforge_shard::read(&path).unwrap();
    assert_eq!(p.trajectory.len(), bag.joint_states.len(), "a 1 kHz shard is already on the grid");

    let spec = WindowSpec::default();
    let features = JacobianFeatures::new(&p.model);
    let width = row_width(&p.model, &features);
    assert_eq!(width, 18 + features.len());
    let (count, data) = windows(&p, &spec, &features);
    assert_eq!(count, spec.windows(p.trajectory.len()).len());
    assert!(count >= 1, "a >= 6 s trajectory holds at least one 4.096 s window");
    assert_eq!(data.len(), count * spec.len * width);
    // Window 0, step 5 is source sample 5 * 64: its state, torque and features, as f32.
    let row = &data[5 * width..6 * width];
    let m = &bag.joint_states[5 * 64];
    for j in 0..6 {
        assert_eq!(row[j], m.position[j] as f32);
        assert_eq!(row[6 + j], m.velocity[j] as f32);
        assert_eq!(row[12 + j], m.effort[j] as f32);
    }
    let mut jac = Vec::new();
    features.evaluate(&p.model, &mut Data::new(&p.model), &m.position, &mut jac);
    assert_eq!(&row[18..], jac.iter().map(|v| *v as f32).collect::<Vec<_>>().as_slice());

    let (other, overlapping) = (WindowSpec::new(32, 32, 8), spec.with_hop(spec.len / 2));
    let s = stats(dir.path(), &[spec, other, overlapping]).unwrap();
    assert_eq!((s.shards, s.robots), (1, 1));
    assert!((s.hours - p.trajectory.len() as f64 / 3.6e6).abs() < 1e-12);
    assert_eq!(s.windows[&spec], count);
    assert_eq!(s.windows[&other], other.windows(p.trajectory.len()).len());
    // Counted apart from the back-to-back windows of the same length, stride and SSR.
    assert_eq!(s.windows[&overlapping], overlapping.windows(p.trajectory.len()).len());
    assert!(s.windows[&overlapping] >= count);
    assert_eq!(s.label_ranges[12], (p.labels.unwrap()[12], p.labels.unwrap()[12]));

    // A corrupt file among the shards is skipped with its name, not fatal.
    std::fs::write(dir.path().join("broken.mcap"), b"not an mcap").unwrap();
    let s = stats(dir.path(), &[spec]).unwrap();
    assert_eq!(s.shards, 1);
    assert!(s.skipped.len() == 1 && s.skipped[0].contains("broken.mcap"), "{:?}", s.skipped);
}
