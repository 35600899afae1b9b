//! End-to-end tests of `dynforge simulate`, spawning the real binary.

mod common;

use common::dynforge;

#[test]
fn simulate_writes_a_readable_shard_and_reports_what_it_did() {
    let dir = tempfile::tempdir().unwrap();
    let out = dynforge(&[
        "simulate",
        "--seed",
        "1",
        "--robot",
        "7",
        "--trajectory",
        "3",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let shard = dir.path().join("r000007-t03-native.mcap");
    assert!(text.contains(shard.to_str().unwrap()), "{text}");
    let bag = dynforge_shard::read(&shard).unwrap();
    // The report's sample count is the shard's.
    assert!(text.contains(&format!("{} samples", bag.joint_states.len())), "{text}");
    assert!(bag.joint_states.len() as f64 >= 4096.0 + 1000.0, "at least one 64 x 64 ms window plus offsets");

    // `info` describes it, also as a rosbag2 directory (metadata.yaml beside the .mcap).
    let bag_dir = dir.path().join("rosbag2");
    std::fs::create_dir(&bag_dir).unwrap();
    std::fs::copy(&shard, bag_dir.join("rosbag2_0.mcap")).unwrap();
    std::fs::write(bag_dir.join("metadata.yaml"), "rosbag2_bagfile_information: {}\n").unwrap();
    let labels = dynforge_recording::read(&shard, None).unwrap().labels.unwrap();
    for log in [&shard, &bag_dir] {
        let info = dynforge(&["info", log.to_str().unwrap()]);
        assert!(info.status.success(), "{}", String::from_utf8_lossy(&info.stderr));
        let text = String::from_utf8(info.stdout).unwrap();
        let n = bag.joint_states.len();
        assert!(text.contains(&format!("/joint_states: {n} messages, 1000.0 Hz mean")), "{text}");
        assert!(text.contains(&format!("Duration:    {:.3} s", (n - 1) as f64 * 1e-3)), "{text}");
        assert!(text.contains("Robot:       df6_s1_r7 (6 moving joints"), "{text}");
        assert!(text.contains("robot 7, seed 1") && text.contains("trajectory 3"), "{text}");
        assert!(text.contains(&format!("mass_l2 {:.5}", labels[dynforge_proto::labels::index_of("mass_l2").unwrap()])));
    }
}

#[test]
fn simulate_rejects_bad_arguments_with_clear_messages() {
    let dir = tempfile::tempdir().unwrap();
    let out = dynforge(&["simulate", "--trajectory", "16", "--out", dir.path().to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--trajectory 16 is out of range"));
    let file = dir.path().join("file");
    std::fs::write(&file, "x").unwrap();
    let out = dynforge(&["simulate", "--out", file.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains(file.to_str().unwrap()));
}

#[test]
fn dataset_stats_reports_the_shards_of_a_directory() {
    let dir = tempfile::tempdir().unwrap();
    let out = dynforge(&[
        "simulate",
        "--seed",
        "2",
        "--robot",
        "1",
        "--trajectory",
        "0",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert!(out.status.success());
    let out = dynforge(&["dataset", "stats", dir.path().to_str().unwrap(), "--window", "64:64:16"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("1 robots, 1 trajectories"), "{text}");
    assert!(text.contains("64 x  64, ssr  16:  4.096 s,  6.25 %"), "{text}");
    assert!(text.contains("mass_l2"), "{text}");
    let bad = dynforge(&["dataset", "stats", dir.path().to_str().unwrap(), "--window", "64:0:16"]);
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("LEN:STRIDE:SSR"));

    // One shard by its file name is a dataset of one trajectory.
    let shard = std::fs::read_dir(dir.path()).unwrap().next().unwrap().unwrap().path();
    let out = dynforge(&["dataset", "stats", shard.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("1 robots, 1 trajectories"), "{text}");
}

#[test]
fn dataset_stats_refuses_a_directory_without_readable_shards_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let stats = |d: &std::path::Path| dynforge(&["dataset", "stats", d.to_str().unwrap()]);
    let o = stats(dir.path());
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.code() == Some(1) && err.contains("holds no .mcap file"), "{err}");
    assert!(err.contains(dir.path().to_str().unwrap()), "{err}");
    std::fs::write(dir.path().join("a.mcap"), b"junk").unwrap();
    let o = stats(dir.path());
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.code() == Some(1) && err.contains("none of its 1 .mcap files is readable"), "{err}");
    assert!(err.contains("a.mcap"), "{err}");
}
