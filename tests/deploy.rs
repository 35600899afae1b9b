//! The deploy scripts on the engines themselves: a real single-node Slurm cluster (installed and started by
//! `deploy/slurm/local-cluster.sh` when absent; needs root), the job array over partitions and the dependent merge.

mod common;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use common::dynforge;

const EXE: &str = env!("CARGO_BIN_EXE_dynforge");

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn shard_hashes(dir: &Path) -> BTreeMap<String, u64> {
    std::fs::read_dir(dir.join("shards"))
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (e.file_name().to_string_lossy().into(), dynforge_shard::content_hash(&std::fs::read(e.path()).unwrap()))
        })
        .collect()
}

fn ledger_set(dir: &Path) -> BTreeSet<String> {
    let entries = dynforge_coordinator::ledger::read(&dir.join("ledger.tsv")).unwrap();
    entries.iter().map(|e| format!("{e:?}")).collect()
}

#[test]
fn a_slurm_job_array_of_three_partitions_merges_into_the_single_host_dataset_and_trains() {
    let up = Command::new(repo().join("deploy/slurm/local-cluster.sh")).arg("up").output().unwrap();
    if up.status.code() == Some(77) {
        eprintln!("skipped: {}", String::from_utf8_lossy(&up.stderr));
        return;
    }
    assert!(up.status.success(), "the local Slurm cluster did not come up:\n{}", String::from_utf8_lossy(&up.stderr));

    let generate = ["--robots", "6", "--trajectories", "2", "--seed", "4"];
    let single = tempfile::tempdir().unwrap();
    let mut args = vec!["generate", "--out", single.path().to_str().unwrap(), "--workers", "2"];
    args.extend(generate);
    assert!(dynforge(&args).status.success());

    let root = tempfile::tempdir().unwrap();
    let train = "--epochs 1 --generated 1024 --dim 32 --validation 0.34";
    let ids = submit_and_wait(root.path(), &["--train", train], &generate);
    let merged = root.path().join("merged");
    let log = std::fs::read_to_string(root.path().join(format!("dynforge-merge-{}.log", ids[1]))).unwrap_or_default();
    assert!(
        log.contains("merged 3 partitions: 12 shards (12 hard-linked, 0 copied, 0 pruned)"),
        "merge job log:\n{log}"
    );
    assert_eq!(shard_hashes(&merged), shard_hashes(single.path()), "byte-identical shards");
    assert_eq!(
        std::fs::read(merged.join("manifest.toml")).unwrap(),
        std::fs::read(single.path().join("manifest.toml")).unwrap(),
        "the single host's manifest"
    );
    assert_eq!(ledger_set(&merged), ledger_set(single.path()), "the same ledger records");
    assert!(root.path().join("model/checkpoint.json").is_file(), "the merge job trained:\n{log}");

    // Bounded disk: each task caches its partition and deletes the shards; the merge combines the caches into the
    // single host's, and trains the same weights.
    let pruned = tempfile::tempdir().unwrap();
    let ids = submit_and_wait(pruned.path(), &["--train", train, "--prune"], &generate);
    let merged = pruned.path().join("merged");
    let log = std::fs::read_to_string(pruned.path().join(format!("dynforge-merge-{}.log", ids[1]))).unwrap_or_default();
    assert!(log.contains("12 shards (0 hard-linked, 0 copied, 12 pruned)"), "merge job log:\n{log}");
    assert!(shard_hashes(&merged).is_empty());
    assert!(dynforge(&["dataset", "prepare", single.path().to_str().unwrap()]).status.success());
    let cache = |d: &Path| {
        let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(d.join("cache"))
            .unwrap()
            .map(|e| e.unwrap())
            .map(|e| (e.file_name().to_string_lossy().to_string(), std::fs::read(e.path()).unwrap()))
            .collect();
        files.sort();
        files
    };
    assert!(cache(&merged) == cache(single.path()), "the combined cache differs from the single host's");
    let weights = |d: &Path| std::fs::read(d.join("model/model.safetensors")).unwrap();
    assert!(weights(pruned.path()) == weights(root.path()), "other weights from the same data:\n{log}");
}

/// Submits `deploy/slurm/submit.sh` (3 partitions into `root`, `options`, then `generate` flags) and waits for its
/// jobs; returns the two job ids (array, merge).
fn submit_and_wait(root: &Path, options: &[&str], generate: &[&str]) -> Vec<String> {
    let submit = Command::new(repo().join("deploy/slurm/submit.sh"))
        .args(["--root", root.to_str().unwrap(), "--partitions", "3", "--cpus", "1", "--dynforge", EXE])
        .args(options)
        .arg("--")
        .args(generate)
        .output()
        .unwrap();
    assert!(submit.status.success(), "{}", String::from_utf8_lossy(&submit.stderr));
    let said = String::from_utf8_lossy(&submit.stdout).to_string();
    let ids: Vec<String> = said
        .lines()
        .filter_map(|l| l.split_whitespace().find(|w| w.chars().all(|c| c.is_ascii_digit())).map(String::from))
        .collect();
    assert_eq!(ids.len(), 2, "two job ids in: {said}");
    let start = Instant::now();
    loop {
        let q = Command::new("squeue").args(["-h", "-j", &ids.join(",")]).output().unwrap();
        if String::from_utf8_lossy(&q.stdout).trim().is_empty() {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(900),
            "the jobs did not finish: {}",
            String::from_utf8_lossy(&q.stdout)
        );
        std::thread::sleep(Duration::from_millis(500));
    }
    ids
}

/// Renders `deploy/k8s` with kustomize (`kubectl kustomize`), or takes its resource files as they are where kubectl
/// is absent.
fn rendered_manifests() -> String {
    let dir = repo().join("deploy/k8s");
    if let Ok(out) = Command::new("kubectl").arg("kustomize").arg(&dir).output() {
        assert!(out.status.success(), "kustomize: {}", String::from_utf8_lossy(&out.stderr));
        return String::from_utf8(out.stdout).unwrap();
    }
    eprintln!("kubectl absent: validating the resource files unrendered");
    ["namespace.yaml", "volume.yaml", "generate.yaml", "merge.yaml"]
        .iter()
        .map(|f| std::fs::read_to_string(dir.join(f)).unwrap())
        .collect::<Vec<_>>()
        .join("\n---\n")
}

/// Runs kubernetes-validate (strict: unknown fields are errors) on `yaml`; its verdict and output.
fn validate(python: &str, yaml: &str) -> (bool, String) {
    let file = tempfile::Builder::new().suffix(".yaml").tempfile().unwrap();
    std::fs::write(file.path(), yaml).unwrap();
    let validator = Path::new(python).with_file_name("kubernetes-validate");
    let out = Command::new(validator).args(["--strict", "-k", "1.31.0"]).arg(file.path()).output().unwrap();
    (out.status.success(), format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr)))
}

#[test]
fn the_kubernetes_manifests_render_and_pass_the_api_schema() {
    let Some(python) = dynforge_testkit::reference_python() else { return };
    let yaml = rendered_manifests();
    let (ok, said) = validate(&python, &yaml);
    assert!(ok, "{said}");
    for kind in
        ["namespace/dynforge", "persistentvolumeclaim/dynforge-data", "job/dynforge-generate", "job/dynforge-merge"]
    {
        assert!(said.contains(&format!("passed for resource {kind}")), "{kind} not checked:\n{said}");
    }
    // The validator is real: a misspelt field fails it.
    let (ok, said) = validate(&python, &yaml.replacen("parallelism:", "parallelizm:", 1));
    assert!(!ok && said.contains("'parallelizm' was unexpected"), "{said}");
    // Index i is partition i/n: the Job runs n indices, n at once, and tells the pods n.
    let count = |key: &str| yaml.lines().find_map(|l| l.trim().strip_prefix(key).map(|v| v.trim().to_string()));
    assert_eq!(count("completionMode:").as_deref(), Some("Indexed"));
    let n = count("completions:").unwrap();
    assert_eq!(count("parallelism:").unwrap(), n);
    let partitions = yaml.lines().skip_while(|l| !l.contains("name: PARTITIONS")).nth(1).unwrap();
    assert!(partitions.contains(&format!("\"{n}\"")), "PARTITIONS must equal completions {n}: {partitions}");
}

#[test]
fn the_container_image_builds_and_generates_the_same_shards_as_the_host() {
    // podman with runc, offline: the base made by debootstrap from the Debian mirror, no registry needed.
    let tag = "localhost/dynforge:test";
    let build = Command::new(repo().join("deploy/container/build.sh"))
        .args(["--binary", EXE, "--offline-base", "--install", "--tag", tag])
        .output()
        .unwrap();
    if build.status.code() == Some(77) {
        eprintln!("skipped: {}", String::from_utf8_lossy(&build.stderr));
        return;
    }
    assert!(build.status.success(), "image build failed:\n{}", String::from_utf8_lossy(&build.stderr));

    let host = tempfile::tempdir().unwrap();
    let args = ["--robots", "1", "--trajectories", "2", "--workers", "2", "--seed", "4"];
    let mut run = vec!["generate", "--out", host.path().to_str().unwrap()];
    run.extend(args);
    assert!(dynforge(&run).status.success());

    let volume = tempfile::tempdir().unwrap();
    let mount = format!("{}:/data", volume.path().display());
    // The rlimits are given explicitly: this VM refuses the engine's defaults (runc cannot raise them).
    let out = Command::new("podman")
        .args(["--runtime", "runc", "run", "--rm", "--network=none", "--shm-size=256m"])
        .args(["--ulimit", "nofile=4096:4096", "--ulimit", "nproc=4096:4096", "-v", &mount, tag])
        .args(["generate", "--out", "/data/run"])
        .args(args)
        .output()
        .unwrap();
    assert!(out.status.success(), "generate in the container:\n{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(shard_hashes(&volume.path().join("run")), shard_hashes(host.path()), "the same shards");
}
