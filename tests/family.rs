//! `dynforge generate --urdf --excitation`: a robot's family as a dataset, end to end with real coordinator and
//! worker processes, on example-robot-data's Panda (7 joints, fingers welded).

mod common;

use common::{children_of, dynforge, shard_hashes};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use dynforge_identify::NormalEquations;
use dynforge_recording::Reading;
use dynforge_recording::log::read_log;
use dynforge_robot::parameters::{dynamic_parameters, standard_names, standard_parameters};
use dynforge_testkit::arms::{Harness, PANDA};

const FIX: [&str; 4] = ["--fix", "panda_finger_joint1", "--fix", "panda_finger_joint2"];

/// Two short excitations of the Panda, in `dir/excite`.
fn excitations(urdf: &str, dir: &Path) -> std::path::PathBuf {
    let out = dir.join("excite");
    let mut args = vec!["excite", "--urdf", urdf, "--out", out.to_str().unwrap()];
    args.extend(["--count", "2", "--duration", "3", "--evaluations", "60", "--seed", "3"]);
    args.extend(FIX);
    let o = dynforge(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

fn family_args<'a>(urdf: &'a str, excite: &'a str, out: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec!["generate", "--urdf", urdf, "--excitation", excite, "--out", out.to_str().unwrap()];
    a.extend(["--robots", "6", "--seed", "2"]);
    a.extend(FIX);
    a.extend_from_slice(extra);
    a
}

fn run(args: &[&str]) {
    let o = dynforge(args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn a_family_dataset_is_reproducible_resumable_and_partitionable_and_refuses_other_files() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let urdf = Harness::new(py, tmp.path(), &PANDA).urdf;
    let excite = excitations(&urdf, tmp.path());
    let ex = excite.to_str().unwrap();

    let whole = tmp.path().join("whole");
    run(&family_args(&urdf, ex, &whole, &["--workers", "2"]));
    let want = shard_hashes(&whole);
    // Some variants must make it through the controller and the checks, or nothing here is tested.
    assert!(want.len() >= 6, "{} of 12 jobs written", want.len());
    let o = dynforge(&["verify", whole.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));

    // One worker, and a run killed with its workers then resumed: the same bytes.
    let one = tmp.path().join("one");
    run(&family_args(&urdf, ex, &one, &["--workers", "1"]));
    assert_eq!(shard_hashes(&one), want, "one worker");
    let killed = tmp.path().join("killed");
    let mut child = Command::new(env!("CARGO_BIN_EXE_dynforge"))
        .args(family_args(&urdf, ex, &killed, &["--workers", "2"]))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while std::fs::read_to_string(killed.join("ledger.tsv")).map_or(0, |l| l.lines().count()) < 3 {
        assert!(child.try_wait().unwrap().is_none() && start.elapsed() < Duration::from_secs(120), "no progress");
        std::thread::sleep(Duration::from_millis(10));
    }
    let workers = children_of(child.id());
    for pid in std::iter::once(child.id()).chain(workers) {
        let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
    }
    let _ = child.wait();
    run(&family_args(&urdf, ex, &killed, &["--workers", "2"]));
    assert_eq!(shard_hashes(&killed), want, "killed and resumed");

    // Partitions add up to the whole.
    let mut union = BTreeMap::new();
    for part in ["0/2", "1/2"] {
        let p = tmp.path().join(part.replace('/', "of"));
        run(&family_args(&urdf, ex, &p, &["--workers", "1", "--partition", part]));
        union.extend(shard_hashes(&p));
    }
    assert_eq!(union, want, "partitions");
    // Merged, they are the whole run, with the family's files the workers read.
    let merged = tmp.path().join("merged");
    run(&[
        "merge",
        "--out",
        merged.to_str().unwrap(),
        tmp.path().join("0of2").to_str().unwrap(),
        tmp.path().join("1of2").to_str().unwrap(),
    ]);
    assert_eq!(shard_hashes(&merged), want, "merged");
    for f in ["robot.urdf", "excitation-0.json", "excitation-1.json"] {
        assert_eq!(
            std::fs::read(merged.join("family").join(f)).unwrap(),
            std::fs::read(whole.join("family").join(f)).unwrap(),
            "{f}"
        );
    }

    // An excitation changed since `excite` wrote the set is refused, naming it; one written as the set (its
    // manifest too) is another dataset: refused, naming what differs.
    let json = excite.join("excitation-1.json");
    let text = std::fs::read_to_string(&json).unwrap();
    let changed = text.replacen("\"period\": 3.0", "\"period\": 3.5", 1);
    std::fs::write(&json, &changed).unwrap();
    let o = dynforge(&family_args(&urdf, ex, &whole, &["--workers", "1"]));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("excitation-1.json: differs from the excitation"), "{err}");
    let first = std::fs::read_to_string(excite.join("excitation-0.json")).unwrap();
    let set = dynforge_proto::family::ExcitationSet::of(&[first, changed]);
    std::fs::write(excite.join(dynforge_proto::family::SET), serde_json::to_string(&set).unwrap()).unwrap();
    let o = dynforge(&family_args(&urdf, ex, &whole, &["--workers", "1"]));
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("family.excitation_hashes"), "{err}");
    assert_eq!(shard_hashes(&whole), want, "a refused run touches nothing");

    // Excitations of other joints (the fingers not welded): refused before anything is made, naming the file.
    let other = tmp.path().join("other");
    let mut args = vec!["generate", "--urdf", urdf.as_str(), "--excitation", ex, "--out", other.to_str().unwrap()];
    args.extend(["--robots", "2"]);
    let o = dynforge(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains(&format!("{ex}/excitation-0.json moves joints")), "{err}");
    assert!(!other.exists(), "a refused family creates no directory");
    // The fingers moving, on an engine that has no prismatic joints: refused up front, naming the joint.
    args.extend(["--engine", "rapier"]);
    let o = dynforge(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("joint 'panda_finger_joint1' is prismatic"), "{err}");
    assert!(!other.exists(), "a refused family creates no directory");
    // A URDF whose joint is slower than the excitations move it (they were designed for other limits): refused up
    // front, naming the excitation and the joint, where every variant would be discarded.
    let text = std::fs::read_to_string(&urdf).unwrap();
    let joint = text.find("name=\"panda_joint2\"").unwrap();
    let at = joint + text[joint..].find("velocity=\"").unwrap() + "velocity=\"".len();
    let end = at + text[at..].find('"').unwrap();
    let slow = tmp.path().join("slow.urdf");
    std::fs::write(&slow, format!("{}0.01{}", &text[..at], &text[end..])).unwrap();
    let o = dynforge(&family_args(slow.to_str().unwrap(), ex, &other, &["--workers", "1"]));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("excitation-0.json: joint 'panda_joint2' reaches speed") && err.contains("speed 0.01"),
        "{err}"
    );
    assert!(!other.exists(), "a refused family creates no directory");
}

#[test]
fn a_family_shard_is_a_physical_variant_of_the_urdf_labelled_with_its_parameters() {
    let Some(py) = dynforge_testkit::reference_python() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let urdf = Harness::new(py, tmp.path(), &PANDA).urdf;
    let excite = excitations(&urdf, tmp.path());
    let out = tmp.path().join("family");
    run(&family_args(&urdf, excite.to_str().unwrap(), &out, &["--workers", "2"]));
    // The estimators learn the generator's 38 labels: a family is refused up front, naming what serves it.
    let o = dynforge(&["train", out.to_str().unwrap(), "--out", tmp.path().join("run").to_str().unwrap()]);
    assert!(
        !o.status.success()
            && String::from_utf8_lossy(&o.stderr).contains("identify --spread 0.3")
            && String::from_utf8_lossy(&o.stderr).contains("dynforge calibrate")
    );
    assert!(!tmp.path().join("run").exists(), "a refused train writes nothing");
    let o = dynforge(&["info", first_shard(&out).to_str().unwrap()]);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("identify: yes") && said.contains("estimate: no: a shard of a robot's family"), "{said}");
    let fixed: Vec<String> = ["panda_finger_joint1", "panda_finger_joint2"].map(String::from).to_vec();
    let nominal = read_log(
        &first_shard(&out),
        Some((&std::fs::read_to_string(&urdf).unwrap(), &urdf)),
        &Reading::welding(&fixed),
    )
    .unwrap()
    .model;
    let mut masses = Vec::new();
    for entry in std::fs::read_dir(out.join("shards")).unwrap() {
        let path = entry.unwrap().path();
        // The shard's own URDF (its /robot_description) is the variant.
        let log = read_log(&path, None, &Reading::welding(&fixed)).unwrap();
        let model = &log.model;
        assert_eq!(model.dof(), 7);
        // Its labels are the variant's standard parameters, to the digit.
        let bag = dynforge_shard::read(&path).unwrap();
        let labels = &bag.metadata[dynforge_proto::shard::META_LABELS];
        for (name, value) in standard_names(model).iter().zip(standard_parameters(model)) {
            let got: f64 = labels[name].parse().unwrap();
            assert!((got - value).abs() <= 1e-12 * value.abs().max(1e-9), "{name}: label {got}, URDF {value}");
        }
        // Its torques are the variant's dynamics: the true parameters leave the pairing's second-order error
        // ((omega dt)^2 / 24 of the swinging torque, tests/pairing_on_simulation.rs: ~2e-5 at the generator's gains;
        // a family's loops are stiffer, to hold the joints against twice the Coulomb friction the prior expects, 5 %
        // of the effort limit: omega about 1.6x, ~5e-5).
        let ne = NormalEquations::of(model, &log.segments[0]).unwrap();
        let worst = ne.nrmse(&dynamic_parameters(model)).into_iter().fold(0.0, f64::max);
        assert!(worst < 1.25e-4, "{}: NRMSE of its own parameters {worst:e}", path.display());
        // And the nominal URDF's do not (the variant is not the URDF).
        let nominal_worst = ne.nrmse(&dynamic_parameters(&nominal)).into_iter().fold(0.0, f64::max);
        assert!(nominal_worst > 100.0 * worst, "{}: the nominal fits as well ({nominal_worst:e})", path.display());
        masses.push(model.inertia(3).mass);
    }
    // Variants differ from each other by about the spread (0.3 log-normal): a relative spread of link 4's masses
    // over the shards of at least a tenth (far below 0.3, which six variants would have to miss by 3 standard errors).
    let mean = masses.iter().sum::<f64>() / masses.len() as f64;
    let sd = (masses.iter().map(|m| (m / mean - 1.0).powi(2)).sum::<f64>() / masses.len() as f64).sqrt();
    assert!(sd > 0.1, "masses of link 4 across the shards: {masses:?}");
}

fn first_shard(dir: &Path) -> std::path::PathBuf {
    let mut paths: Vec<_> = std::fs::read_dir(dir.join("shards")).unwrap().map(|e| e.unwrap().path()).collect();
    paths.sort();
    paths.remove(0)
}
