//! `dynforge calibrate`: a UR5 simulated by MuJoCo running excitations `dynforge excite` designed, logged as a
//! driver writes it (1 % effort noise, 2^17-count encoders, velocity from encoder differences, sampled effort),
//! calibrated from a nominal URDF with spreads its family measured; the family made by real coordinator and worker
//! processes into a cache, and reused.

mod common;

use common::dynforge;
use std::path::{Path, PathBuf};

use dynforge_testkit::arms::{Harness, LogKind, PANDA, UR5};
use serde_json::Value;

/// Two short excitations of the UR5 in `dir/excite`, and a bag of the arm running each.
fn excitations_and_bags(h: &Harness, dir: &Path) -> (PathBuf, Vec<PathBuf>) {
    let out = dir.join("excite");
    let mut args = vec!["excite", "--urdf", &h.urdf, "--out", out.to_str().unwrap()];
    args.extend(["--count", "2", "--duration", "4", "--evaluations", "60", "--seed", "3"]);
    let o = dynforge(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let bags = (0..2)
        .map(|k| {
            let bag = dir.join(format!("bag-{k}.mcap"));
            h.excitation_log(&UR5, &out.join(format!("excitation-{k}.json")), 10 + k, &bag);
            bag
        })
        .collect();
    (out, bags)
}

fn json_of(o: &std::process::Output) -> Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).expect("JSON on stdout")
}

/// Every (value, std) of a `--json` identification, in order.
fn estimates(v: &Value) -> Vec<(f64, f64)> {
    let e = |x: &Value| (x["value"].as_f64().unwrap(), x["std"].as_f64().unwrap());
    dynforge_testkit::json_parameters(v).expect("links and joints").into_iter().map(e).collect()
}

#[test]
fn calibrate_writes_identifys_urdf_with_spreads_its_family_measured_and_reuses_the_family() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let h = Harness::new(py, tmp.path(), &UR5);
    let (excite, bags) = excitations_and_bags(&h, tmp.path());
    let nominal = h.nominal(1);
    let held = h.log(&UR5, 9, 6.0, "sampled", LogKind::Clean, 1000.0);
    let cache = tmp.path().join("cache");
    let (cal, id) = (tmp.path().join("calibrate.urdf"), tmp.path().join("identify.urdf"));
    let common = |out: &Path| {
        let mut a: Vec<String> = bags.iter().map(|b| b.display().to_string()).collect();
        for s in ["--urdf", nominal.to_str().unwrap(), "--holdout", held.to_str().unwrap(), "--spread", "0.3"] {
            a.push(s.into());
        }
        a.extend(["--out".into(), out.display().to_string(), "--json".into()]);
        a
    };
    let mut args = vec!["calibrate".to_string()];
    args.extend(common(&cal));
    args.extend(
        ["--excitation", excite.to_str().unwrap(), "--cache", cache.to_str().unwrap(), "--robots", "32"]
            .map(String::from),
    );
    args.extend(["--workers", "2"].map(String::from));
    let argv: Vec<&str> = args.iter().map(String::as_str).collect();
    let first = dynforge(&argv);
    let c = json_of(&first);
    let said = String::from_utf8_lossy(&first.stderr);
    for k in 0..2 {
        assert!(said.contains(&format!("bag-{k}.mcap: ran excitation-{k}.json from 0.00 s")), "{said}");
    }

    // The same identification as `identify` at the same spread: the same file, byte for byte, and the same values.
    let mut id_args = vec!["identify".to_string()];
    id_args.extend(common(&id));
    let i = json_of(&dynforge(&id_args.iter().map(String::as_str).collect::<Vec<_>>()));
    assert_eq!(std::fs::read(&cal).unwrap(), std::fs::read(&id).unwrap(), "calibrate's URDF is not identify's");
    assert_eq!(c["held_out"]["nrmse_calibrated"], i["held_out"]["nrmse_calibrated"]);
    assert!(c["held_out"]["nrmse_calibrated"].as_f64().unwrap() < 0.1 * c["held_out"]["nrmse_urdf"].as_f64().unwrap());

    // Each spread is identify's times the factor its family measured, where that widens it, and never narrower.
    let spreads = &c["family"]["spreads"];
    let variants = spreads["variants"].as_u64().unwrap();
    assert!(variants >= 32 - spreads["refused"].as_u64().unwrap() && variants >= 32, "{spreads}");
    let factors: Vec<f64> =
        spreads["parameters"].as_array().unwrap().iter().map(|p| p["factor"].as_f64().unwrap()).collect();
    let (ce, ie) = (estimates(&c), estimates(&i));
    assert_eq!(factors.len(), ce.len());
    let mut widened = 0;
    for ((cv, iv), f) in ce.iter().zip(&ie).zip(&factors) {
        assert_eq!(cv.0, iv.0, "values differ");
        assert!((cv.1 / iv.1 - f.max(1.0)).abs() < 1e-12, "std {} vs identify {} with factor {f}", cv.1, iv.1);
        widened += usize::from(*f > 1.0);
    }
    // The family measures something: not every factor is one value (a constant would be a stub).
    assert!(factors.iter().any(|f| (f - factors[0]).abs() > 0.05), "{factors:?}");
    assert!(widened > 0, "{factors:?}");

    // Again: the family and what it measured come from the cache, and the answer is the same.
    let second = dynforge(&argv);
    let err = String::from_utf8_lossy(&second.stderr);
    assert!(err.contains("measured before"), "{err}");
    assert!(err.contains("64 resumed from an earlier run"), "{err}");
    let mut again = json_of(&second);
    let mut before = c.clone();
    for v in [&mut again, &mut before] {
        v.as_object_mut().unwrap().remove("logs");
    }
    assert_eq!(again, before);

    // A family another process is making (its run directory's lock held) is said to be one, and nothing is written.
    let family = PathBuf::from(c["family"]["dir"].as_str().unwrap());
    let held = dynforge_proto::lock::RunLock::acquire(&family, std::time::Duration::ZERO, "generate").unwrap();
    std::fs::remove_file(&cal).unwrap();
    let busy = dynforge(&argv);
    let err = String::from_utf8_lossy(&busy.stderr);
    assert!(!busy.status.success() && err.contains("the robot's family is being made by another process"), "{err}");
    assert!(!cal.exists(), "a refused calibrate writes nothing");
    drop(held);
    // A damaged shard of the cached family (its spreads to be measured again) names the directory to delete.
    let shard = std::fs::read_dir(family.join("shards")).unwrap().next().unwrap().unwrap().path();
    std::fs::write(&shard, b"damaged").unwrap();
    for entry in std::fs::read_dir(&family).unwrap() {
        let path = entry.unwrap().path();
        if path.file_name().unwrap().to_str().unwrap().starts_with("spreads-") {
            std::fs::remove_file(path).unwrap();
        }
    }
    let damaged = dynforge(&argv);
    let err = String::from_utf8_lossy(&damaged.stderr);
    let delete = format!("delete {} and run again", family.display());
    assert!(!damaged.status.success() && err.contains(&delete), "{err}");
}

/// Logs that did not run the excitations are refused before the family is made, naming the log or the excitation:
/// one bag against a set of two, and a bag of some other motion beside one that ran its excitation.
#[test]
fn calibrate_refuses_logs_that_did_not_run_the_excitations() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let h = Harness::new(py, tmp.path(), &UR5);
    let (excite, bags) = excitations_and_bags(&h, tmp.path());
    let other = h.log(&UR5, 5, 6.0, "sampled", LogKind::Noisy, 1000.0);
    let (cache, out) = (tmp.path().join("cache"), tmp.path().join("out.urdf"));
    let run = |logs: &[&Path]| {
        let mut args: Vec<&str> = vec!["calibrate"];
        args.extend(logs.iter().map(|l| l.to_str().unwrap()));
        args.extend(["--urdf", &h.urdf, "--excitation", excite.to_str().unwrap(), "--cache"]);
        args.extend([cache.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        let o = dynforge(&args);
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    let one = run(&[&bags[0]]);
    assert!(one.contains("no log ran excitation-1.json (the closest is excitation-1.json in"), "{one}");
    let stray = run(&[&bags[0], &bags[1], &other]);
    let name = other.file_name().unwrap().to_str().unwrap();
    assert!(stray.contains(&format!("{name}: ran none of the excitations")), "{stray}");
    assert!(!out.exists() && !cache.join("families").exists(), "something was made");
}

#[test]
fn calibrate_refuses_another_robots_excitation_before_writing_anything() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let ur5 = Harness::new(py.clone(), tmp.path(), &UR5);
    let panda = Harness::new(py, tmp.path(), &PANDA);
    let excite = tmp.path().join("panda-excite");
    let mut args = vec!["excite", "--urdf", &panda.urdf, "--out", excite.to_str().unwrap()];
    args.extend(["--count", "1", "--duration", "2", "--evaluations", "20"]);
    args.extend(["--fix", "panda_finger_joint1", "--fix", "panda_finger_joint2"]);
    assert!(dynforge(&args).status.success());
    let bag = ur5.log(&UR5, 1, 4.0, "held", LogKind::Clean, 1000.0);
    let out = tmp.path().join("out.urdf");
    let cache = tmp.path().join("cache");
    let o = dynforge(&[
        "calibrate",
        bag.to_str().unwrap(),
        "--urdf",
        &ur5.urdf,
        "--excitation",
        excite.to_str().unwrap(),
        "--cache",
        cache.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("excitation-0.json"), "{err}");
    assert!(!out.exists() && !cache.exists(), "something was written");
    // --out or --mjcf into the excitations or the cache is refused before anything is read, and leaves both as they
    // were.
    let before = std::fs::read(excite.join("excitation-0.json")).unwrap();
    for target in [excite.join("excitation-0.json"), cache.join("families/k/manifest.toml")] {
        for flag in ["--out", "--mjcf"] {
            let mut args = vec!["calibrate", bag.to_str().unwrap(), "--urdf", &ur5.urdf, "--excitation"];
            args.extend([excite.to_str().unwrap(), "--cache", cache.to_str().unwrap(), flag, target.to_str().unwrap()]);
            args.extend(["--out", out.to_str().unwrap()].iter().filter(|_| flag == "--mjcf"));
            let o = dynforge(&args);
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(!o.status.success() && err.contains("would overwrite the input"), "{flag}: {err}");
        }
    }
    assert_eq!(std::fs::read(excite.join("excitation-0.json")).unwrap(), before);
    assert!(!cache.exists(), "something was written");
}
