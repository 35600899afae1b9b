//! End to end through the real binary: generate a small dataset, train a small model, evaluate it, estimate a
//! recording's parameters into a URDF the robot crate loads, and refuse bad inputs clearly.

mod common;

use common::dynforge;
use dynforge_evaluation::spread::{LEAST, MIN_ROBOTS, UNTOLD};
use dynforge_proto::manifest::Manifest;
use std::path::Path;

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn ok(o: std::process::Output) -> String {
    assert!(o.status.success(), "stdout:\n{}\nstderr:\n{}", String::from_utf8_lossy(&o.stdout), stderr(&o));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

const SMALL: [&str; 16] = [
    "--model",
    "transformer",
    "--preset",
    "fast",
    "--layers",
    "1",
    "--heads",
    "2",
    "--dim",
    "16",
    "--epochs",
    "2",
    "--batch",
    "16",
    "--validation",
    "0.5",
];

/// `dynforge evaluate RUN` with `flags`, which must succeed; its standard output.
fn evaluate(run: &Path, flags: &[&str]) -> String {
    ok(dynforge(&[&["evaluate", run.to_str().unwrap()][..], flags].concat()))
}

fn first_shard(data: &Path) -> std::path::PathBuf {
    let mut v: Vec<_> = std::fs::read_dir(data.join("shards")).unwrap().map(|e| e.unwrap().path()).collect();
    v.sort();
    v.remove(0)
}

#[test]
fn train_evaluate_and_estimate_a_small_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let run = dir.path().join("run");
    let d = data.to_str().unwrap();
    ok(dynforge(&["generate", "--out", d, "--robots", "4", "--trajectories", "2", "--workers", "2", "--seed", "5"]));
    let mut args = vec!["train", d, "--out", run.to_str().unwrap()];
    args.extend(SMALL);
    ok(dynforge(&args));
    for f in ["checkpoint.json", "model.safetensors", "metrics.csv", "metrics.json", "train/state.json"] {
        assert!(run.join(f).is_file(), "{f} missing");
    }
    // A second `train` into the same checkpoint is refused unless it resumes.
    let again = dynforge(&args);
    assert!(!again.status.success() && stderr(&again).contains("--resume"), "{}", stderr(&again));
    // A batch cannot be split into no parts, or more parts than windows; nothing is written.
    let elsewhere = dir.path().join("elsewhere");
    for parts in ["0", "17"] {
        let mut bad = vec!["train", d, "--out", elsewhere.to_str().unwrap(), "--micro-batches", parts];
        bad.extend(SMALL);
        let o = dynforge(&bad);
        let said = stderr(&o);
        let named = said.contains(&format!("--micro-batches {parts}"))
            || said.contains(&format!("invalid value '{parts}' for '--micro-batches <MICRO_BATCHES>'"));
        assert!(!o.status.success() && named, "{said}");
        assert!(!elsewhere.exists());
    }

    let out = evaluate(&run, &["--torque-recordings", "2", "--identify-robots", "2", "--spread-robots", "0"]);
    for needle in [
        "Friction per joint",
        "Mass and centre of mass per link",
        "Inertia per link",
        "Overall",
        "Torque check",
        "Identification",
    ] {
        assert!(out.contains(needle), "{needle} missing from\n{out}");
    }
    for png in ["predicted_vs_true.png", "learning_curves.png"] {
        let bytes = std::fs::read(run.join(png)).unwrap();
        assert!(bytes.starts_with(b"\x89PNG") && bytes.len() > 1000, "{png}");
    }
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["windows"]["targets"].as_array().unwrap().len(), 38);
    // The true parameters predict the recorded torques far better than any small-data estimate can be expected
    // to be wrong: the check discriminates.
    let overall = |rows: &serde_json::Value, name: &str| {
        let row = rows.as_array().unwrap().iter().find(|r| r["parameters"] == name).unwrap();
        row["overall"].as_f64().unwrap()
    };
    let t = &report["torque"]["rows"];
    assert!(overall(t, "true") < overall(t, "training mean"), "{t}");
    // Identification on the validation robot(s) (one recording to identify from, one to predict, each). The
    // physics estimates predict the held-out torques to within an order of the noise floor the refinement assumes
    // (1e-3 of the torque RMS, which exceeds a joint's torque spread by up to ~10x when it holds against gravity);
    // the training mean and the network are off by tens of percent.
    let id = &report["identification"];
    assert!(id["robots"].as_u64().unwrap() >= 1, "{id}");
    let rows = &id["torque"];
    for name in ["physics, training prior", "hybrid"] {
        assert!(overall(rows, name) < 1e-2 && overall(rows, name) < overall(rows, "training mean") / 10.0, "{rows}");
    }
    // Friction enters the regressor through columns of its own (sign(qd), qd of one joint): the hybrid's friction
    // error is a small fraction of the network's.
    let friction_rmse = |s: &serde_json::Value| (0..12).map(|k| s["targets"][k]["rmse"].as_f64().unwrap()).sum::<f64>();
    assert!(friction_rmse(&id["hybrid"]) < 0.1 * friction_rmse(&id["network"]), "{id}");

    let shard = first_shard(&data);
    let urdf = dir.path().join("estimated.urdf");
    let out = ok(dynforge(&[
        "estimate",
        "--checkpoint",
        run.to_str().unwrap(),
        shard.to_str().unwrap(),
        "--out",
        urdf.to_str().unwrap(),
        "--json",
    ]));
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["parameters"].as_object().unwrap().len(), 38);
    // Written into the log's own description: the base keeps its visual (the model alone has none to write).
    let written = std::fs::read_to_string(&urdf).unwrap();
    let base = &written[written.find("<link name=\"base_link\">").unwrap()..];
    assert!(base[..base.find("</link>").unwrap()].contains("<visual>"), "{written}");
    // Refined by physics: the log's own torques are explained far better than by the network alone.
    let r = &v["refinement"];
    let (refined, network) =
        (r["torque_nrmse_refined"].as_f64().unwrap(), r["torque_nrmse_estimator"].as_f64().unwrap());
    assert!(refined < 1e-2 && refined < network, "{r}");
    let plain = ok(dynforge(&[
        "estimate",
        "--checkpoint",
        run.to_str().unwrap(),
        shard.to_str().unwrap(),
        "--out",
        dir.path().join("plain.urdf").to_str().unwrap(),
        "--json",
        "--no-refine",
    ]));
    let plain: serde_json::Value = serde_json::from_str(&plain).unwrap();
    assert!(plain["refinement"].is_null());
    for l in dynforge_proto::LABELS.iter() {
        let p = &plain["parameters"][l.name];
        let projected = plain["projections"].as_array().unwrap().iter().any(|n| n.as_str().unwrap().contains(l.name));
        // Unprojected values pass through the URDF's inertia about the joint frame and back: equal to rounding.
        let (value, estimator) = (p["value"].as_f64().unwrap(), p["estimator"].as_f64().unwrap());
        assert!(projected || (value - estimator).abs() <= 1e-9 * estimator.abs().max(1e-9), "{}: {p}", l.name);
        assert_eq!(p["estimator"], v["parameters"][l.name]["estimator"], "{}", l.name);
    }
    let model = dynforge_robot::urdf::load(&urdf).unwrap();
    let y = dynforge_robot::parameters::labels_of(&model).unwrap();
    for (k, l) in dynforge_proto::LABELS.iter().enumerate() {
        let est = v["parameters"][l.name]["value"].as_f64().unwrap();
        let projected = v["projections"].as_array().unwrap().iter().any(|p| p.as_str().unwrap().contains(l.name));
        assert!(
            projected || (y[k] - est).abs() <= 1e-9 * est.abs().max(1e-9),
            "{}: URDF {} vs estimate {est}",
            l.name,
            y[k]
        );
    }

    // Bad inputs: a checkpoint for another feature set, a bag without /joint_states, joints of other names.
    let mut ck: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("checkpoint.json")).unwrap()).unwrap();
    ck["features"].as_array_mut().unwrap()[0] = "J_other".into();
    let other = dir.path().join("other");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("checkpoint.json"), serde_json::to_vec(&ck).unwrap()).unwrap();
    std::fs::copy(run.join("model.safetensors"), other.join("model.safetensors")).unwrap();
    let o = dynforge(&["estimate", "--checkpoint", other.to_str().unwrap(), shard.to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("Jacobian features"), "{}", stderr(&o));

    let empty = dir.path().join("empty.mcap");
    let robot = std::fs::read_to_string(&urdf).unwrap();
    let metadata = dynforge_shard::Metadata::new();
    dynforge_shard::write(
        &empty,
        &dynforge_shard::ShardContent { urdf: &robot, joint_states: &[], metadata: &metadata },
    )
    .unwrap();
    let o = dynforge(&["estimate", "--checkpoint", run.to_str().unwrap(), empty.to_str().unwrap()]);
    assert!(
        !o.status.success() && stderr(&o).contains("empty.mcap") && stderr(&o).contains("/joint_states"),
        "{}",
        stderr(&o)
    );

    // A robot that holds still: its torques cannot refine anything, so the network's estimate stands, with a
    // warning, and is still written.
    let names: Vec<String> = model.joints().iter().map(|j| j.name.clone()).collect();
    let still: Vec<dynforge_proto::shard::JointState> = (0..6000u32)
        .map(|i| dynforge_proto::shard::JointState {
            sec: (i / 1000) as i32,
            nanosec: (i % 1000) * 1_000_000,
            frame_id: String::new(),
            name: names.as_slice().into(),
            position: vec![0.3; 6],
            velocity: vec![0.0; 6],
            effort: vec![1.0; 6],
        })
        .collect();
    let held = dir.path().join("still.mcap");
    dynforge_shard::write(
        &held,
        &dynforge_shard::ShardContent { urdf: &robot, joint_states: &still, metadata: &metadata },
    )
    .unwrap();
    let o = dynforge(&["estimate", "--checkpoint", run.to_str().unwrap(), held.to_str().unwrap(), "--json"]);
    assert!(o.status.success() && stderr(&o).contains("not refined by physics"), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["refinement"].is_null() && dir.path().join("still.estimated.urdf").is_file(), "{v}");

    let renamed = dir.path().join("renamed.urdf");
    std::fs::write(&renamed, robot.replace("\"joint_1\"", "\"shoulder\"")).unwrap();
    let o = dynforge(&[
        "estimate",
        "--checkpoint",
        run.to_str().unwrap(),
        shard.to_str().unwrap(),
        "--urdf",
        renamed.to_str().unwrap(),
    ]);
    assert!(!o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("shoulder") || stderr(&o).contains("joint"), "{}", stderr(&o));

    // A checkpoint directory that is not one.
    let o = dynforge(&["estimate", "--checkpoint", dir.path().to_str().unwrap(), shard.to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("not a checkpoint"), "{}", stderr(&o));
}

#[test]
fn sweep_runs_both_grids_and_names_the_configurations_a_dataset_cannot_serve() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let out = dir.path().join("sweep");
    let d = data.to_str().unwrap();
    ok(dynforge(&["generate", "--out", d, "--robots", "4", "--trajectories", "2", "--workers", "2", "--seed", "5"]));
    let mut args = vec!["sweep", d, "--out", out.to_str().unwrap()];
    args.extend(SMALL);
    let epochs = args.iter().position(|a| *a == "--epochs").unwrap() + 1;
    args[epochs] = "1";
    let read =
        || -> serde_json::Value { serde_json::from_slice(&std::fs::read(out.join("sweep.json")).unwrap()).unwrap() };
    let printed = ok(dynforge(&args));
    let first = read();
    let (dataset, arch) = (first["dataset"].as_array().unwrap(), first["architecture"].as_array().unwrap());
    assert_eq!((dataset.len(), arch.len()), (16, 4), "every configuration of both grids has a row");
    let mut ran = 0;
    for row in dataset.iter().chain(arch) {
        match row["skipped"].as_str() {
            // Trajectories last 6-8 s: a window spanning 128 x 64 ms may find none in a split. That is a row
            // with the reason, not the end of the sweep.
            Some(reason) => assert!(reason.contains("windows"), "{row}"),
            None => {
                ran += 1;
                assert!(row["windows"].as_u64().unwrap() > 0 && row["rmse"].as_f64().unwrap().is_finite(), "{row}");
            }
        }
    }
    assert!(ran >= 16, "only {ran} configurations ran");
    assert_eq!(
        printed
            .lines()
            .filter(|l| l.starts_with("| ") && !l.starts_with("| Seq") && !l.starts_with("| Layers"))
            .count(),
        20
    );
    // Rerunning resumes: every finished configuration is kept, and the scores are the same.
    ok(dynforge(&args));
    let again = read();
    for grid in ["dataset", "architecture"] {
        let scores = |v: &serde_json::Value| -> Vec<String> {
            v[grid].as_array().unwrap().iter().map(|r| format!("{} {} {}", r["name"], r["rmse"], r["r2"])).collect()
        };
        assert_eq!(scores(&first), scores(&again), "{grid}");
    }
}

#[test]
fn the_physics_estimator_trains_evaluates_and_estimates_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let run = dir.path().join("run");
    let d = data.to_str().unwrap();
    ok(dynforge(&["generate", "--out", d, "--robots", "6", "--trajectories", "3", "--workers", "2", "--seed", "7"]));
    let small = ["--epochs", "2", "--generated", "4096", "--dim", "64", "--validation", "0.34"];
    let mut args = vec!["train", d, "--out", run.to_str().unwrap()];
    args.extend(small);
    ok(dynforge(&args));
    let ck: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("checkpoint.json")).unwrap()).unwrap();
    assert_eq!(ck["model"]["kind"], "physics", "the default estimator");
    // The generator's prior: 72 parameters, 30 directions.
    assert_eq!(ck["prior"]["mean"].as_array().unwrap().len(), 72);
    assert_eq!(ck["prior"]["factor"].as_array().unwrap().len(), 72 * 30);
    assert_eq!(ck["examples"], serde_json::json!({"generated_per_epoch": 4096, "real": true, "noisy": false}));
    // A resume may change what it trains on, and says so (the checkpoint records the examples when it is saved).
    let mut more = vec!["train", d, "--out", run.to_str().unwrap(), "--resume", "--generated-only"];
    more.extend(["--epochs", "3", "--generated", "2048", "--dim", "64", "--validation", "0.34"]);
    let o = dynforge(&more);
    assert!(o.status.success(), "{}", stderr(&o));
    let said = stderr(&o);
    assert!(
        said.contains(
            "examples changed: generated robots per epoch 4096 -> 2048, real examples trained on -> left out"
        ) && said.contains("0 real training examples"),
        "{said}"
    );
    let epochs = std::fs::read_to_string(run.join("metrics.csv")).unwrap().lines().count() - 1;
    assert_eq!(epochs, 3, "the resumed run trained its third epoch");

    let out = evaluate(&run, &["--torque-recordings", "3", "--identify-robots", "2", "--spread-from", "validation"]);
    assert!(out.contains("Overall") && out.contains("Per robot") && out.contains("Identification"), "{out}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["windows"]["targets"].as_array().unwrap().len(), 38);

    // A validation robot's recording: the estimate, refined by its torques, carries the true friction (friction
    // has regressor columns of its own) and is what the URDF gets.
    let validation_shard = std::fs::read_dir(data.join("shards"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| {
            let r = dynforge_proto::shard::robot_of_file_name(p.file_name().unwrap().to_str().unwrap()).unwrap();
            let (seed, fraction) = (0, 0.34);
            dynforge_dataset::split::split_of(seed, r, fraction) == dynforge_dataset::split::Split::Validation
        })
        .expect("a validation robot");
    let urdf = dir.path().join("estimated.urdf");
    let out = ok(dynforge(&[
        "estimate",
        "--checkpoint",
        run.to_str().unwrap(),
        validation_shard.to_str().unwrap(),
        "--out",
        urdf.to_str().unwrap(),
        "--json",
    ]));
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    // A simulated log's residual is far under the noise floor: its evidence is weighted as in training.
    let noise: Vec<f64> = v["torque_noise"].as_array().unwrap().iter().map(|n| n.as_f64().unwrap()).collect();
    assert!(noise.len() == 6 && noise.iter().all(|&n| n < 1e-4), "{noise:?}");
    let refined = v["refinement"]["torque_nrmse_refined"].as_f64().unwrap();
    assert!(refined < 1e-2, "{v}");
    let truth = dynforge_recording::read(&validation_shard, None).unwrap().labels.unwrap();
    let model = dynforge_robot::urdf::load(&urdf).unwrap();
    let written = dynforge_robot::parameters::labels_of(&model).unwrap();
    let mut friction_errors = Vec::new();
    for (k, l) in dynforge_proto::LABELS.iter().enumerate() {
        let value = v["parameters"][l.name]["value"].as_f64().unwrap();
        assert_eq!(value, written[k], "{}: reported values are the URDF's", l.name);
        if matches!(l.kind, dynforge_proto::LabelKind::Coulomb | dynforge_proto::LabelKind::Viscous) {
            friction_errors.push((value - truth[k]).abs() / truth[k]);
        }
    }
    friction_errors.sort_by(f64::total_cmp);
    assert!(friction_errors[6] < 0.02, "median relative friction error {friction_errors:?}");
    // Each value carries its standard deviation, never above the estimator's: friction, which the log's torques
    // decide, to under 1 % of its value.
    for l in dynforge_proto::LABELS.iter() {
        let p = &v["parameters"][l.name];
        let (spread, prior) = (p["spread"].as_f64().unwrap(), p["estimator_spread"].as_f64().unwrap());
        assert!(spread > 0.0 && spread.is_finite() && spread <= prior * (1.0 + 1e-9), "{}: {p}", l.name);
        if matches!(l.kind, dynforge_proto::LabelKind::Coulomb | dynforge_proto::LabelKind::Viscous) {
            assert!(p["decided"] == "log" && spread < 0.01 * p["value"].as_f64().unwrap(), "{}: {p}", l.name);
        }
    }

    // The calibration `evaluate` measures on validation robots (too few here: none). With one, the estimator's
    // spread is the evidence's deviation from the estimate (a simulated log: of the posterior its residual supports), scaled
    // with the floor in quadrature; the refined spread the refinement's posterior likewise; each at the
    // calibration for this many logs (one: the one-log calibrations). The refined spread of a noisy log, or with a
    // calibration written before noisy validation logs were measured (no noisy part), is never under the
    // estimator's.
    assert!(report["spread_calibration"].is_null(), "measured on {} robots", report["robots"]["count"]);
    let estimator_floors: Vec<f64> = (0..38).map(|k| 1e-3 * (1 + k) as f64).collect();
    let calibration = |scale: f64, floor: &[f64]| serde_json::json!({"scale": vec![scale; 38], "floor": floor});
    // The part for a log with effort noise would widen tenfold: this log is at its noise floor, so it is not used.
    let with_noisy = |mut c: serde_json::Value| {
        let mut noisy = calibration(10.0, &[1.0; 38]);
        noisy["noise"] = serde_json::json!(0.01);
        c["noisy"] = serde_json::json!([noisy]);
        c
    };
    let with_calibration = |refined: &[f64], log: &Path, noisy: bool| -> serde_json::Value {
        let mut fitted = report.clone();
        let at = |logs: usize, estimator: serde_json::Value, refined: serde_json::Value| serde_json::json!({"logs": logs, "robots": 9, "estimator": estimator, "refined": refined, "coverage": []});
        let part = |c: serde_json::Value| if noisy { with_noisy(c) } else { c };
        fitted["spread_calibration"] = serde_json::json!({"robots": 9, "counts": [
            at(1, part(calibration(0.5, &estimator_floors)), part(calibration(1.0, refined))),
            at(4, calibration(1.0, &[1.0; 38]), calibration(1.0, &[1.0; 38])),
        ]});
        std::fs::write(run.join("report.json"), serde_json::to_vec(&fitted).unwrap()).unwrap();
        let out = ok(dynforge(&["estimate", "--checkpoint", run.to_str().unwrap(), log.to_str().unwrap(), "--json"]));
        serde_json::from_str(&out).unwrap()
    };
    let refined_floors: Vec<f64> = (0..38).map(|k| 1e-4 * (1 + k) as f64).collect();
    let (bare, widened) = (
        with_calibration(&[0.0; 38], &validation_shard, true),
        with_calibration(&refined_floors, &validation_shard, true),
    );
    let before_noisy = with_calibration(&refined_floors, &validation_shard, false);
    assert_eq!(widened["refinement"]["calibration_robots"], 9);
    assert!(bare["noise_level"].is_null(), "a simulated log is at its noise floor: {}", bare["noise_level"]);
    // A spread is never over the family's nor under a millionth of it; a label whose evidence leaves 0.4 of the
    // family's spread or more gets the family's.
    let bounded = |s: f64, family: f64| s.min(family).max(LEAST * family);
    let estimator_spread = |evidence: f64, family: f64, scaled: f64| match evidence >= UNTOLD * family {
        true => family,
        false => scaled.max(LEAST * family),
    };
    for (k, l) in dynforge_proto::LABELS.iter().enumerate() {
        let (before, after) = (&bare["parameters"][l.name], &widened["parameters"][l.name]);
        let evidence = before["evidence_spread"].as_f64().unwrap();
        let estimator = before["estimator_spread"].as_f64().unwrap();
        let family = before["family_spread"].as_f64().unwrap();
        let deviation = before["posterior_deviation"].as_f64().unwrap();
        assert!(deviation > 0.0 && deviation.is_finite(), "{}: {before}", l.name);
        let scaled = (0.5 * deviation).hypot(estimator_floors[k]);
        assert_eq!(estimator, estimator_spread(evidence, family, scaled), "{}: {before}", l.name);
        assert_eq!(before["value"], after["value"], "{}: the refinement's floor changes no value", l.name);
        let posterior = before["refined_posterior"].as_f64().unwrap();
        assert_eq!(after["refined_posterior"].as_f64().unwrap(), posterior, "{}", l.name);
        for (v, floor) in [(before, 0.0), (after, refined_floors[k])] {
            assert_eq!(v["spread"].as_f64().unwrap(), bounded(posterior.hypot(floor), family), "{}: {v}", l.name);
        }
        let old = &before_noisy["parameters"][l.name];
        let want = bounded(posterior.hypot(refined_floors[k]).max(estimator), family);
        assert_eq!(old["spread"].as_f64().unwrap(), want, "{}: {old}", l.name);
    }
    // The same log with effort noise of 1 % of each joint's torque RMS, as a bag: its posterior is its measured
    // noise's, and takes the noisy part (ten times its deviation, with that part's floor), refined likewise (ten times
    // the posterior) and never under the estimator's.
    let mut rec = dynforge_recording::read(&validation_shard, None).unwrap();
    let mut rng = dynforge_robot::rng::Rng::stream(7, &[]);
    dynforge_evaluation::spread::add_effort_noise(&mut rec, 0.01, &mut rng);
    let noisy_bag = dir.path().join("noisy.mcap");
    let urdf_text = dynforge_robot::urdf::to_string(&rec.model, &Default::default());
    dynforge_testkit::write_bag(&noisy_bag, &urdf_text, &rec.trajectory);
    let noisy = with_calibration(&refined_floors, &noisy_bag, true);
    assert!(noisy["noise_level"].as_f64().unwrap() > 1e-3, "{}", noisy["noise_level"]);
    for l in dynforge_proto::LABELS.iter() {
        let v = &noisy["parameters"][l.name];
        let estimator = v["estimator_spread"].as_f64().unwrap();
        let (evidence, family) = (v["evidence_spread"].as_f64().unwrap(), v["family_spread"].as_f64().unwrap());
        let scaled = (10.0 * v["posterior_deviation"].as_f64().unwrap()).hypot(1.0);
        assert_eq!(estimator, estimator_spread(evidence, family, scaled), "{}: {v}", l.name);
        let refined = (10.0 * v["refined_posterior"].as_f64().unwrap()).hypot(1.0);
        assert_eq!(v["spread"].as_f64().unwrap(), bounded(refined.max(estimator), family), "{}: {v}", l.name);
    }
    // A calibration that does not read is said, and the spreads are the validation RMSE as without one.
    let mut broken = report.clone();
    broken["spread_calibration"] = serde_json::json!({"robots": "nine"});
    std::fs::write(run.join("report.json"), serde_json::to_vec(&broken).unwrap()).unwrap();
    let o =
        dynforge(&["estimate", "--checkpoint", run.to_str().unwrap(), validation_shard.to_str().unwrap(), "--json"]);
    let said = stderr(&o);
    assert!(o.status.success() && said.contains("report.json: spread_calibration does not read"), "{said}");
    let fallback: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(fallback["refinement"]["calibration_robots"].is_null(), "{}", fallback["refinement"]);
    std::fs::write(run.join("report.json"), serde_json::to_vec(&report).unwrap()).unwrap();

    // Robots drawn fresh from the training data's generator calibrate the spreads, however few robots the split
    // holds out (here 2): another seed of the same generator, generated into the checkpoint's directory.
    let flags = ["--torque-recordings", "0", "--identify-robots", "0", "--spread-robots", "36"];
    evaluate(&run, &[&flags[..], &["--spread-trajectories", "1"]].concat());
    let fresh = run.join("spread-robots");
    let (trained_on, drawn) = (Manifest::load(&data).unwrap().unwrap(), Manifest::load(&fresh).unwrap().unwrap());
    assert!(drawn.seed != trained_on.seed && drawn.generator == trained_on.generator && drawn.trajectories == 1);
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("report.json")).unwrap()).unwrap();
    let calibration = &report["spread_calibration"];
    let robots = calibration["robots"].as_u64().unwrap() as usize;
    assert!(calibration["fresh"] == true && (MIN_ROBOTS..=36).contains(&robots), "{calibration}");
    assert_eq!(calibration["counts"][0]["logs"], 1);
    // None of them is a training robot.
    let labels = |dir: &Path| -> Vec<[f64; 38]> {
        let by_robot = dynforge_recording::dataset::shards_by_robot(dir).unwrap();
        by_robot.values().map(|p| dynforge_recording::read(&p[0], None).unwrap().labels.unwrap()).collect()
    };
    let training = labels(&data);
    assert!(labels(&fresh).iter().all(|l| !training.contains(l)));
    let out = ok(dynforge(&["estimate", "--checkpoint", run.to_str().unwrap(), validation_shard.to_str().unwrap()]));
    assert!(out.contains(&format!("spreads calibrated on {robots} robots drawn fresh from the generator")), "{out}");

    // A robot of another family is refused with the way out: the same joint names, one joint placed 5 cm off.
    let rec = dynforge_recording::read(&validation_shard, None).unwrap();
    let mut joints = rec.model.joints().to_vec();
    joints[2].origin.xyz[2] += 0.05;
    let links = rec.model.links().to_vec();
    let other = dynforge_robot::Model::new("moved", rec.model.name(), rec.model.base(), joints, links).unwrap();
    let bag = dir.path().join("other_family.mcap");
    let urdf_text = dynforge_robot::urdf::to_string(&other, &Default::default());
    dynforge_testkit::write_bag(&bag, &urdf_text, &dynforge_testkit::sinusoid_recording(&other, 0, 1e-3, 4000));
    let o = dynforge(&["estimate", "--checkpoint", run.to_str().unwrap(), bag.to_str().unwrap()]);
    let said = stderr(&o);
    assert!(
        !o.status.success()
            && said.contains("not of the family")
            && said.contains("sits at")
            && said.contains("dynforge identify"),
        "{said}"
    );
    // Of the family's kinematics but with torques its dynamics cannot take (an offset of its RMS on one joint's effort,
    // which no mass or friction gives): refused by the posterior predictive check, with the same way out.
    let mut offset = dynforge_testkit::sinusoid_recording(&rec.model, 0, 1e-3, 8000);
    let n = offset.joints();
    let rms = (offset.tau.iter().skip(1).step_by(n).map(|t| t * t).sum::<f64>() / offset.len() as f64).sqrt();
    offset.tau.iter_mut().skip(1).step_by(n).for_each(|t| *t += rms);
    let bag = dir.path().join("offset.mcap");
    dynforge_testkit::write_bag(&bag, &dynforge_robot::urdf::to_string(&rec.model, &Default::default()), &offset);
    let o = dynforge(&["estimate", "--checkpoint", run.to_str().unwrap(), bag.to_str().unwrap()]);
    let said = stderr(&o);
    assert!(
        !o.status.success() && said.contains("unexplained") && said.contains("dynforge identify"),
        "{said}{}",
        String::from_utf8_lossy(&o.stdout)
    );
    // The written URDF loads in Pinocchio and MuJoCo (both refuse a body outside the triangle inequality), with
    // the masses the estimate gave.
    if let Some(python) = dynforge_testkit::reference_python() {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/reference/load_urdf.py");
        let out = dynforge_testkit::run_python(&python, &script, &[urdf.to_str().unwrap()], "");
        let loaded: serde_json::Value = serde_json::from_str(&out).unwrap();
        for tool in ["pinocchio", "mujoco"] {
            let masses: Vec<f64> = loaded[tool].as_array().unwrap().iter().map(|m| m.as_f64().unwrap()).collect();
            assert_eq!(masses.len(), 6, "{tool}: {loaded}");
            for link in 2..=6 {
                let k = dynforge_proto::LABELS.iter().position(|l| l.name == format!("mass_l{link}")).unwrap();
                assert!((masses[link - 1] - written[k]).abs() <= 1e-9 * written[k], "{tool} link {link}: {loaded}");
            }
        }
    }

    // What the physics estimator cannot do is refused with the reason: following a generation, a folder of shards
    // without the generator's manifest.
    let (f, g) = (dir.path().join("f"), dir.path().join("g"));
    let mut follow = vec!["train", d, "--out", f.to_str().unwrap(), "--follow"];
    follow.extend(small);
    let o = dynforge(&follow);
    assert!(!o.status.success() && stderr(&o).contains("--follow trains the transformer"), "{}", stderr(&o));
    let loose = dir.path().join("loose");
    std::fs::create_dir(&loose).unwrap();
    std::fs::copy(&validation_shard, loose.join(validation_shard.file_name().unwrap())).unwrap();
    let mut bare = vec!["train", loose.to_str().unwrap(), "--out", g.to_str().unwrap()];
    bare.extend(small);
    let o = dynforge(&bare);
    assert!(!o.status.success() && stderr(&o).contains("manifest"), "{}", stderr(&o));
}

/// `--split`: what validation holds out is what was asked, recorded in the checkpoint and named by the report; the
/// held-out recordings are the ones the rule picks from the shards' names; the checks that need unseen robots are
/// left out, and said to be, under a split that has none.
#[test]
fn the_split_holds_out_robots_trajectories_or_windows_as_asked() {
    use dynforge_dataset::split::{HoldOut, Origin, Split, SplitRule};
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let d = data.to_str().unwrap();
    ok(dynforge(&["generate", "--out", d, "--robots", "6", "--trajectories", "3", "--workers", "2", "--seed", "7"]));
    let shards: Vec<(u64, u32)> = std::fs::read_dir(data.join("shards"))
        .unwrap()
        .map(|e| {
            let name = e.unwrap().file_name().into_string().unwrap();
            let robot = dynforge_proto::shard::robot_of_file_name(&name).unwrap();
            (robot, name[9..11].parse().unwrap())
        })
        .collect();
    let mut validation_robots = Vec::new();
    // Last, windows that overlap (`--hop`): every window of a recording overlaps the next, so the recording is one
    // unit of the split by window.
    let runs = [
        (HoldOut::Robots, None),
        (HoldOut::Trajectories, None),
        (HoldOut::Windows, None),
        (HoldOut::Windows, Some(32)),
    ];
    for (by, hop) in runs {
        let run = dir.path().join(format!("{}{}", by.name(), hop.map_or(String::new(), |h| format!("-hop{h}"))));
        let mut args = vec!["train", d, "--out", run.to_str().unwrap(), "--split", by.name()];
        args.extend(["--epochs", "1", "--generated", "1024", "--dim", "32", "--validation", "0.34"]);
        let hop_flag = hop.map(|h: usize| h.to_string());
        if let Some(h) = &hop_flag {
            args.extend(["--hop", h]);
        }
        ok(dynforge(&args));
        let ck: serde_json::Value =
            serde_json::from_slice(&std::fs::read(run.join("checkpoint.json")).unwrap()).unwrap();
        assert_eq!(ck["held_out"], by.name());
        assert_eq!(ck["window_hop"], hop.map_or(serde_json::Value::Null, |h| h.into()));
        if hop.is_some() {
            // A hop that does not divide the window's length is refused, naming the file.
            let bad = dir.path().join("bad-hop");
            std::fs::create_dir_all(&bad).unwrap();
            let mut edited = ck.clone();
            edited["window_hop"] = 24.into();
            std::fs::write(bad.join("checkpoint.json"), edited.to_string()).unwrap();
            let o = dynforge(&["evaluate", bad.to_str().unwrap()]);
            let e = stderr(&o);
            assert!(!o.status.success() && e.contains("checkpoint.json") && e.contains("hop 24"), "{e}");
        }
        let flags = ["--torque-recordings", "2", "--identify-robots", "1", "--spread-robots", "0"];
        evaluate(&run, &flags);
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(run.join("report.json")).unwrap()).unwrap();
        let markdown = std::fs::read_to_string(run.join("report.md")).unwrap();
        assert_eq!(report["held_out"], by.name());
        assert!(markdown.contains(&format!("34 % of the {} held out (seed 0)", by.name())), "{markdown}");
        let rule = SplitRule { by, seed: 0, fraction: 0.34 };
        let whole = |&(robot, trajectory): &(u64, u32)| rule.side(Origin { robot, trajectory, segment: 0 });
        let held: Vec<&(u64, u32)> = shards.iter().filter(|s| whole(s) == Split::Validation).collect();
        let recordings = report["recordings"]["count"].as_u64().unwrap() as usize;
        let robots = report["robots"]["count"].as_u64().unwrap() as usize;
        match by {
            _ if hop.is_some() => {
                assert_eq!(recordings, held.len(), "overlapping windows: the recordings the rule holds out whole")
            }
            HoldOut::Robots | HoldOut::Trajectories => {
                assert_eq!(recordings, held.len(), "{by:?}: the recordings the rule holds out");
                let mut r: Vec<u64> = held.iter().map(|s| s.0).collect();
                r.sort();
                r.dedup();
                assert_eq!(robots, r.len(), "{by:?}");
            }
            // A recording is validation data when any of its windows is: some, not all.
            HoldOut::Windows => assert!(recordings > 0 && recordings < shards.len(), "{report}"),
        }
        validation_robots.push(robots);
        let checked = !report["torque"].is_null() && !report["identification"].is_null();
        assert_eq!(checked, by == HoldOut::Robots, "{by:?}: the checks need robots never trained on");
        assert_eq!(markdown.contains("none under this split"), by != HoldOut::Robots);
    }
    // Trajectories and windows put validation data on robots the training also sees: more robots than whole ones.
    assert!(
        validation_robots[1] > validation_robots[0] && validation_robots[2] > validation_robots[0],
        "{validation_robots:?}"
    );
}

/// `script --dry-run out` with this build's dynforge; its output, after asserting that it succeeded.
fn dry_run(script: &str, out: &Path) -> std::process::Output {
    let o = std::process::Command::new(Path::new(env!("CARGO_MANIFEST_DIR")).join(script))
        .arg("--dry-run")
        .arg(out)
        .env("DYNFORGE", env!("CARGO_BIN_EXE_dynforge"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    o
}

#[test]
fn the_gpu_bench_runs_dry_on_the_cpu_and_a_gpu_needs_the_cuda_build() {
    // What a task lent a GPU runs (bench/gpu.sh), at a few robots and one epoch on the CPU.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bench");
    dry_run("bench/gpu.sh", &out);
    let table = std::fs::read_to_string(out.join("gpu.md")).unwrap();
    let row = table.lines().find(|l| l.starts_with("| cpu | 0 |")).unwrap_or_else(|| panic!("{table}"));
    let cells: Vec<f64> = row.split('|').filter_map(|c| c.trim().parse().ok()).collect();
    // epoch, R2, windows/s, seconds: an R2 (finite, at most 1) and a positive rate.
    assert!(cells.len() == 4 && cells[1].is_finite() && cells[1] <= 1.0 && cells[2] > 0.0, "{row}");
    // A GPU on a build without the cuda feature is refused before anything is written, saying how to build it.
    #[cfg(not(feature = "cuda"))]
    {
        let run = dir.path().join("cuda");
        let d = out.join("data");
        let o = dynforge(&["train", d.to_str().unwrap(), "--out", run.to_str().unwrap(), "--device", "cuda:1"]);
        let said = stderr(&o);
        assert!(!o.status.success() && said.contains("device cuda:1") && said.contains("--features cuda"), "{said}");
        assert!(!run.exists());
        let o = dynforge(&["train", d.to_str().unwrap(), "--out", run.to_str().unwrap(), "--device", "gpu"]);
        assert!(!o.status.success() && stderr(&o).contains("expected cpu, cuda or cuda:N"), "{}", stderr(&o));
    }
}

#[test]
fn the_scale_bench_runs_dry_on_nested_subsets_of_one_run_and_resumes() {
    // bench/scale.sh at 32 robots: partitions j/8, merged into robots r % 4 == 0, r % 2 == 0 and all; one epoch each.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scale");
    let run = || dry_run("bench/scale.sh", &out);
    run();
    let table = std::fs::read_to_string(out.join("scale.md")).unwrap();
    let rows: Vec<Vec<f64>> = table
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| robots"))
        .map(|l| l.split('|').filter_map(|c| c.trim().parse().ok()).collect())
        .collect();
    assert_eq!(rows.iter().map(|r| r[0]).collect::<Vec<_>>(), [4.0, 8.0, 16.0, 32.0], "{table}");
    for r in &rows {
        // robots, training windows, validation robots, epochs run, best epoch, R2 per window and per robot, CPU
        // and wall hours.
        assert!(r.len() == 9 && r[1] > 0.0 && r[2] >= 2.0 && r[3] == 1.0 && r[4] == 1.0, "{table}");
        assert!(r[5].is_finite() && r[5] <= 1.0 && r[6].is_finite() && r[6] <= 1.0 && r[7] > 0.0, "{table}");
    }
    // The merged subsets are the coarser partitions of the one run, each robot once.
    for (name, partition) in [("n8", "0/4"), ("n16", "0/2"), ("n32", "0/1")] {
        let m = Manifest::load(&out.join(name)).unwrap().unwrap();
        assert_eq!(m.partition.to_string(), partition, "{name}");
    }
    // A rerun finds everything done: no new epoch, the same table.
    let again = run();
    assert!(!stderr(&again).contains("training"), "{}", stderr(&again));
    assert_eq!(std::fs::read_to_string(out.join("scale.md")).unwrap(), table);
}
