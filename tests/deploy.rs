//! The deploy scripts (`deploy/`) on the engines themselves: a real single-node Slurm 22.05 (Debian's slurm-wlm and
//! munge), podman with runc, docker, and the rendered Kubernetes manifests, whose pods' exact commands run under
//! podman.
//!
//! The engine tests are opt-in: they run only with `DYNFORGE_ENGINE_TESTS=1` (as `.ci/run` sets), as root, because
//! they install packages (slurm-wlm, munge, podman, runc, debootstrap, docker.io) and start daemons. Every daemon
//! they start is stopped at the end, whatever the outcome: each Slurm test runs its own cluster in a private
//! namespace (`tests/engines/sandbox.sh`: the host's Slurm, running or not, is never touched), the docker test its
//! own dockerd, and every container is removed. Without the variable they print why they skipped and pass. The
//! manifest checks that need no engine (the API schema, `run.sh` against a stand-in kubectl) always run.

mod common;

use std::collections::BTreeSet;
use std::ffi::OsStr;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use common::{dynforge, shard_hashes};

const EXE: &str = env!("CARGO_BIN_EXE_dynforge");
/// The variable that turns the engine tests on.
const ENGINE_TESTS: &str = "DYNFORGE_ENGINE_TESTS";

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Whether the engine tests run (`DYNFORGE_ENGINE_TESTS=1`); says why not otherwise.
fn engines(test: &str) -> bool {
    if std::env::var(ENGINE_TESTS).is_ok_and(|v| v == "1") {
        assert!(
            unsafe { libc::geteuid() } == 0,
            "{ENGINE_TESTS}=1 needs root: the engine tests install packages and start daemons"
        );
        return true;
    }
    eprintln!(
        "SKIPPED {test}: an engine test (installs packages, starts daemons and stops them); set {ENGINE_TESTS}=1, as \
         root, to run it"
    );
    false
}

fn said(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn run(cmd: &mut Command) -> Output {
    cmd.stdin(Stdio::null()).output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"))
}

fn ok(cmd: &mut Command) -> String {
    let out = run(cmd);
    assert!(out.status.success(), "{cmd:?} failed:\n{}", said(&out));
    String::from_utf8_lossy(&out.stdout).to_string()
}

/// Installs Debian packages through the project's installer (one apt at a time), which returns at once when dpkg
/// has them installed. Always through it, even when their commands are on PATH: on a fresh machine another test may
/// be unpacking that very package, and the installer's lock waits for it to finish.
fn install(packages: &[&str]) {
    let out = run(Command::new(repo().join("deploy/apt-install.sh")).args(packages));
    assert!(out.status.success(), "installing {packages:?} failed:\n{}", said(&out));
}

fn ledger_set(dir: &Path) -> BTreeSet<String> {
    let entries = dynforge_proto::ledger::read(&dir.join("ledger.tsv")).unwrap();
    entries.iter().map(|e| format!("{e:?}")).collect()
}

/// The cache files of a run directory, by name.
fn caches(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir.join("cache"))
        .unwrap()
        .map(|e| e.unwrap())
        .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
        .map(|e| (e.file_name().to_string_lossy().to_string(), std::fs::read(e.path()).unwrap()))
        .collect();
    files.sort();
    files
}

fn generate_single(dir: &Path, generate: &[&str]) {
    let mut args = vec!["generate", "--out", dir.to_str().unwrap(), "--workers", "2"];
    args.extend(generate);
    let out = dynforge(&args);
    assert!(out.status.success(), "{}", said(&out));
}

// ---------------------------------------------------------------------------------------------------------------
// Slurm

/// A private host for one Slurm test: `tests/engines/sandbox.sh` as PID 1 of new mount, UTS, IPC, network and PID
/// namespaces, where `deploy/slurm/local-cluster.sh` sets up its cluster as on a fresh machine. Dropped (the test
/// passed or panicked), it runs `local-cluster.sh down` and kills the namespace: every process in it ends. If the
/// test process itself is killed, the kernel kills `unshare` (parent-death signal) and `unshare` its child.
struct Sandbox {
    unshare: Child,
    init: u32,
    /// Its PID namespace (`/proc/PID/ns/pid`'s link).
    ns: PathBuf,
    _dir: tempfile::TempDir,
}

impl Sandbox {
    fn start() -> Sandbox {
        install(&["slurm-wlm", "munge", "iproute2"]);
        let dir = tempfile::tempdir().unwrap();
        let ready = dir.path().join("ready");
        let log = std::fs::File::create(dir.path().join("sandbox.log")).unwrap();
        let mut cmd = Command::new("unshare");
        cmd.args(["--mount", "--uts", "--ipc", "--net", "--pid", "--fork", "--kill-child", "--mount-proc"])
            .arg(repo().join("tests/engines/sandbox.sh"))
            .arg(&ready)
            .stdin(Stdio::null())
            .stdout(log.try_clone().unwrap())
            .stderr(log);
        // SAFETY: prctl is async-signal-safe.
        unsafe {
            cmd.pre_exec(|| {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
                Ok(())
            });
        }
        let mut unshare = cmd.spawn().expect("unshare (util-linux) runs");
        let start = Instant::now();
        while !ready.exists() {
            let log = std::fs::read_to_string(dir.path().join("sandbox.log")).unwrap_or_default();
            assert!(unshare.try_wait().unwrap().is_none(), "the sandbox did not start:\n{log}");
            assert!(start.elapsed() < Duration::from_secs(30), "the sandbox did not get ready:\n{log}");
            std::thread::sleep(Duration::from_millis(50));
        }
        let pid = unshare.id();
        let children = std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/children")).unwrap();
        let init = children.split_whitespace().next().expect("unshare's child").parse().unwrap();
        let ns = std::fs::read_link(format!("/proc/{init}/ns/pid")).unwrap();
        Sandbox { unshare, init, ns, _dir: dir }
    }

    /// The host's pids of the processes in the sandbox's PID namespace.
    fn processes(&self) -> Vec<u32> {
        std::fs::read_dir("/proc")
            .unwrap()
            .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
            .filter(|pid| std::fs::read_link(format!("/proc/{pid}/ns/pid")).is_ok_and(|l| l == self.ns))
            .collect()
    }

    /// The command lines of the sandbox's processes running `dynforge SUBCOMMAND`.
    fn running(&self, subcommand: &str) -> Vec<String> {
        self.processes()
            .into_iter()
            .filter_map(|pid| std::fs::read(format!("/proc/{pid}/cmdline")).ok())
            .map(|c| String::from_utf8_lossy(&c).split('\0').map(str::to_string).collect::<Vec<_>>())
            .filter(|args| {
                args.first().is_some_and(|a| a.ends_with("dynforge")) && args.get(1).is_some_and(|a| a == subcommand)
            })
            .map(|args| args.join(" "))
            .collect()
    }

    /// `program` run inside the sandbox, in `cwd`.
    fn command(&self, program: impl AsRef<OsStr>, cwd: &Path) -> Command {
        let mut cmd = Command::new("nsenter");
        cmd.arg(format!("--target={}", self.init))
            .args(["--mount", "--uts", "--ipc", "--net", "--pid"])
            .arg(format!("--wd={}", cwd.display()))
            .arg("--")
            .arg(program);
        cmd
    }

    fn sh(&self, script: &str) -> Output {
        run(self.command("sh", Path::new("/")).args(["-c", script]))
    }

    /// Writes `text` into the sandbox's file `path`.
    fn write(&self, path: &str, text: &str) {
        let file = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(file.path(), text).unwrap();
        ok(self.command("cp", Path::new("/")).arg(file.path()).arg(path));
    }

    fn local_cluster(&self, action: &str) -> Output {
        run(self.command(repo().join("deploy/slurm/local-cluster.sh"), Path::new("/")).arg(action))
    }

    fn up(&self) {
        let up = self.local_cluster("up");
        assert!(up.status.success(), "the sandbox's Slurm did not come up:\n{}", said(&up));
    }

    /// Submits `deploy/slurm/submit.sh` from `cwd` (3 partitions into `root`, `options`, then `generate` flags);
    /// the two job ids (array, merge).
    fn submit(&self, cwd: &Path, root: &Path, options: &[&str], generate: &[&str]) -> [String; 2] {
        let out = ok(self
            .command(repo().join("deploy/slurm/submit.sh"), cwd)
            .args(["--root", root.to_str().unwrap(), "--partitions", "3"])
            .args(options)
            .arg("--")
            .args(generate));
        let ids: Vec<String> = out
            .lines()
            .filter_map(|l| l.split_whitespace().find(|w| w.chars().all(|c| c.is_ascii_digit())).map(String::from))
            .collect();
        assert_eq!(ids.len(), 2, "two job ids in: {out}");
        [ids[0].clone(), ids[1].clone()]
    }

    /// Waits until none of `ids` is queued (or `timeout`); whether they all left.
    fn wait_gone(&self, ids: &[String], timeout: Duration) -> bool {
        let start = Instant::now();
        loop {
            let q = ok(self.command("squeue", Path::new("/")).args(["-h", "-j", &ids.join(",")]));
            if q.trim().is_empty() {
                return true;
            }
            if start.elapsed() > timeout {
                eprintln!("still queued after {timeout:?}:\n{q}");
                return false;
            }
            std::thread::sleep(Duration::from_millis(300));
        }
    }

    fn wait(&self, ids: &[String]) {
        assert!(self.wait_gone(ids, Duration::from_secs(900)), "the jobs did not finish");
    }

    /// A field of `scontrol show job ID` (the first record's).
    fn job_field(&self, id: &str, field: &str) -> String {
        let out = ok(self.command("scontrol", Path::new("/")).args(["show", "job", id]));
        let key = format!("{field}=");
        out.split_whitespace()
            .find_map(|w| w.strip_prefix(&key))
            .unwrap_or_else(|| panic!("no {field} in:\n{out}"))
            .to_string()
    }
}

impl Drop for Sandbox {
    fn drop(&mut self) {
        let down = self.local_cluster("down");
        eprintln!("sandbox: local-cluster.sh down: {}", said(&down).trim());
        let _ = self.unshare.kill();
        let _ = self.unshare.wait();
        // The namespace ends with its first process: wait until none of its processes is left.
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(20) && !self.processes().is_empty() {
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

fn merge_log(root: &Path, id: &str) -> String {
    std::fs::read_to_string(root.join(format!("dynforge-merge-{id}.log"))).unwrap_or_default()
}

/// The logs of job array `id`'s tasks, each under its name: what a failed assertion on its merge job shows (a merge
/// job cancelled by its dependency has no log of its own).
fn array_logs(root: &Path, id: &str) -> String {
    let prefix = format!("dynforge-generate-{id}_");
    let names = names_in(root).into_iter().filter(|n| n.starts_with(&prefix));
    names.map(|n| format!("--- {n}\n{}", std::fs::read_to_string(root.join(&n)).unwrap_or_default())).collect()
}

/// The names of the entries of `dir`, sorted (none if it cannot be read).
fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|d| d.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    names.sort();
    names
}

const TRAIN: &str = "--epochs 1 --generated 1024 --dim 32 --validation 0.34";

/// On the way: the merge job gets the CPUs asked for (`--merge-cpus`, default
/// `--cpus`), a relative `--dynforge` works, and `--prune-args` repeated builds each cache before the shards go.
#[test]
fn a_slurm_job_array_of_three_partitions_merges_into_the_single_host_dataset_and_trains() {
    if !engines("slurm job array") {
        return;
    }
    let sandbox = Sandbox::start();
    sandbox.up();

    let generate = ["--robots", "6", "--trajectories", "2", "--seed", "4"];
    let single = tempfile::tempdir().unwrap();
    generate_single(single.path(), &generate);

    // The binary given relative to where submit.sh runs (the jobs run elsewhere: --chdir at the root).
    let exe = Path::new(EXE);
    let cwd = exe.parent().unwrap().parent().unwrap();
    let relative = exe.strip_prefix(cwd).unwrap().to_str().unwrap();
    let root = tempfile::tempdir().unwrap();
    let options = ["--dynforge", relative, "--cpus", "1", "--merge-cpus", "2", "--train", TRAIN];
    let ids = sandbox.submit(cwd, root.path(), &options, &generate);
    sandbox.wait(&ids);
    let merged = root.path().join("merged");
    let log = merge_log(root.path(), &ids[1]);
    assert_eq!(sandbox.job_field(&ids[1], "JobState"), "COMPLETED", "merge job log:\n{log}");
    assert_eq!(sandbox.job_field(&ids[1], "NumCPUs"), "2", "--merge-cpus 2");
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

    // Bounded disk: each task builds two caches (the physics estimator's, the transformer's windows) and deletes the
    // shards; the merge combines the caches into the single host's, and trains the same weights.
    let pruned = tempfile::tempdir().unwrap();
    let options = ["--dynforge", EXE, "--cpus", "2", "--train", TRAIN];
    let prune = ["--prune-args", "--model physics", "--prune-args", "--model transformer --window 32:32:8"];
    let ids = sandbox.submit(Path::new("/"), pruned.path(), &[&options[..], &prune[..]].concat(), &generate);
    sandbox.wait(&ids);
    let merged = pruned.path().join("merged");
    let log = merge_log(pruned.path(), &ids[1]);
    assert_eq!(sandbox.job_field(&ids[1], "NumCPUs"), "2", "the merge job has --cpus by default");
    assert!(log.contains("12 shards (0 hard-linked, 0 copied, 12 pruned), 12 ledger records, 2 caches"), "{log}");
    assert!(shard_hashes(&merged).is_empty());
    let single_dir = single.path().to_str().unwrap();
    for cache in [&["--model", "physics"][..], &["--model", "transformer", "--window", "32:32:8"][..]] {
        let out = dynforge(&[&["dataset", "prepare", single_dir][..], cache].concat());
        assert!(out.status.success(), "{}", said(&out));
    }
    let (got, want) = (caches(&merged), caches(single.path()));
    assert_eq!(got.len(), 2, "two caches: {:?}", got.iter().map(|c| &c.0).collect::<Vec<_>>());
    assert!(got == want, "the combined caches differ from the single host's");
    let weights = |d: &Path| std::fs::read(d.join("model/model.safetensors")).unwrap();
    assert!(weights(pruned.path()) == weights(root.path()), "other weights from the same data:\n{log}");
}

/// Issue 24, items 1 and 2: `scancel` of the array cancels the merge job (it does not stay pending forever); the
/// merge job can be resubmitted after a failed training (a complete merge is kept, training runs again) and after
/// an interrupted merge (redone).
#[test]
fn a_cancelled_slurm_array_cancels_its_merge_and_a_resubmit_retries_a_failed_training() {
    if !engines("slurm cancel and retry") {
        return;
    }
    let sandbox = Sandbox::start();
    sandbox.up();
    let root = tempfile::tempdir().unwrap();
    let generate = ["--robots", "30", "--trajectories", "4", "--seed", "5"];
    let exe = ["--dynforge", EXE, "--cpus", "1"];

    // Cancelled while it runs: the merge's dependency can never be satisfied.
    let ids = sandbox.submit(Path::new("/"), root.path(), &[&exe[..], &["--train", TRAIN]].concat(), &generate);
    let start = Instant::now();
    loop {
        let running = ok(sandbox.command("squeue", Path::new("/")).args(["-h", "-t", "R", "-j", &ids[0]]));
        if !running.trim().is_empty() {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(60), "the array did not start");
        std::thread::sleep(Duration::from_millis(100));
    }
    ok(sandbox.command("scancel", Path::new("/")).arg(&ids[0]));
    let start = Instant::now();
    let gone = sandbox.wait_gone(&ids, Duration::from_secs(120));
    eprintln!("after scancel: the merge job left the queue in {:?}", start.elapsed());
    assert!(gone, "the merge job still waits for the cancelled array");
    // Gone from the queue is gone: a coordinator Slurm no longer tracks would still hold its partition's lock when
    // the resubmitted array starts, and refuse it.
    assert_eq!(sandbox.running("generate"), Vec::<String>::new(), "{}", array_logs(root.path(), &ids[0]));
    assert_eq!(sandbox.job_field(&ids[1], "JobState"), "CANCELLED");
    assert!(!root.path().join("merged").exists());

    // Resubmitted: the partitions resume and merge; the training fails (a bad flag).
    let bad = format!("{TRAIN} --no-such-flag");
    let ids = sandbox.submit(Path::new("/"), root.path(), &[&exe[..], &["--train", &bad]].concat(), &generate);
    sandbox.wait(&ids);
    let log = merge_log(root.path(), &ids[1]);
    assert_eq!(sandbox.job_field(&ids[1], "JobState"), "FAILED", "{log}\n{}", array_logs(root.path(), &ids[0]));
    assert!(log.contains("merged 3 partitions") && log.contains("--no-such-flag"), "{log}");
    let merged = root.path().join("merged");
    let hashes = shard_hashes(&merged);

    // Resubmitted with a good training: the complete merge is kept, and it trains.
    let ids = sandbox.submit(Path::new("/"), root.path(), &[&exe[..], &["--train", TRAIN]].concat(), &generate);
    sandbox.wait(&ids);
    let log = merge_log(root.path(), &ids[1]);
    assert_eq!(sandbox.job_field(&ids[1], "JobState"), "COMPLETED", "{log}");
    assert!(log.contains("already a complete merge of this run: merge skipped"), "{log}");
    assert!(root.path().join("model/checkpoint.json").is_file(), "{log}");

    // An interrupted merge (no manifest.toml: it is written last) is removed and done again.
    std::fs::remove_file(merged.join("manifest.toml")).unwrap();
    let ids = sandbox.submit(Path::new("/"), root.path(), &[&exe[..], &["--train", TRAIN]].concat(), &generate);
    sandbox.wait(&ids);
    let log = merge_log(root.path(), &ids[1]);
    assert_eq!(sandbox.job_field(&ids[1], "JobState"), "COMPLETED", "{log}");
    assert!(log.contains("(an interrupted merge): removing it and merging again"), "{log}");
    assert!(log.contains("merged 3 partitions"), "{log}");
    assert_eq!(shard_hashes(&merged), hashes);
    assert!(merged.join("manifest.toml").is_file());
}

/// scancel of a generating array: a task leaves the queue only once its command has stopped. The command here is a
/// stand-in for `dynforge` that takes two seconds to stop on SIGTERM, as a coordinator finishing its ledger takes a
/// moment, and says when it has; Slurm tracks a task's processes by descent, so a command whose script died first
/// ran on untracked, and the array was "gone" while it still held its partition.
#[test]
fn a_cancelled_array_task_leaves_the_queue_only_once_its_command_has_stopped() {
    if !engines("slurm cancel waits for the command") {
        return;
    }
    let sandbox = Sandbox::start();
    sandbox.up();
    let root = tempfile::tempdir().unwrap();
    let slow = root.path().join("slow-dynforge");
    std::fs::write(
        &slow,
        "#!/bin/sh\n\
         at=\"$DYNFORGE_ROOT/task-$SLURM_ARRAY_TASK_ID\"\n\
         trap 'sleep 2; touch \"$at.stopped\"; exit 143' TERM\n\
         touch \"$at.started\"\n\
         while :; do sleep 0.1; done\n",
    )
    .unwrap();
    std::fs::set_permissions(&slow, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let ids = sandbox.submit(Path::new("/"), root.path(), &["--dynforge", slow.to_str().unwrap(), "--cpus", "1"], &[]);
    // The tasks that have written `task-I{suffix}`.
    let tasks_with = |suffix: &str| -> Vec<String> {
        names_in(root.path()).iter().filter_map(|n| n.strip_suffix(suffix).map(str::to_string)).collect()
    };
    let start = Instant::now();
    while tasks_with(".started").is_empty() {
        assert!(start.elapsed() < Duration::from_secs(60), "no task started");
        std::thread::sleep(Duration::from_millis(100));
    }
    ok(sandbox.command("scancel", Path::new("/")).arg(&ids[0]));
    assert!(sandbox.wait_gone(&ids, Duration::from_secs(120)), "the cancelled array is still queued");
    let started = tasks_with(".started");
    assert_eq!(tasks_with(".stopped"), started, "tasks left the queue before their command stopped");
}

/// Issue 24, items 5 and 23: `local-cluster.sh up` refuses a slurm.conf it did not write and a daemon it did not
/// start that it would have to restart, backs up the file it replaces, and `down` stops exactly the daemons it
/// started (munged included); the host's own Slurm is untouched by all this.
#[test]
fn local_cluster_sh_takes_over_nothing_it_did_not_set_up_and_stops_exactly_what_it_started() {
    if !engines("local-cluster.sh") {
        return;
    }
    let host_before = host_slurm();
    let sandbox = Sandbox::start();
    let conf = "/etc/slurm/slurm.conf";
    let pids = |name: &str| {
        String::from_utf8_lossy(&sandbox.sh(&format!("pgrep -x {name} || true")).stdout).trim().to_string()
    };

    // A site's configuration: refused, left as it was, nothing started.
    let site = "ClusterName=site\nSlurmctldHost=head\n";
    sandbox.write(conf, site);
    let up = sandbox.local_cluster("up");
    assert_eq!(up.status.code(), Some(3), "{}", said(&up));
    assert!(said(&up).contains("was not written by this script"), "{}", said(&up));
    assert_eq!(String::from_utf8_lossy(&sandbox.sh(&format!("cat {conf}")).stdout), site);
    for d in ["munged", "slurmctld", "slurmd"] {
        assert_eq!(pids(d), "", "{d} started");
    }

    // Its own older configuration: replaced, the old one backed up.
    let marker = "# dynforge-local-cluster: written by deploy/slurm/local-cluster.sh (pids of the daemons it started: \
                  /var/lib/dynforge-local-cluster)";
    let old = format!("{marker}\nClusterName=dynforge-local\nNodeName=old\n");
    sandbox.write(conf, &old);
    sandbox.up();
    let backups = sandbox.sh("cat /var/lib/dynforge-local-cluster/backup/slurm.conf.*");
    assert_eq!(String::from_utf8_lossy(&backups.stdout), old, "the replaced file's backup");
    let started: Vec<String> = ["munged", "slurmctld", "slurmd"].iter().map(|d| pids(d)).collect();
    assert!(started.iter().all(|p| !p.is_empty() && !p.contains('\n')), "{started:?}");
    // Up again: the same daemons.
    sandbox.up();
    assert_eq!(["munged", "slurmctld", "slurmd"].iter().map(|d| pids(d)).collect::<Vec<_>>(), started);

    // A process named slurmd that is not its own: down stops its three daemons, and not that one.
    let decoys = tempfile::tempdir().unwrap();
    for name in ["slurmd", "slurmctld"] {
        std::fs::copy("/bin/sleep", decoys.path().join(name)).unwrap();
    }
    let mut decoy = sandbox.command(decoys.path().join("slurmd"), Path::new("/")).arg("600").spawn().unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let decoy_pid = pids("slurmd").lines().find(|p| *p != started[2]).expect("the decoy runs").to_string();
    let down = sandbox.local_cluster("down");
    assert!(down.status.success(), "{}", said(&down));
    for (d, pid) in ["munged", "slurmctld", "slurmd"].iter().zip(&started) {
        assert!(said(&down).contains(&format!("stopped {d} (pid {pid})")), "{}", said(&down));
    }
    assert!(said(&down).contains(&format!("left running: slurmd pid {decoy_pid}")), "{}", said(&down));
    assert_eq!(pids("munged"), "", "munged stopped");
    assert_eq!(pids("slurmctld"), "", "slurmctld stopped");
    assert_eq!(pids("slurmd"), decoy_pid, "only its own slurmd stopped");
    let _ = decoy.kill();
    let _ = decoy.wait();
    sandbox.sh(&format!("kill -KILL {decoy_pid}"));
    let start = Instant::now();
    while !pids("slurmd").is_empty() {
        assert!(start.elapsed() < Duration::from_secs(10), "the decoy slurmd does not go");
        std::thread::sleep(Duration::from_millis(50));
    }

    // A slurmctld it did not start, that a changed configuration would have to restart: refused, left running.
    let mut decoy = sandbox.command(decoys.path().join("slurmctld"), Path::new("/")).arg("600").spawn().unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let site_daemon = pids("slurmctld");
    sandbox.sh(&format!("sed -i 's/MaxTime=INFINITE/MaxTime=60/' {conf}"));
    let up = sandbox.local_cluster("up");
    assert_eq!(up.status.code(), Some(3), "{}", said(&up));
    assert!(said(&up).contains("runs and was not started by this script"), "{}", said(&up));
    assert_eq!(pids("slurmctld"), site_daemon, "the other slurmctld is left running");
    assert_eq!(pids("munged"), "", "nothing started");
    let _ = decoy.kill();
    let _ = decoy.wait();
    let ns = sandbox.ns.clone();
    drop(sandbox);
    let left = std::fs::read_dir("/proc")
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter(|pid| std::fs::read_link(format!("/proc/{pid}/ns/pid")).is_ok_and(|l| l == ns))
        .count();
    assert_eq!(left, 0, "processes of the sandbox outlived it");
    assert_eq!(host_slurm(), host_before, "the host's own Slurm changed");
}

/// The host's Slurm as the tests must leave it: its slurm.conf and its daemons' pids.
fn host_slurm() -> (Option<Vec<u8>>, String) {
    let conf = std::fs::read("/etc/slurm/slurm.conf").ok();
    // The host's own daemons only: the other Slurm tests' sandboxes run theirs in PID namespaces of their own,
    // which the host's /proc lists too (they come and go while this test runs).
    let own = format!("pgrep --ns {} --nslist pid -x 'munged|slurmctld|slurmd' || true", std::process::id());
    let pids = run(Command::new("sh").args(["-c", &own]));
    (conf, String::from_utf8_lossy(&pids.stdout).to_string())
}

// ---------------------------------------------------------------------------------------------------------------
// Kubernetes manifests

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

/// The rendered manifests as JSON documents (PyYAML of the reference venv).
fn manifest_objects(python: &str) -> Vec<serde_json::Value> {
    let mut child = Command::new(python)
        .args(["-c", "import sys, yaml, json; json.dump([d for d in yaml.safe_load_all(sys.stdin) if d], sys.stdout)"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::Write;
    child.stdin.take().unwrap().write_all(rendered_manifests().as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    serde_json::from_slice(&out.stdout).unwrap()
}

fn object<'a>(objects: &'a [serde_json::Value], kind: &str, name: &str) -> &'a serde_json::Value {
    objects
        .iter()
        .find(|o| o["kind"] == kind && o["metadata"]["name"] == name)
        .unwrap_or_else(|| panic!("no {kind} {name} rendered"))
}

/// Runs kubernetes-validate (strict: unknown fields are errors) on `yaml`; its verdict and output.
fn validate(python: &str, yaml: &str) -> (bool, String) {
    let file = tempfile::Builder::new().suffix(".yaml").tempfile().unwrap();
    std::fs::write(file.path(), yaml).unwrap();
    let validator = Path::new(python).with_file_name("kubernetes-validate");
    let out = Command::new(validator).args(["--strict", "-k", "1.31.0"]).arg(file.path()).output().unwrap();
    (out.status.success(), said(&out))
}

/// Also: the images are pulled only when absent, the volume names a storage class (a
/// placeholder for a ReadWriteMany one), and the files say what they need and mention nothing that is not there.
#[test]
fn the_kubernetes_manifests_render_and_pass_the_api_schema() {
    let Some(python) = dynforge_testkit::reference_python() else { return };
    let yaml = rendered_manifests();
    let (ok, out) = validate(&python, &yaml);
    assert!(ok, "{out}");
    for kind in
        ["namespace/dynforge", "persistentvolumeclaim/dynforge-data", "job/dynforge-generate", "job/dynforge-merge"]
    {
        assert!(out.contains(&format!("passed for resource {kind}")), "{kind} not checked:\n{out}");
    }
    // The validator is real: a misspelt field fails it.
    let (ok, out) = validate(&python, &yaml.replacen("parallelism:", "parallelizm:", 1));
    assert!(!ok && out.contains("'parallelizm' was unexpected"), "{out}");

    let objects = manifest_objects(&python);
    let generate = object(&objects, "Job", "dynforge-generate");
    // Index i is partition i/n: the Job runs n indices, n at once, and tells the pods n.
    let spec = &generate["spec"];
    assert_eq!(spec["completionMode"], "Indexed");
    assert_eq!(spec["parallelism"], spec["completions"]);
    let n = spec["completions"].to_string();
    assert_eq!(env(&generate["spec"]["template"]["spec"]["containers"][0], "PARTITIONS"), n);
    for job in ["dynforge-generate", "dynforge-merge"] {
        for c in object(&objects, "Job", job)["spec"]["template"]["spec"]["containers"].as_array().unwrap() {
            assert_eq!(c["imagePullPolicy"], "IfNotPresent", "{job}: {c}");
        }
    }
    let pvc = object(&objects, "PersistentVolumeClaim", "dynforge-data");
    assert_eq!(pvc["spec"]["accessModes"], serde_json::json!(["ReadWriteMany"]));
    assert_eq!(pvc["spec"]["storageClassName"], "replace-with-a-readwritemany-class");
    let k8s = repo().join("deploy/k8s");
    let read = |f: &str| std::fs::read_to_string(k8s.join(f)).unwrap();
    assert!(read("generate.yaml").contains("Needs Kubernetes >= 1.29: `backoffLimitPerIndex`"));
    assert!(read("volume.yaml").contains("it must be ReadWriteMany"));
    assert!(!read("kustomization.yaml").contains("patches"), "kustomization.yaml mentions patches it has not");
    let guide = std::fs::read_to_string(repo().join("deploy/README.md")).unwrap();
    for needed in ["1.29", "storageClassName", "imagePullPolicy", "podman push", "--ulimit nofile", ENGINE_TESTS] {
        assert!(guide.contains(needed), "deploy/README.md does not say {needed}");
    }
}

/// The value of the environment variable `name` of a rendered container.
fn env(container: &serde_json::Value, name: &str) -> String {
    container["env"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == name)
        .and_then(|e| e["value"].as_str())
        .unwrap_or_else(|| panic!("no {name} in {container}"))
        .to_string()
}

/// Issue 24, item 8: `run.sh` against a stand-in kubectl (`tests/engines/fake-kubectl.sh`, whose `wait` blocks as
/// kubectl's does): it refuses the storage-class placeholder, exits non-zero when a Job fails, and run again while
/// the merge runs it neither applies the merge Job again nor suspends it.
#[test]
fn run_sh_stops_on_a_failed_job_and_never_suspends_a_released_merge() {
    let bin = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink(repo().join("tests/engines/fake-kubectl.sh"), bin.path().join("kubectl")).unwrap();
    let path = format!("{}:{}", bin.path().display(), std::env::var("PATH").unwrap());
    let state = tempfile::tempdir().unwrap();
    let s = state.path();
    let rendered = rendered_manifests();
    let write = |f: &str, text: &str| std::fs::write(s.join(f), text).unwrap();
    let read = |f: &str| std::fs::read_to_string(s.join(f)).unwrap_or_default().trim().to_string();
    let start = || {
        Command::new(repo().join("deploy/k8s/run.sh"))
            .env("PATH", &path)
            .env("FAKE_K8S", s)
            .env("DYNFORGE_POLL_SECONDS", "0.1")
            .process_group(0)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    // Waits for run.sh to exit (at most 20 s: then it and its kubectl calls are killed); its exit code and output.
    let finish = |mut child: Child| {
        let start = Instant::now();
        while child.try_wait().unwrap().is_none() && start.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(50));
        }
        // SAFETY: a signal to the process group of run.sh, which this test started.
        unsafe { libc::kill(-(child.id() as i32), libc::SIGKILL) };
        let out = child.wait_with_output().unwrap();
        (out.status.code(), said(&out))
    };
    let until = |what: &str, cond: &dyn Fn() -> bool| {
        let start = Instant::now();
        while !cond() {
            assert!(start.elapsed() < Duration::from_secs(20), "{what} did not happen; calls:\n{}", read("calls"));
            std::thread::sleep(Duration::from_millis(50));
        }
    };

    // The placeholder storage class: refused before anything is applied.
    write("rendered.yaml", &rendered);
    let (code, out) = finish(start());
    assert_eq!(code, Some(2), "{out}");
    assert!(out.contains("storageClassName is still the placeholder") && !read("calls").contains("apply"), "{out}");

    // A generation that fails: run.sh says so and exits non-zero (kubectl wait for complete would wait forever).
    write("rendered.yaml", &rendered.replace("replace-with-a-readwritemany-class", "nfs"));
    let child = start();
    // The stand-in applies the Jobs one after the other: wait for both.
    until("the apply", &|| read("dynforge-generate.suspend") == "false" && !read("dynforge-merge.suspend").is_empty());
    assert_eq!(read("dynforge-merge.suspend"), "true", "the merge applied suspended");
    write("dynforge-generate.conditions", "FailureTarget Failed");
    let (code, out) = finish(child);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("job/dynforge-generate failed"), "{out}");
    assert_eq!(read("dynforge-merge.suspend"), "true", "a failed generation does not release the merge");

    // Retried (the failed Job deleted): the generation completes, the merge is released, and fails.
    std::fs::remove_file(s.join("dynforge-generate.exists")).unwrap();
    std::fs::remove_file(s.join("dynforge-generate.conditions")).unwrap();
    let child = start();
    until("the apply", &|| s.join("dynforge-generate.exists").exists());
    write("dynforge-generate.conditions", "SuccessCriteriaMet Complete");
    until("the release", &|| read("dynforge-merge.suspend") == "false");
    // run.sh run again while the merge runs: the merge is not applied again (which would suspend it).
    std::fs::write(s.join("calls"), "").unwrap();
    let again = start();
    until("the second run's apply", &|| read("calls").contains("apply"));
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(
        read("dynforge-merge.suspend"),
        "false",
        "the second run suspended the running merge:\n{}",
        read("calls")
    );
    write("dynforge-merge.conditions", "Failed");
    let (code, out) = finish(child);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("job/dynforge-merge failed"), "{out}");
    let (code, out) = finish(again);
    assert_eq!(code, Some(1), "{out}");

    // And a merge that completes: exit 0.
    write("dynforge-merge.conditions", "Complete");
    let (code, out) = finish(start());
    assert_eq!(code, Some(0), "{out}");
    assert_eq!(read("dynforge-merge.suspend"), "false");
}

// ---------------------------------------------------------------------------------------------------------------
// Containers

/// `--ulimit` for podman: nofile the host's hard limit, nproc 4096 (podman's defaults exceed a low hard limit of
/// the host, and runc then cannot start the container; its conmon holds nproc at most 32768 here).
fn ulimits() -> Vec<String> {
    let hard = ok(Command::new("sh").args(["-c", "ulimit -Hn"]));
    ["--ulimit".into(), format!("nofile={0}:{0}", hard.trim()), "--ulimit".into(), "nproc=4096:4096".into()].to_vec()
}

fn podman() -> Command {
    let mut cmd = Command::new("podman");
    cmd.args(["--runtime", "runc"]);
    cmd
}

/// The test image (this build's binary, the debootstrap base), built once per test run by `build.sh` with podman.
/// Its tag is this target directory's own, so test runs of other checkouts do not share it.
fn image() -> &'static str {
    static IMAGE: OnceLock<String> = OnceLock::new();
    IMAGE.get_or_init(|| {
        let tag = format!("localhost/dynforge:test-{:016x}", dynforge_proto::content_hash(EXE.as_bytes()));
        let build = run(Command::new(repo().join("deploy/container/build.sh")).args([
            "--binary",
            EXE,
            "--engine",
            "podman",
            "--offline-base",
            "--install",
            "--tag",
            &tag,
        ]));
        assert!(build.status.success(), "image build failed:\n{}", said(&build));
        tag
    })
}

/// A container removed when dropped.
struct Container(String);

impl Container {
    fn name(n: &str) -> Container {
        let c = Container(format!("dynforge-test-{n}-{}", std::process::id()));
        c.remove();
        c
    }

    /// Removes the container if it exists. Without podman (not installed yet: the image's build installs it)
    /// there is none to remove.
    fn remove(&self) {
        let _ = podman().args(["rm", "-f", "-t", "0", &self.0]).stdin(Stdio::null()).output();
    }
}

impl Drop for Container {
    fn drop(&mut self) {
        self.remove();
    }
}

#[test]
fn the_container_image_builds_and_generates_the_same_shards_as_the_host() {
    if !engines("container image") {
        return;
    }
    let tag = image();
    // Issue 24, item 10: the debootstrap base keeps no apt archives or lists.
    let listing = ok(podman().args(["run", "--rm", "--network=none"]).args(ulimits()).args([
        "--entrypoint",
        "/bin/sh",
        tag,
        "-c",
        "ls -A /var/cache/apt/archives /var/lib/apt/lists",
    ]));
    assert!(!listing.contains(".deb") && !listing.contains("_Packages"), "apt's files in the image:\n{listing}");

    let host = tempfile::tempdir().unwrap();
    let args = ["--robots", "1", "--trajectories", "2", "--workers", "2", "--seed", "4"];
    let mut generate = vec!["generate", "--out", host.path().to_str().unwrap()];
    generate.extend(args);
    assert!(dynforge(&generate).status.success());

    let volume = tempfile::tempdir().unwrap();
    let mount = format!("{}:/data", volume.path().display());
    let out = run(podman()
        .args(["run", "--rm", "--network=none", "--shm-size=256m"])
        .args(ulimits())
        .args(["-v", &mount, tag, "generate", "--out", "/data/run"])
        .args(args));
    assert!(out.status.success(), "generate in the container:\n{}", said(&out));
    assert_eq!(shard_hashes(&volume.path().join("run")), shard_hashes(host.path()), "the same shards");
}

/// `podman run` of a rendered Job's pod: its image, its exact command and args, its environment with `env`'s
/// values instead, the volume at /data and a shared memory as its emptyDir.
fn pod(container: &serde_json::Value, name: &str, data: &Path, env: &[(&str, &str)], detach: bool) -> Command {
    let mut cmd = podman();
    cmd.args(["run", "--name", name, "--network=none", "--shm-size=256m"]).args(ulimits());
    if detach {
        cmd.arg("-d");
    }
    cmd.args(["-v", &format!("{}:/data", data.display())]);
    for e in container["env"].as_array().unwrap() {
        let key = e["name"].as_str().unwrap();
        let value = env.iter().find(|(k, _)| *k == key).map_or(e["value"].as_str().unwrap(), |(_, v)| v);
        cmd.args(["-e", &format!("{key}={value}")]);
    }
    for (k, v) in env {
        if !container["env"].as_array().unwrap().iter().any(|e| e["name"] == *k) {
            cmd.args(["-e", &format!("{k}={v}")]);
        }
    }
    let command: Vec<&str> = container["command"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
    cmd.arg(format!("--entrypoint={}", serde_json::to_string(&command).unwrap())).arg(image());
    for a in container["args"].as_array().unwrap() {
        cmd.arg(a.as_str().unwrap());
    }
    cmd
}

fn job_container<'a>(objects: &'a [serde_json::Value], job: &str) -> &'a serde_json::Value {
    &object(objects, "Job", job)["spec"]["template"]["spec"]["containers"][0]
}

/// Issue 24, item 6: the generation pod's SIGTERM (`podman stop`, as the kubelet on deletion or eviction) reaches
/// the coordinator, which logs its interruption and exits by itself well within the grace period (not SIGKILL's
/// 137), with and without PRUNE (dynforge as PID 1, or the shell passing the signal on).
#[test]
fn the_generation_pod_stops_on_sigterm_by_itself() {
    if !engines("pod signals") {
        return;
    }
    let Some(python) = dynforge_testkit::reference_python() else { return };
    let objects = manifest_objects(&python);
    let container = job_container(&objects, "dynforge-generate");
    for prune in ["", "yes"] {
        let data = tempfile::tempdir().unwrap();
        let name = Container::name(&format!("sigterm{}", prune.len()));
        let env = [
            ("JOB_COMPLETION_INDEX", "0"),
            ("PARTITIONS", "2"),
            ("WORKERS", "2"),
            ("GENERATE_ARGS", "--robots 2000 --trajectories 16 --seed 3"),
            ("PRUNE", prune),
        ];
        ok(&mut pod(container, &name.0, data.path(), &env, true));
        let ledger = data.path().join("run/part-0/ledger.tsv");
        let start = Instant::now();
        while std::fs::read_to_string(&ledger).map_or(0, |l| l.lines().count()) < 2 {
            assert!(
                start.elapsed() < Duration::from_secs(120),
                "no job done: {}",
                said(&run(podman().args(["logs", &name.0])))
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        let start = Instant::now();
        ok(podman().args(["stop", "-t", "10", &name.0]));
        let took = start.elapsed();
        let logs = said(&run(podman().args(["logs", &name.0])));
        let code = ok(podman().args(["inspect", "--format", "{{.State.ExitCode}}", &name.0]));
        eprintln!("PRUNE={prune:?}: stopped in {took:?}, exit {}", code.trim());
        assert_ne!(code.trim(), "137", "SIGKILLed after the grace period (PRUNE={prune:?}):\n{logs}");
        assert!(took < Duration::from_secs(9), "{took:?}");
        assert!(logs.contains("interrupted"), "no interruption logged (PRUNE={prune:?}):\n{logs}");
        // Resumable: the partition's lock was released with the coordinator.
        let status = dynforge(&["status", data.path().join("run/part-0").to_str().unwrap()]);
        assert!(said(&status).starts_with("not running"), "{}", said(&status));
    }
}

/// Issue 24, items 2 and 13 on Kubernetes, with the pods' exact commands under podman: each generation pod builds
/// the caches PRUNE_ARGS lists and prunes, the merge pod combines them into the single host's; run again after a
/// failed training it keeps the complete merge and trains; after an interrupted merge it merges again.
#[test]
fn the_kubernetes_pods_prune_to_several_caches_and_the_merge_pod_can_run_again() {
    if !engines("kubernetes pods") {
        return;
    }
    let Some(python) = dynforge_testkit::reference_python() else { return };
    let objects = manifest_objects(&python);
    let generate = ["--robots", "6", "--trajectories", "2", "--seed", "4"];
    let single = tempfile::tempdir().unwrap();
    generate_single(single.path(), &generate);
    let data = tempfile::tempdir().unwrap();
    let container = job_container(&objects, "dynforge-generate");
    let args = generate.join(" ");
    for i in 0..3 {
        let name = Container::name(&format!("generate{i}"));
        let index = i.to_string();
        let env = [
            ("JOB_COMPLETION_INDEX", index.as_str()),
            ("PARTITIONS", "3"),
            ("WORKERS", "2"),
            ("GENERATE_ARGS", args.as_str()),
            ("PRUNE", "yes"),
            ("PRUNE_ARGS", "--model physics\n\n--model transformer --window 32:32:8\n"),
        ];
        let out = run(&mut pod(container, &name.0, data.path(), &env, false));
        assert!(out.status.success(), "pod {i}:\n{}", said(&out));
        assert!(shard_hashes(&data.path().join(format!("run/part-{i}"))).is_empty(), "pruned");
    }

    let container = job_container(&objects, "dynforge-merge");
    let merge = |name: &str, train: &str| {
        let name = Container::name(name);
        run(&mut pod(container, &name.0, data.path(), &[("TRAIN_ARGS", train)], false))
    };
    let out = merge("merge1", &format!("{TRAIN} --no-such-flag"));
    assert!(!out.status.success() && said(&out).contains("merged 3 partitions"), "{}", said(&out));
    let merged = data.path().join("run/merged");
    for cache in [&["--model", "physics"][..], &["--model", "transformer", "--window", "32:32:8"][..]] {
        let out = dynforge(&[&["dataset", "prepare", single.path().to_str().unwrap()][..], cache].concat());
        assert!(out.status.success(), "{}", said(&out));
    }
    let want = caches(single.path());
    assert_eq!(want.len(), 2);
    assert!(caches(&merged) == want, "the combined caches differ from the single host's");

    let out = merge("merge2", TRAIN);
    assert!(out.status.success(), "{}", said(&out));
    assert!(said(&out).contains("already a complete merge of this run: merge skipped"), "{}", said(&out));
    assert!(data.path().join("run/model/checkpoint.json").is_file());

    std::fs::remove_file(merged.join("manifest.toml")).unwrap();
    let out = merge("merge3", TRAIN);
    assert!(out.status.success(), "{}", said(&out));
    assert!(said(&out).contains("(an interrupted merge): removing it and merging again"), "{}", said(&out));
    assert_eq!(
        std::fs::read(merged.join("manifest.toml")).unwrap(),
        std::fs::read(single.path().join("manifest.toml")).unwrap()
    );
}

/// A dockerd of the test's own (its socket, data and pid file in a temporary directory), stopped when dropped.
struct Dockerd {
    child: Child,
    dir: tempfile::TempDir,
}

impl Dockerd {
    fn start() -> Dockerd {
        install(&["docker.io"]);
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().to_path_buf();
        let log = std::fs::File::create(d.join("dockerd.log")).unwrap();
        let child = Command::new("dockerd")
            .arg(format!("--data-root={}", d.join("root").display()))
            .arg(format!("--exec-root={}", d.join("exec").display()))
            .arg(format!("--pidfile={}", d.join("dockerd.pid").display()))
            .arg(format!("--host=unix://{}", d.join("docker.sock").display()))
            .args(["--bridge=none", "--iptables=false", "--ip6tables=false", "--containerd-namespace=dynforge-test"])
            .arg("--containerd-plugins-namespace=dynforge-test-plugins")
            .stdin(Stdio::null())
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .spawn()
            .unwrap();
        let mut dockerd = Dockerd { child, dir };
        let start = Instant::now();
        while !run(Command::new("docker").env("DOCKER_HOST", dockerd.host()).arg("info")).status.success() {
            let log = std::fs::read_to_string(d.join("dockerd.log")).unwrap_or_default();
            assert!(dockerd.child.try_wait().unwrap().is_none(), "dockerd exited:\n{log}");
            assert!(start.elapsed() < Duration::from_secs(60), "dockerd did not start:\n{log}");
            std::thread::sleep(Duration::from_millis(200));
        }
        dockerd
    }

    fn host(&self) -> String {
        format!("unix://{}", self.dir.path().join("docker.sock").display())
    }
}

impl Drop for Dockerd {
    fn drop(&mut self) {
        // SIGTERM: dockerd stops its containers and its containerd, then exits; SIGKILL after 30 s.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        let start = Instant::now();
        while self.child.try_wait().unwrap().is_none() {
            if start.elapsed() > Duration::from_secs(30) {
                let _ = self.child.kill();
                let _ = self.child.wait();
                break;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        let _ = Command::new("umount").arg("-R").arg(self.dir.path().join("root")).stderr(Stdio::null()).status();
    }
}

/// Issue 24, item 10: build.sh with docker (the real docker engine: a dockerd of the test's own): the cached base
/// is found (docker has no `image exists`) and named as docker names it, the image has no apt archives or lists,
/// and it runs.
#[test]
fn build_sh_builds_the_image_with_docker() {
    if !engines("build.sh with docker") {
        return;
    }
    let dockerd = Dockerd::start();
    let build = || {
        run(Command::new(repo().join("deploy/container/build.sh")).env("DOCKER_HOST", dockerd.host()).args([
            "--engine",
            "docker",
            "--binary",
            EXE,
            "--offline-base",
            "--install",
            "--tag",
            "dynforge:docker-test",
        ]))
    };
    let first = build();
    assert!(first.status.success(), "{}", said(&first));
    assert!(said(&first).contains("made the base image dynforge-base:bookworm-min"), "{}", said(&first));
    let again = build();
    assert!(again.status.success(), "{}", said(&again));
    assert!(said(&again).contains("using the cached base image dynforge-base:bookworm-min"), "{}", said(&again));
    let docker = || {
        let mut cmd = Command::new("docker");
        cmd.env("DOCKER_HOST", dockerd.host());
        cmd
    };
    let version = ok(docker().args(["run", "--rm", "--network=none", "dynforge:docker-test", "--version"]));
    assert!(version.starts_with("dynforge "), "{version}");
    let listing = ok(docker().args([
        "run",
        "--rm",
        "--network=none",
        "--entrypoint",
        "/bin/sh",
        "dynforge:docker-test",
        "-c",
        "ls -A /var/cache/apt/archives /var/lib/apt/lists",
    ]));
    assert!(!listing.contains(".deb") && !listing.contains("_Packages"), "apt's files in the image:\n{listing}");
}
