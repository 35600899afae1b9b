//! End-to-end tests of the hostile cases an operator campaign found: the real binary, real
//! processes, real kills. Each case is one that failed before its fix.

mod common;

use common::{children_of, dynforge};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const EXE: &str = env!("CARGO_BIN_EXE_dynforge");

fn arg(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Runs `dynforge args` and returns its stdout, failing the test with its stderr if it fails.
fn ok(args: &[&str]) -> String {
    let o = dynforge(args);
    assert!(o.status.success(), "dynforge {}: {}", args.join(" "), stderr(&o));
    stdout(&o)
}

/// A finished run of `robots` x `trajectories` (seed 3) in `dir`.
fn generate(dir: &Path, robots: u32, trajectories: u32) {
    let (r, t) = (robots.to_string(), trajectories.to_string());
    ok(&["generate", "--out", arg(dir), "--robots", &r, "--trajectories", &t, "--seed", "3", "--workers", "2"]);
}

fn shards(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir.join("shards")).unwrap().map(|e| e.unwrap().path()).collect();
    v.sort();
    v
}

/// Item 14: a prepare that could not read a shard writes no cache, so a later `prepare --prune` cannot take a cache
/// without that shard's data for a complete one and delete the shard.
#[test]
fn a_shard_that_could_not_be_cached_is_never_pruned_without_its_data() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    generate(&dir, 4, 2);
    let all = shards(&dir);
    let saved = std::fs::read(&all[3]).unwrap();
    std::fs::write(&all[3], &saved[..1000]).unwrap();
    let o = dynforge(&["dataset", "prepare", arg(&dir)]);
    assert!(!o.status.success() && stderr(&o).contains("1 shard(s) could not be cached"), "{}", stderr(&o));
    let cached = std::fs::read_dir(dir.join("cache")).map_or(0, |l| l.count());
    assert_eq!(cached, 0, "a cache without the unreadable shard was written");

    std::fs::write(&all[3], &saved).unwrap();
    let said = ok(&["dataset", "prepare", arg(&dir), "--prune"]);
    assert!(said.contains(&format!("and {} recordings", all.len())), "not every shard is cached: {said}");
    assert!(said.contains(&format!("{} shards pruned", all.len())), "{said}");
    ok(&["verify", arg(&dir)]);
}

/// Item 14: a plain `prepare` takes the run's lock, so it cannot replace the complete cache of a prune in progress
/// with one read from shards being deleted; and it is told what holds the directory (item 22).
#[test]
fn prepare_during_a_prune_is_refused_naming_the_prune() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    generate(&dir, 4, 2);
    let n = shards(&dir).len();
    let prune = Command::new(EXE)
        .args(["dataset", "prepare", arg(&dir), "--prune"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The prune fits the generator's prior (seconds) with the lock held.
    let start = Instant::now();
    while dynforge_proto::lock::holder(&dir).is_none() {
        assert!(start.elapsed() < Duration::from_secs(60), "the prune never took the lock");
        std::thread::sleep(Duration::from_millis(10));
    }
    let o = dynforge(&["dataset", "prepare", arg(&dir)]);
    let prune = prune.wait_with_output().unwrap();
    assert!(prune.status.success(), "{}", stderr(&prune));
    assert!(!o.status.success(), "a prepare ran during the prune: {}", stdout(&o));
    assert!(stderr(&o).contains("another dataset prepare --prune is using this directory (pid "), "{}", stderr(&o));
    let said = ok(&["dataset", "prepare", arg(&dir)]);
    assert!(said.contains(&format!("and {n} recordings (already cached)")), "{said}");
}

/// Item 22: a command refused by a run directory's lock is told which command holds it (a `prepare` was reported as
/// "another generate").
#[test]
fn a_refused_command_names_the_command_holding_the_directory() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    let _lock = dynforge_proto::lock::RunLock::acquire(&dir, Duration::ZERO, "dataset prepare").unwrap();
    let o = dynforge(&["generate", "--out", arg(&dir), "--robots", "1", "--trajectories", "1"]);
    let e = stderr(&o);
    assert!(!o.status.success() && e.contains("another dataset prepare is using this directory (pid "), "{e}");
    assert!(!dir.join("manifest.toml").exists(), "the refused generate wrote its manifest");
}

/// Item 19: a symbolic link planted in a run directory as its lock, its ledger or a worker's log makes `generate`
/// refuse, naming it, instead of truncating, overwriting or appending to the file it points at.
#[test]
fn links_planted_in_a_run_directory_are_refused_not_written_through() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    generate(&dir, 2, 2);
    let outside = root.path().join("outside.txt");
    std::fs::write(&outside, b"precious\n").unwrap();
    for name in ["lock", "ledger.tsv", "logs/worker-0.log"] {
        let path = dir.join(name);
        let saved = std::fs::read(&path).unwrap_or_default();
        let _ = std::fs::remove_file(&path);
        std::os::unix::fs::symlink(&outside, &path).unwrap();
        // One more robot: workers start and the ledger is appended to.
        let o = dynforge(&["generate", "--out", arg(&dir), "--robots", "3", "--trajectories", "2", "--seed", "3"]);
        let e = stderr(&o);
        assert!(!o.status.success() && e.contains(name) && e.contains("symbolic link"), "{name}: {e}");
        assert_eq!(std::fs::read(&outside).unwrap(), b"precious\n", "written through {name}");
        std::fs::remove_file(&path).unwrap();
        std::fs::write(&path, saved).unwrap();
    }
    ok(&["generate", "--out", arg(&dir), "--robots", "3", "--trajectories", "2", "--seed", "3"]);
    ok(&["verify", arg(&dir)]);
}

/// `dynforge args` with `env`, which must end within `limit`: killed and reported otherwise.
fn bounded(args: &[&str], env: &[(&str, &str)], limit: Duration) -> Output {
    let child = Command::new(EXE)
        .args(args)
        .envs(env.iter().copied())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_bounded(child, limit)
}

fn wait_bounded(mut child: std::process::Child, limit: Duration) -> Output {
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            let o = child.wait_with_output().unwrap();
            panic!("still running after {limit:?}: {}", stderr(&o));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.wait_with_output().unwrap()
}

/// Item 15: a worker that never gets through its start-up (stopped, stuck) is replaced after the start deadline, and
/// after three failed starts in a row the run ends with an error naming the worker's log, instead of waiting with
/// nothing in flight for ever.
#[test]
fn workers_that_never_start_end_the_run_with_an_error_naming_their_log() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    let args = ["generate", "--out", arg(&dir), "--robots", "1", "--trajectories", "2", "--workers", "1"];
    let o = bounded(
        &[&args[..], &["--job-timeout", "1"]].concat(),
        &[("DYNFORGE_FAULT_WORKER_START_STALL", "3600")],
        Duration::from_secs(120),
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("no worker could be started") && e.contains("was not ready within 5 s"), "{e}");
    assert!(e.contains(&format!("{}", dir.join("logs").join("worker-0.log").display())), "{e}");
    assert_eq!(e.matches("starting it again").count(), 2, "{e}");
    // Nothing was lost: the same command without the fault does the jobs.
    let o = bounded(&args, &[], Duration::from_secs(120));
    assert!(o.status.success(), "{}", stderr(&o));
    ok(&["verify", arg(&dir)]);
}

/// Item 15: replacement workers that fail at once (here: garbage appended to the manifest mid-run) are not restarted
/// for ever: the run ends, saying why and where the worker's log is; once the manifest is repaired it resumes.
#[test]
fn replacement_workers_that_fail_at_start_end_the_run_with_their_error() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    let args = ["generate", "--out", arg(&dir), "--robots", "6", "--trajectories", "16", "--workers", "2"];
    let child = Command::new(EXE).args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let ledger = dir.join("ledger.tsv");
    let start = Instant::now();
    while std::fs::read_to_string(&ledger).map_or(0, |l| l.lines().count()) < 3 {
        assert!(start.elapsed() < Duration::from_secs(60), "no progress");
        std::thread::sleep(Duration::from_millis(20));
    }
    let manifest = std::fs::read(dir.join("manifest.toml")).unwrap();
    let mut broken = manifest.clone();
    broken.extend(b"garbage\n");
    std::fs::write(dir.join("manifest.toml"), &broken).unwrap();
    for w in children_of(child.id()) {
        let _ = Command::new("kill").args(["-9", &w.to_string()]).status();
    }
    let o = wait_bounded(child, Duration::from_secs(60));
    let e = stderr(&o);
    assert!(!o.status.success(), "{e}");
    assert!(e.contains("no worker could be started") && e.contains("not a dynforge run manifest"), "{e}");
    assert!(e.contains("worker-0.log") || e.contains("worker-1.log"), "{e}");
    std::fs::write(dir.join("manifest.toml"), &manifest).unwrap();
    let o = bounded(&args, &[], Duration::from_secs(300));
    assert!(o.status.success(), "{}", stderr(&o));
    ok(&["verify", arg(&dir)]);
}

/// Item 15: the run's shared-memory files are its user's alone (iceoryx2 makes its management segment writable by
/// everyone: another user wrote into it, and every worker started after failed).
#[test]
fn a_runs_shared_memory_is_writable_by_its_owner_only() {
    use std::os::unix::fs::PermissionsExt;
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    let args = ["generate", "--out", arg(&dir), "--robots", "2", "--trajectories", "2", "--workers", "2"];
    // Each job stalls: the run stays live while its files are looked at.
    let child = Command::new(EXE)
        .args(args)
        .env("DYNFORGE_FAULT_WORKER_STALL", "30")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let prefix = format!("{}_", dynforge_ipc::RunId::for_dir(&dir).unwrap());
    let files = || -> Vec<(String, u32)> {
        std::fs::read_dir("/dev/shm")
            .unwrap()
            .filter_map(Result::ok)
            .filter(|e| e.file_name().to_string_lossy().starts_with(&prefix))
            .filter_map(|e| {
                Some((e.file_name().to_string_lossy().into_owned(), e.metadata().ok()?.permissions().mode()))
            })
            .collect()
    };
    let start = Instant::now();
    // Both workers joined: their jobs' services exist, the management segment too.
    while !files().iter().any(|(n, _)| n.ends_with("global_mgmt")) || children_of(child.id()).len() < 2 {
        assert!(start.elapsed() < Duration::from_secs(60), "the run never started: {:?}", files());
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    let open: Vec<(String, u32)> = files().into_iter().filter(|(_, mode)| mode & 0o022 != 0).collect();
    let _ = Command::new("kill").args(["-TERM", &child.id().to_string()]).status();
    let _ = wait_bounded(child, Duration::from_secs(60));
    assert!(open.is_empty(), "writable by others: {open:?}");
}

/// Item 16: `train --resume` on another data directory refuses, naming both, and keeps the model it has.
#[test]
fn a_resume_on_other_data_is_refused_naming_both_directories() {
    let root = tempfile::tempdir().unwrap();
    let (a, b, run) = (root.path().join("a"), root.path().join("b"), root.path().join("ckpt"));
    generate(&a, 5, 2);
    generate(&b, 5, 2);
    let train = |data: &Path, extra: &[&str]| {
        let args = ["train", arg(data), "--out", arg(&run), "--generated", "256"];
        dynforge(&[&args[..], extra].concat())
    };
    let o = train(&a, &["--epochs", "1"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let model = std::fs::read(run.join("model.safetensors")).unwrap();
    let o = train(&b, &["--resume", "--epochs", "2"]);
    let e = stderr(&o);
    assert!(!o.status.success(), "resumed on other data: {e}");
    let canonical = |p: &Path| p.canonicalize().unwrap().display().to_string();
    assert!(e.contains(&canonical(&a)) && e.contains(&canonical(&b)), "{e}");
    assert_eq!(std::fs::read(run.join("model.safetensors")).unwrap(), model, "the model was replaced");
    // Its own data resume it.
    let o = train(&a, &["--resume", "--epochs", "2"]);
    assert!(o.status.success() && stderr(&o).contains("resuming"), "{}", stderr(&o));
}

/// Item 17: a training killed (kill -9) before its first save leaves a description without a resume state; `train
/// --resume` trains it again from its start instead of refusing both ways.
#[test]
fn a_training_killed_before_its_first_save_resumes() {
    let root = tempfile::tempdir().unwrap();
    let (data, run) = (root.path().join("data"), root.path().join("ckpt"));
    generate(&data, 5, 2);
    // Many generated robots: epoch 0 takes seconds, and its description is written before it.
    let args = ["train", arg(&data), "--out", arg(&run), "--epochs", "1", "--generated", "400000"];
    let mut child = Command::new(EXE).args(args).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
    let start = Instant::now();
    while !run.join("checkpoint.json").exists() {
        assert!(child.try_wait().unwrap().is_none() && start.elapsed() < Duration::from_secs(120), "no description");
        std::thread::sleep(Duration::from_millis(10));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(!run.join("train").join("state.json").exists(), "killed too late: a state was saved");
    let o = dynforge(&["train", arg(&data), "--out", arg(&run), "--epochs", "1", "--generated", "256"]);
    assert!(!o.status.success() && stderr(&o).contains("--resume"), "{}", stderr(&o));
    let o = dynforge(&["train", arg(&data), "--out", arg(&run), "--epochs", "1", "--generated", "256", "--resume"]);
    let e = stderr(&o);
    assert!(o.status.success() && e.contains("training it again from its start"), "{e}");
    assert!(run.join("model.safetensors").exists() && run.join("train").join("state.json").exists());
}

/// A copy of the shard `from` as a user's log at `to`: its robot description and joint states, each stamp moved by
/// `shift(k, stamp_ns)`, no dataset metadata.
fn log_from_shard(from: &Path, to: &Path, shift: impl Fn(usize, i64) -> i64) {
    let bag = dynforge_shard::read(from).unwrap();
    let states: Vec<_> = bag
        .joint_states
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let t = shift(k, m.stamp_ns());
            dynforge_proto::shard::JointState {
                sec: (t / 1_000_000_000) as i32,
                nanosec: (t % 1_000_000_000) as u32,
                ..m.clone()
            }
        })
        .collect();
    let urdf = bag.robot_description.unwrap();
    let metadata = Default::default();
    dynforge_shard::write(
        to,
        &dynforge_shard::ShardContent { urdf: &urdf, joint_states: &states, metadata: &metadata },
    )
    .unwrap();
}

/// Item 18: a log whose stamps jump (one moved by an hour, or a day) is refused at once by `estimate`, naming the
/// gap, instead of being put on the 1 kHz grid whole (a day: an allocation that aborts; an hour: 6.5 GB and 23 s);
/// `info` says where the gap is, and `identify` reads the stretches on both sides apart.
#[test]
fn a_log_with_a_gap_is_refused_at_once_by_estimate_and_shown_by_info() {
    let root = tempfile::tempdir().unwrap();
    let (data, run) = (root.path().join("data"), root.path().join("ckpt"));
    generate(&data, 5, 2);
    ok(&["train", arg(&data), "--out", arg(&run), "--epochs", "1", "--generated", "256"]);
    let shard = &shards(&data)[0];
    for (gap_s, name) in [(3600, "hour.mcap"), (86_400, "day.mcap")] {
        let log = root.path().join(name);
        log_from_shard(shard, &log, |k, t| if k >= 1500 { t + gap_s * 1_000_000_000 } else { t });
        let start = Instant::now();
        let out = root.path().join("out.urdf");
        let o = bounded(
            &["estimate", "--checkpoint", arg(&run), arg(&log), "--out", arg(&out)],
            &[],
            Duration::from_secs(60),
        );
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{e}");
        assert!(e.contains(name) && e.contains(&format!("jump by {gap_s}.001 s after t = 1.499 s")), "{e}");
        assert!(start.elapsed() < Duration::from_secs(20), "{:?} to refuse", start.elapsed());
        let said = ok(&["info", arg(&log)]);
        assert!(said.contains(&format!("Gaps:        1 (the first {gap_s}.001 s long, after t = 1.499 s)")), "{said}");
        assert!(!said.contains("NaN") && said.contains("1000.0 Hz (median period)"), "{said}");
    }
    for name in ["hour.mcap", "day.mcap"] {
        let out = root.path().join(format!("{name}.urdf"));
        let o = bounded(&["identify", arg(&root.path().join(name)), "--out", arg(&out)], &[], Duration::from_secs(60));
        assert!(o.status.success(), "{name}: {}", stderr(&o));
        let said = stdout(&o) + &stderr(&o);
        assert!(said.contains("1 gap(s) in the stamps: identified as 2 separate stretches"), "{name}: {said}");
        assert!(out.exists(), "{name}: no calibrated URDF");
    }
}

/// Items 20 and 22: flags out of range are refused before anything runs, saying what the flag takes: no panic, no
/// abort, no message about something else.
#[test]
fn flags_out_of_range_are_refused_saying_what_they_take() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    let refused = |args: &[&str], said: &str| {
        let o = bounded(args, &[], Duration::from_secs(120));
        let e = stderr(&o);
        assert!(matches!(o.status.code(), Some(1 | 2)), "{args:?}: {:?} {e}", o.status);
        assert!(e.contains(said), "{args:?}: {e}");
    };
    let generating = ["generate", "--out", arg(&dir), "--trajectories", "1"];
    refused(&[&generating[..], &["--robots", "-1"]].concat(), "'--robots <ROBOTS>': expected a whole number from 1 to");
    refused(&[&generating[..], &["--robots", "10000000000"]].concat(), "expected a whole number from 1 to 100000000");
    assert!(!dir.join("manifest.toml").exists(), "a refused run wrote its manifest");
    // More workers than a few per core only cost memory: started are 4 per core.
    let o =
        bounded(&[&generating[..], &["--robots", "64", "--workers", "10000"]].concat(), &[], Duration::from_secs(300));
    assert!(o.status.success() && stderr(&o).contains("--workers 10000: starting "), "{}", stderr(&o));
    let cores = std::thread::available_parallelism().unwrap().get();
    let started = std::fs::read_dir(dir.join("logs")).unwrap().count();
    assert!(started <= 4 * cores, "{started} worker processes started on {cores} cores");

    let data = root.path().join("data");
    generate(&data, 5, 2);
    let ckpt = root.path().join("ckpt");
    let train = ["train", arg(&data), "--out", arg(&ckpt), "--epochs", "1"];
    refused(&[&train[..], &["--generated", "18446744073709551615"]].concat(), "expected a whole number from 1 to");
    refused(&[&train[..], &["--generated", "1000000000"]].concat(), "--generated 1000000000: an epoch's robots");
    refused(&[&train[..], &["--dim", "1000000000"]].concat(), "'--dim <DIM>': expected a whole number");
    refused(&[&train[..], &["--dim", "16000000"]].concat(), "GB of memory; this machine has");
    refused(&[&train[..], &["--layers", "100000000"]].concat(), "'--layers <LAYERS>': expected a whole number");
    refused(&[&train[..], &["--lr", "nan"]].concat(), "'--lr <LR>': expected a positive finite number");
    refused(&[&train[..], &["--lr", "-1"]].concat(), "'--lr <LR>': expected a positive finite number");
}

/// Item 20: a manifest of a trillion robots (written by a run of a size refused since: ten billion robots aborted
/// `verify` and hung `status`) is counted, not listed: `verify` and `status` answer at once.
#[test]
fn verify_and_status_count_a_huge_plan_without_listing_it() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    generate(&dir, 2, 2);
    let m = dynforge_proto::manifest::Manifest::load(&dir).unwrap().unwrap();
    let huge = dynforge_proto::manifest::Manifest { robots: 1_000_000_000_000, ..m };
    std::fs::write(dir.join("manifest.toml"), huge.to_toml()).unwrap();
    let o = bounded(&["status", arg(&dir)], &[], Duration::from_secs(30));
    assert!(o.status.success() && stdout(&o).contains("4/2000000000000 jobs"), "{}{}", stdout(&o), stderr(&o));
    let o = bounded(&["verify", arg(&dir)], &[], Duration::from_secs(30));
    assert!(stdout(&o).contains("2000000000000 jobs planned: 4 done"), "{}{}", stdout(&o), stderr(&o));
    assert!(stdout(&o).contains("1999999999996 pending"), "{}", stdout(&o));
}

/// Item 21: `verify` while a generation holds the run counts a planned job's shard that is in place before its ledger
/// line (a worker renames it, then the coordinator records it) as in flight, not as extra; a file no job of the plan
/// writes is extra all the same, and without a live generation the unrecorded shard is extra.
#[test]
fn verify_during_a_live_generation_reports_no_extra_shards() {
    use dynforge_proto::ledger::{self, Ledger};
    use dynforge_proto::lock::RunLock;
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    generate(&dir, 2, 2);
    // The last job's shard is in place, its line not yet written.
    let path = dir.join("ledger.tsv");
    let mut entries = ledger::read(&path).unwrap();
    let last = entries.pop().unwrap();
    std::fs::remove_file(&path).unwrap();
    let (mut l, _) = Ledger::open(&path).unwrap();
    entries.iter().for_each(|e| l.append(e).unwrap());
    drop(l);
    let unrecorded = last.shard_name(3, "native");
    assert!(dir.join("shards").join(&unrecorded).exists());
    let stranger = "r000009-t00-native.mcap";

    let lock = RunLock::acquire(&dir, Duration::ZERO, "generate").unwrap();
    let said = stdout(&dynforge(&["verify", arg(&dir)]));
    assert!(said.contains("a generation is live") && said.contains("1 pending"), "{said}");
    assert!(!said.contains("extra:"), "{said}");
    std::fs::copy(dir.join("shards").join(&unrecorded), dir.join("shards").join(stranger)).unwrap();
    let said = stdout(&dynforge(&["verify", arg(&dir)]));
    assert!(said.contains(&format!("extra: {stranger}")) && !said.contains(&unrecorded), "{said}");
    drop(lock);
    std::fs::remove_file(dir.join("shards").join(stranger)).unwrap();

    // Held by another command, no generation writes: the unrecorded shard is extra.
    let lock = RunLock::acquire(&dir, Duration::ZERO, "dataset prepare").unwrap();
    let o = dynforge(&["verify", arg(&dir)]);
    let said = stdout(&o);
    assert!(said.contains("in use by dataset prepare (pid "), "{said}");
    assert!(!o.status.success() && said.contains(&format!("extra: {unrecorded}")), "{said}");
    drop(lock);
    let o = dynforge(&["verify", arg(&dir)]);
    assert!(!o.status.success() && stdout(&o).contains(&format!("extra: {unrecorded}")), "{}", stdout(&o));
}

/// Zeroes the data-section CRC of the MCAP `bytes` (MCAP allows 0: "not computed").
fn clear_crc(bytes: &mut [u8]) {
    let footer = bytes.len() - 8 - 29;
    let summary = u64::from_le_bytes(bytes[footer + 9..footer + 17].try_into().unwrap()) as usize;
    let data_end = if summary == 0 { footer } else { summary } - 13;
    assert_eq!(bytes[data_end], 0x0F, "the DataEnd record");
    bytes[data_end + 9..data_end + 13].fill(0);
}

/// Item 21: a shard whose label was edited and whose data-section CRC was cleared (0 is allowed by MCAP) is not
/// trusted: its run's ledger hash, or for a file outside a run the missing CRC, refuses it in `info`, `dataset
/// stats` and `prepare`.
#[test]
fn a_shard_without_its_crc_and_with_an_edited_label_is_never_read_as_data() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    generate(&dir, 4, 2);
    let path = shards(&dir)[2].clone();
    let mut bytes = std::fs::read(&path).unwrap();
    let at = bytes.windows(7).position(|w| w == b"mass_l2").unwrap();
    let digit = (at..bytes.len()).find(|&k| bytes[k].is_ascii_digit()).unwrap();
    bytes[digit] = if bytes[digit] == b'9' { b'8' } else { b'9' };
    clear_crc(&mut bytes);
    std::fs::write(&path, &bytes).unwrap();
    let name = path.file_name().unwrap().to_str().unwrap();
    let o = dynforge(&["info", arg(&path)]);
    assert!(!o.status.success() && stderr(&o).contains("the run's ledger records"), "{}", stdout(&o));
    let o = dynforge(&["dataset", "stats", arg(&dir)]);
    assert!(stderr(&o).contains(name) && stdout(&o).contains("7 trajectories"), "{}{}", stdout(&o), stderr(&o));
    let o = dynforge(&["dataset", "prepare", arg(&dir)]);
    assert!(!o.status.success() && stderr(&o).contains(name), "{}", stderr(&o));
    // Outside its run nothing vouches for its labels.
    let alone = root.path().join("alone.mcap");
    std::fs::write(&alone, &bytes).unwrap();
    let said = ok(&["info", arg(&alone)]);
    assert!(said.contains("Checked:     nothing"), "{said}");
    let o = dynforge(&["dataset", "stats", arg(root.path().join("alone.mcap").as_path())]);
    assert!(!o.status.success() && stderr(&o).contains("no data-section CRC"), "{}", stderr(&o));
}

/// Item 21: what killed writers leave in `cache/` is removed by the next holder of the run's lock.
#[test]
fn a_killed_cache_writers_temporary_file_is_removed() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    generate(&dir, 4, 2);
    std::fs::create_dir_all(dir.join("cache")).unwrap();
    let stale = dir.join("cache").join(".physics-0123456789abcdef-0123456789abcdef.bin.4242.tmp");
    std::fs::write(&stale, vec![0u8; 4096]).unwrap();
    ok(&["dataset", "prepare", arg(&dir)]);
    assert!(!stale.exists(), "the stale temporary file is still there");
    // And by a generation (here: resumed, with nothing left to do).
    let leftovers = [stale, dir.join(".ledger.tsv.4242.tmp")];
    leftovers.iter().for_each(|f| std::fs::write(f, b"partial").unwrap());
    generate(&dir, 4, 2);
    assert!(leftovers.iter().all(|f| !f.exists()), "a generation left stale temporary files");
}

/// Item 21: ledger records of jobs the manifest does not plan are refused by `generate` (which counted them as done),
/// not counted by `status`, and named by `verify`.
#[test]
fn ledger_records_outside_the_plan_are_refused() {
    use dynforge_proto::ledger::{Entry, Ledger, Status};
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    generate(&dir, 2, 2);
    let (mut ledger, _) = Ledger::open(&dir.join("ledger.tsv")).unwrap();
    let status = Status::Done { samples: 10, shard_hash: 7 };
    ledger.append(&Entry { job_id: 99, robot: 49, trajectory: 1, status }).unwrap();
    drop(ledger);
    let o = dynforge(&["generate", "--out", arg(&dir), "--robots", "2", "--trajectories", "2", "--seed", "3"]);
    let e = stderr(&o);
    assert!(!o.status.success() && e.contains("ledger.tsv records 1 job(s) that"), "{e}");
    assert!(e.contains("job 99, robot 49 trajectory 1"), "{e}");
    assert!(ok(&["status", arg(&dir)]).contains("4/4 jobs finished (done 4"));
    let o = dynforge(&["verify", arg(&dir)]);
    assert!(!o.status.success() && stdout(&o).contains("ledger job 99: not a job of this run's manifest"));
}

/// Item 21: `merge --out` inside one of its partitions is refused, and the partition is left as it was.
#[test]
fn a_merge_into_one_of_its_partitions_is_refused() {
    let root = tempfile::tempdir().unwrap();
    let parts: Vec<PathBuf> = (0..2).map(|i| root.path().join(format!("p{i}"))).collect();
    for (i, p) in parts.iter().enumerate() {
        let part = format!("{i}/2");
        ok(&["generate", "--out", arg(p), "--robots", "2", "--trajectories", "2", "--seed", "3", "--partition", &part]);
    }
    for out in [parts[0].join("merged"), parts[0].join("shards").join("m"), parts[1].join("./cache/../x")] {
        let o = dynforge(&["merge", "--out", arg(&out), arg(&parts[0]), arg(&parts[1])]);
        assert!(!o.status.success() && stderr(&o).contains("is inside it"), "{}: {}", out.display(), stderr(&o));
        assert!(!out.exists(), "{}", out.display());
    }
    for p in &parts {
        ok(&["verify", arg(p)]);
    }
    let merged = root.path().join("merged");
    ok(&["merge", "--out", arg(&merged), arg(&parts[0]), arg(&parts[1])]);
}

/// Item 21: `identify LOG --out LOG` and `estimate ... --out LOG`, however the path is spelt, refuse to write over
/// the input log.
#[test]
fn identify_and_estimate_never_write_over_their_log() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    generate(&dir, 1, 1);
    let log = root.path().join("log.mcap");
    std::fs::copy(&shards(&dir)[0], &log).unwrap();
    let before = std::fs::read(&log).unwrap();
    std::fs::create_dir(root.path().join("sub")).unwrap();
    std::os::unix::fs::symlink(root.path(), root.path().join("link")).unwrap();
    let spellings = [log.clone(), root.path().join("sub/../log.mcap"), root.path().join("link/log.mcap")];
    for out in &spellings {
        let o = dynforge(&["identify", arg(&log), "--out", arg(out)]);
        assert!(!o.status.success() && stderr(&o).contains("would overwrite the input"), "{}", stderr(&o));
        let ckpt = root.path().join("no-checkpoint");
        let o = dynforge(&["estimate", "--checkpoint", arg(&ckpt), arg(&log), "--out", arg(out)]);
        assert!(!o.status.success() && stderr(&o).contains("would overwrite the input"), "{}", stderr(&o));
    }
    assert_eq!(std::fs::read(&log).unwrap(), before, "the log was overwritten");
}

/// Item 22: `info` on a log of one message says it has no rate, not "NaN Hz".
#[test]
fn info_on_a_one_message_log_prints_no_nan() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    generate(&dir, 1, 1);
    let bag = dynforge_shard::read(&shards(&dir)[0]).unwrap();
    let one = root.path().join("one.mcap");
    let content = dynforge_shard::ShardContent {
        urdf: bag.robot_description.as_deref().unwrap(),
        joint_states: &bag.joint_states[..1],
        metadata: &Default::default(),
    };
    dynforge_shard::write(&one, &content).unwrap();
    let said = ok(&["info", arg(&one)]);
    assert!(!said.contains("NaN") && said.contains("1 message(s) at one stamp: no rate"), "{said}");
}
