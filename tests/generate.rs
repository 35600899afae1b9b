//! End-to-end tests of `dynforge generate`: real coordinator and worker processes, real kills.

mod common;

use common::{children_of, dynforge, dynforge_with_env, shard_hashes};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use dynforge_proto::ledger;

const EXE: &str = env!("CARGO_BIN_EXE_dynforge");

fn generate_args<'a>(dir: &'a Path, robots: &'a str, trajectories: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "generate",
        "--out",
        dir.to_str().unwrap(),
        "--robots",
        robots,
        "--trajectories",
        trajectories,
        "--seed",
        "4",
    ];
    a.extend_from_slice(extra);
    a
}

fn spawn(args: &[&str]) -> Child {
    Command::new(EXE).args(args).stdout(Stdio::null()).stderr(Stdio::null()).spawn().expect("dynforge starts")
}

fn ledger_entries(dir: &Path) -> Vec<ledger::Entry> {
    ledger::read(&dir.join("ledger.tsv")).unwrap()
}

fn kill(pid: u32, signal: &str) {
    let _ = Command::new("kill").args([signal, &pid.to_string()]).status();
}

fn wait_for_entries(dir: &Path, n: usize, child: &mut Child) {
    let start = Instant::now();
    while ledger_entries(dir).len() < n {
        assert!(child.try_wait().unwrap().is_none(), "the run ended before {n} jobs were recorded");
        assert!(start.elapsed() < Duration::from_secs(120), "no progress");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn assert_verifies(dir: &Path) {
    let out = dynforge(&["verify", dir.to_str().unwrap()]);
    assert!(out.status.success(), "verify failed:\n{}", String::from_utf8_lossy(&out.stdout));
}

/// Every planned job has exactly one ledger entry.
fn assert_exactly_once(dir: &Path, jobs: usize) {
    let entries = ledger_entries(dir);
    let ids: BTreeSet<u64> = entries.iter().map(|e| e.job_id).collect();
    assert_eq!(entries.len(), jobs, "ledger entries");
    assert_eq!(ids.len(), jobs, "distinct jobs");
}

#[test]
fn a_small_run_with_two_workers_completes_verifies_and_reports_status() {
    let dir = tempfile::tempdir().unwrap();
    let out = dynforge(&generate_args(dir.path(), "4", "3", &["--workers", "2"]));
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_exactly_once(dir.path(), 12);
    assert_verifies(dir.path());
    let status = dynforge(&["status", dir.path().to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&status.stdout).unwrap();
    assert_eq!(v["live"], false);
    assert_eq!(v["total"], 12);
    assert_eq!(v["pending"], 0);
    assert_eq!(v["done"].as_u64().unwrap() + v["discarded"].as_u64().unwrap(), 12);
    // Running it again has nothing left to do and changes nothing.
    let before = shard_hashes(dir.path());
    assert!(dynforge(&generate_args(dir.path(), "4", "3", &["--workers", "2"])).status.success());
    assert_eq!(shard_hashes(dir.path()), before);
    assert_exactly_once(dir.path(), 12);
}

#[test]
fn a_worker_killed_mid_job_is_replaced_and_every_job_recorded_once() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = spawn(&generate_args(dir.path(), "6", "4", &["--workers", "2"]));
    wait_for_entries(dir.path(), 3, &mut child);
    // A monitor in another process sees the live figures and disturbs nothing.
    let status = dynforge(&["status", dir.path().to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&status.stdout).unwrap();
    assert_eq!((v["live"].as_bool(), v["total"].as_u64()), (Some(true), Some(24)), "{v}");
    assert_eq!(v["coordinator_pid"].as_u64(), Some(child.id() as u64));
    let workers = children_of(child.id());
    assert_eq!(workers.len(), 2, "two worker processes");
    kill(workers[0], "-9");
    assert!(child.wait().unwrap().success(), "the run completes despite the kill");
    assert_exactly_once(dir.path(), 24);
    assert_verifies(dir.path());
}

#[test]
fn killing_the_coordinator_and_resuming_gives_the_uninterrupted_dataset_and_partitions_add_up() {
    let base = tempfile::tempdir().unwrap();
    assert!(dynforge(&generate_args(base.path(), "4", "4", &["--workers", "2"])).status.success());
    let want = shard_hashes(base.path());
    let want_ledger: BTreeSet<String> = ledger_entries(base.path()).iter().map(|e| format!("{e:?}")).collect();

    // kill -9 of the coordinator and its workers at two points, then resume to the end.
    let dir = tempfile::tempdir().unwrap();
    for stop_at in [2, 9] {
        let mut child = spawn(&generate_args(dir.path(), "4", "4", &["--workers", "2"]));
        wait_for_entries(dir.path(), stop_at, &mut child);
        let workers = children_of(child.id());
        kill(child.id(), "-9");
        for w in workers {
            kill(w, "-9");
        }
        let _ = child.wait();
    }
    let out = dynforge(&generate_args(dir.path(), "4", "4", &["--workers", "2"]));
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_exactly_once(dir.path(), 16);
    assert_eq!(shard_hashes(dir.path()), want, "identical shards");
    let got_ledger: BTreeSet<String> = ledger_entries(dir.path()).iter().map(|e| format!("{e:?}")).collect();
    assert_eq!(got_ledger, want_ledger, "identical ledger records");
    assert_verifies(dir.path());

    // Two partitions together are the single run.
    let mut union = BTreeMap::new();
    for part in ["0/2", "1/2"] {
        let p = tempfile::tempdir().unwrap();
        assert!(
            dynforge(&generate_args(p.path(), "4", "4", &["--workers", "1", "--partition", part])).status.success()
        );
        assert_verifies(p.path());
        let hashes = shard_hashes(p.path());
        assert!(hashes.keys().all(|k| !union.contains_key(k)), "partitions overlap");
        union.extend(hashes);
    }
    assert_eq!(union, want);
}

#[test]
fn sigterm_stops_cleanly_with_a_resumable_state() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = spawn(&generate_args(dir.path(), "6", "4", &["--workers", "2"]));
    wait_for_entries(dir.path(), 2, &mut child);
    kill(child.id(), "-TERM");
    let start = Instant::now();
    let status = child.wait().unwrap();
    assert!(!status.success(), "an interrupted run exits non-zero");
    assert!(start.elapsed() < Duration::from_secs(10), "it stops promptly");
    assert!(children_of(child.id()).is_empty());
    let out = dynforge(&generate_args(dir.path(), "6", "4", &["--workers", "2"]));
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_exactly_once(dir.path(), 24);
    assert_verifies(dir.path());
}

#[test]
fn two_concurrent_runs_on_one_host_both_complete() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let mut ca = spawn(&generate_args(a.path(), "3", "4", &["--workers", "1"]));
    let mut cb = spawn(&generate_args(b.path(), "3", "4", &["--workers", "1"]));
    assert!(ca.wait().unwrap().success());
    assert!(cb.wait().unwrap().success());
    assert_exactly_once(a.path(), 12);
    assert_exactly_once(b.path(), 12);
    assert_eq!(shard_hashes(a.path()), shard_hashes(b.path()), "same seed, same dataset");
}

#[test]
fn bad_inputs_fail_clearly_and_lose_nothing() {
    let stderr = |o: &Output| String::from_utf8_lossy(&o.stderr).to_string();
    let file = tempfile::NamedTempFile::new().unwrap();
    let o = dynforge(&generate_args(file.path(), "1", "1", &[]));
    assert!(!o.status.success() && stderr(&o).contains(file.path().to_str().unwrap()), "{}", stderr(&o));

    let dir = tempfile::tempdir().unwrap();
    let o = dynforge(&generate_args(dir.path(), "0", "4", &[]));
    assert!(!o.status.success() && stderr(&o).contains("invalid value '0' for '--robots <ROBOTS>'"), "{}", stderr(&o));
    let o = dynforge(&generate_args(dir.path(), "2", "4", &["--partition", "3/2"]));
    assert!(!o.status.success() && stderr(&o).contains("partition '3/2'"), "{}", stderr(&o));
    // A robot's tour has 16 waypoints, so 16 trajectories; a timeout must be a finite number of seconds.
    let o = dynforge(&generate_args(dir.path(), "1", "17", &[]));
    assert!(!o.status.success() && stderr(&o).contains("--trajectories 17 is more than"), "{}", stderr(&o));
    // A family's settings without a family would be silently ignored: refused.
    for extra in [["--fix", "j1"], ["--spread", "0.2"]] {
        let o = dynforge(&generate_args(dir.path(), "1", "1", &extra));
        assert!(!o.status.success() && stderr(&o).contains("--urdf"), "{extra:?}: {}", stderr(&o));
    }
    for t in ["inf", "0", "-1", "NaN", "1e300"] {
        let o = dynforge(&generate_args(dir.path(), "1", "1", &[&format!("--job-timeout={t}")]));
        assert!(o.status.code() == Some(1) && stderr(&o).contains("--job-timeout"), "{t}: {}", stderr(&o));
    }

    // A finished run whose ledger gets a corrupted line: generate refuses and changes nothing.
    assert!(dynforge(&generate_args(dir.path(), "1", "2", &["--workers", "1"])).status.success());
    let ledger_path = dir.path().join("ledger.tsv");
    let mut bytes = std::fs::read(&ledger_path).unwrap();
    bytes[0] = b'7';
    std::fs::write(&ledger_path, &bytes).unwrap();
    let shards = shard_hashes(dir.path());
    let o = dynforge(&generate_args(dir.path(), "1", "2", &["--workers", "1"]));
    assert!(!o.status.success() && stderr(&o).contains("ledger.tsv:1: corrupt ledger line"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&ledger_path).unwrap(), bytes);
    assert_eq!(shard_hashes(dir.path()), shards);

    // Another configuration on the same directory is refused, naming the difference; fewer robots too.
    let other = tempfile::tempdir().unwrap();
    assert!(dynforge(&generate_args(other.path(), "2", "1", &["--workers", "1"])).status.success());
    let o = dynforge(&generate_args(other.path(), "2", "2", &["--workers", "1"]));
    assert!(!o.status.success() && stderr(&o).contains("trajectories: requested 2, directory has 1"), "{}", stderr(&o));
    let o = dynforge(&generate_args(other.path(), "1", "1", &["--workers", "1"]));
    assert!(!o.status.success() && stderr(&o).contains("can grow, not shrink"), "{}", stderr(&o));
}

#[test]
fn a_grown_dataset_equals_one_generated_at_its_final_size() {
    // 2 robots, then the same run asked for 3: only robot 2's jobs run, and the result is the 3-robot dataset.
    let (grown, whole) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    assert!(dynforge(&generate_args(grown.path(), "2", "2", &["--workers", "1"])).status.success());
    let before = shard_hashes(grown.path());
    let o = dynforge(&generate_args(grown.path(), "3", "2", &["--workers", "1"]));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stderr).contains("growing the dataset from 2 to 3 robots"));
    assert!(dynforge(&generate_args(whole.path(), "3", "2", &["--workers", "1"])).status.success());
    assert_exactly_once(grown.path(), 6);
    let after = shard_hashes(grown.path());
    assert_eq!(after, shard_hashes(whole.path()), "same shards as a run of the final size");
    assert!(
        before.iter().all(|(name, hash)| after.get(name) == Some(hash)),
        "the first run's shards are kept as they were"
    );
}

#[test]
fn a_hung_job_is_retried_then_recorded_as_failed_with_the_reason() {
    // Workers stall 30 s before each job (fault injection), far past the 0.3 s deadline: every attempt counts as a
    // hung worker, which is killed and replaced; after the third attempt the job is recorded as failed, and the run
    // finishes with a non-zero exit that says so. A resume (here without the fault) runs the failed job again.
    // still finishes.
    let dir = tempfile::tempdir().unwrap();
    let out = dynforge_with_env(
        &generate_args(dir.path(), "1", "1", &["--workers", "1", "--job-timeout", "0.3"]),
        &[("DYNFORGE_FAULT_WORKER_STALL", "30")],
    );
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.code() == Some(1) && err.contains("1 job(s) failed") && err.contains("rerun"), "{err}");
    let entries = ledger_entries(dir.path());
    assert_eq!(entries.len(), 1);
    match &entries[0].status {
        ledger::Status::Failed { message } => {
            assert!(message.contains("hung") && message.contains("3 attempts"), "{message}")
        }
        other => panic!("expected a failure, got {other:?}"),
    }
    assert!(shard_hashes(dir.path()).is_empty(), "no shard for a failed job");
    let verify = dynforge(&["verify", dir.path().to_str().unwrap()]);
    let err = String::from_utf8_lossy(&verify.stderr).to_string();
    assert!(!verify.status.success() && err.contains("incomplete: 1 job(s) failed"), "{err}");

    let out = dynforge(&generate_args(dir.path(), "1", "1", &["--workers", "1"]));
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success() && err.contains("retrying 1 job(s) that failed"), "{err}");
    let entries = ledger_entries(dir.path());
    assert!(entries.len() == 2 && matches!(entries[1].status, ledger::Status::Done { .. }), "{entries:?}");
    assert_eq!(shard_hashes(dir.path()).len(), 1, "the retried job wrote its shard");
    let verify = dynforge(&["verify", dir.path().to_str().unwrap()]);
    assert!(verify.status.success(), "{}", String::from_utf8_lossy(&verify.stdout));
}

#[test]
fn two_coordinators_started_together_on_one_directory_one_runs_and_the_other_is_refused() {
    for round in 0..20 {
        let dir = tempfile::tempdir().unwrap();
        let args = generate_args(dir.path(), "2", "2", &["--workers", "1"]);
        let run = || Command::new(EXE).args(&args).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
        let (a, b) = (run(), run());
        let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
        let ran: Vec<&Output> = [&a, &b].into_iter().filter(|o| o.status.success()).collect();
        let refused: Vec<&Output> = [&a, &b].into_iter().filter(|o| !o.status.success()).collect();
        assert_eq!(ran.len(), 1, "round {round}: exactly one runs");
        let why = String::from_utf8_lossy(&refused[0].stderr);
        assert!(why.contains("another generate is using this directory (pid "), "round {round}: {why}");
        assert_exactly_once(dir.path(), 4);
        assert_verifies(dir.path());
    }
}

#[test]
fn a_refused_generate_touches_nothing_of_the_live_run() {
    let dir = tempfile::tempdir().unwrap();
    let mut live = spawn(&generate_args(dir.path(), "6", "4", &["--workers", "2"]));
    wait_for_entries(dir.path(), 2, &mut live);
    let manifest = std::fs::read(dir.path().join("manifest.toml")).unwrap();
    // Repeated refused starts with other settings: the lock comes first, or each would delete the live run's files in
    // flight and could rewrite the manifest (--robots 8 grows it) before noticing the other coordinator.
    for _ in 0..5 {
        let o = dynforge(&generate_args(dir.path(), "8", "4", &["--workers", "2"]));
        assert!(!o.status.success());
        assert!(String::from_utf8_lossy(&o.stderr).contains("another generate is using this directory"));
        assert_eq!(std::fs::read(dir.path().join("manifest.toml")).unwrap(), manifest, "manifest rewritten");
    }
    // verify during the run says so instead of calling its files in flight extra.
    let v = dynforge(&["verify", dir.path().to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&v.stdout).contains("a generation is live (pid "), "{v:?}");
    assert!(live.wait().unwrap().success());
    assert_exactly_once(dir.path(), 24);
    assert!(ledger_entries(dir.path()).iter().all(|e| !matches!(e.status, ledger::Status::Failed { .. })));
    assert_verifies(dir.path());
}

#[test]
fn workers_die_with_their_coordinator_and_a_resume_right_after_gives_the_same_dataset() {
    let base = tempfile::tempdir().unwrap();
    assert!(dynforge(&generate_args(base.path(), "3", "4", &["--workers", "2"])).status.success());
    let dir = tempfile::tempdir().unwrap();
    let mut child = spawn(&generate_args(dir.path(), "3", "4", &["--workers", "2"]));
    wait_for_entries(dir.path(), 3, &mut child);
    let workers = children_of(child.id());
    assert_eq!(workers.len(), 2);
    // Only the coordinator is killed: its workers are orphans, possibly inside a job.
    kill(child.id(), "-9");
    let _ = child.wait();
    let out = dynforge(&generate_args(dir.path(), "3", "4", &["--workers", "2"]));
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for w in workers {
        let state = std::fs::read_to_string(format!("/proc/{w}/stat")).unwrap_or_default();
        let running = state.rsplit_once(')').is_some_and(|(_, rest)| !rest.trim_start().starts_with('Z'));
        assert!(!running, "orphan worker {w} still runs: {state}");
    }
    assert_exactly_once(dir.path(), 12);
    assert_eq!(shard_hashes(dir.path()), shard_hashes(base.path()), "identical shards, none extra");
    assert_verifies(dir.path());
}

#[test]
fn a_ledger_without_its_manifest_is_not_reinterpreted_under_other_settings() {
    let dir = tempfile::tempdir().unwrap();
    assert!(dynforge(&generate_args(dir.path(), "2", "3", &["--workers", "1"])).status.success());
    let ledger = std::fs::read(dir.path().join("ledger.tsv")).unwrap();
    std::fs::remove_file(dir.path().join("manifest.toml")).unwrap();
    // Job numbers are robot * trajectories + t: with --trajectories 5 the six recorded jobs would become others.
    let o = dynforge(&generate_args(dir.path(), "3", "5", &["--workers", "1"]));
    assert!(!o.status.success());
    let why = String::from_utf8_lossy(&o.stderr);
    assert!(why.contains("records 6 job(s) but manifest.toml is missing"), "{why}");
    assert_eq!(std::fs::read(dir.path().join("ledger.tsv")).unwrap(), ledger, "ledger changed");
    assert!(!dir.path().join("manifest.toml").exists(), "a manifest was written for settings nobody ran");
}

#[test]
fn lost_and_damaged_shards_are_made_again_and_never_read_as_data() {
    let dir = tempfile::tempdir().unwrap();
    let args = generate_args(dir.path(), "2", "3", &["--workers", "1"]);
    assert!(dynforge(&args).status.success());
    let want = shard_hashes(dir.path());
    let names: Vec<&String> = want.keys().collect();
    let shards = dir.path().join("shards");

    // A deleted shard: the resume notices and makes it again.
    std::fs::remove_file(shards.join(names[0])).unwrap();
    let o = dynforge(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stderr).contains("1 recorded shard(s) are missing"), "{o:?}");
    assert_eq!(shard_hashes(dir.path()), want);

    // A label edited in place (same length): readers refuse the file, verify names it, --repair marks its job.
    let path = shards.join(names[1]);
    let mut bytes = std::fs::read(&path).unwrap();
    let at = bytes.windows(7).position(|w| w == b"mass_l2").unwrap();
    let digit = (at..bytes.len()).find(|&k| bytes[k].is_ascii_digit()).unwrap();
    bytes[digit] = if bytes[digit] == b'9' { b'8' } else { b'9' };
    std::fs::write(&path, &bytes).unwrap();
    let stats = dynforge(&["dataset", "stats", dir.path().to_str().unwrap()]);
    let why = String::from_utf8_lossy(&stats.stderr);
    assert!(why.contains(names[1].as_str()) && why.contains("changed or damaged"), "{why}");
    let v = dynforge(&["verify", dir.path().to_str().unwrap()]);
    assert!(!v.status.success() && String::from_utf8_lossy(&v.stderr).contains("--repair"), "{v:?}");
    let r = dynforge(&["verify", dir.path().to_str().unwrap(), "--repair"]);
    assert!(String::from_utf8_lossy(&r.stderr).contains("1 job(s) recorded as failed"), "{r:?}");
    assert!(dir.path().join("quarantine").join(names[1]).exists(), "the damaged file is kept aside");
    let o = dynforge(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(shard_hashes(dir.path()), want, "the same bytes as the first run");
    assert_verifies(dir.path());
}

/// A tmpfs of `mb` megabytes mounted on a fresh directory, unmounted when dropped; `None` where mounting is not
/// allowed (not root, or a container without the capability).
struct SmallDisk(tempfile::TempDir);

impl SmallDisk {
    fn mount(mb: u32) -> Option<SmallDisk> {
        let dir = tempfile::tempdir().ok()?;
        let ok = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={mb}m"), "tmpfs", dir.path().to_str()?])
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        ok.then_some(SmallDisk(dir))
    }

    fn grow(&self, mb: u32) {
        let remount = format!("remount,size={mb}m");
        assert!(
            Command::new("mount").args(["-o", &remount, self.0.path().to_str().unwrap()]).status().unwrap().success()
        );
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(self.0.path()).status();
    }
}

#[test]
fn a_full_disk_fails_jobs_naming_it_and_a_resume_with_space_completes_the_same_dataset() {
    let Some(disk) = SmallDisk::mount(3) else {
        eprintln!("skipped: cannot mount a tmpfs here (needs root)");
        return;
    };
    let base = tempfile::tempdir().unwrap();
    assert!(dynforge(&generate_args(base.path(), "2", "4", &["--workers", "1"])).status.success());
    let dir = disk.0.path().join("run");
    let args = generate_args(&dir, "2", "4", &["--workers", "1"]);
    // Eight shards of ~1 MB on 3 MB: the disk fills after two or three.
    let o = dynforge(&args);
    assert!(!o.status.success(), "a run that could not write its shards must not succeed");
    let ledger = std::fs::read_to_string(dir.join("ledger.tsv")).unwrap_or_default();
    let said = format!("{}{ledger}", String::from_utf8_lossy(&o.stderr));
    assert!(said.contains("No space left on device"), "ENOSPC is not named:\n{said}");
    disk.grow(64);
    let o = dynforge(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(shard_hashes(&dir), shard_hashes(base.path()), "the same dataset as with space throughout");
    assert_verifies(&dir);
}

#[test]
fn three_partitions_merge_into_the_single_host_directory() {
    let single = tempfile::tempdir().unwrap();
    assert!(dynforge(&generate_args(single.path(), "4", "2", &["--workers", "2"])).status.success());
    let root = tempfile::tempdir().unwrap();
    let parts: Vec<std::path::PathBuf> = (0..3).map(|i| root.path().join(format!("part{i}"))).collect();
    for (i, p) in parts.iter().enumerate() {
        let part = format!("{i}/3");
        assert!(dynforge(&generate_args(p, "4", "2", &["--workers", "1", "--partition", &part])).status.success());
    }
    let out = root.path().join("merged");
    let arg = |p: &Path| p.to_str().unwrap().to_string();
    // Two of three is not the run.
    let o = dynforge(&["merge", "--out", &arg(&out), &arg(&parts[0]), &arg(&parts[2])]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("partition(s) 1/3 missing"), "{o:?}");
    assert!(!out.join("manifest.toml").exists());

    let o = dynforge(&["merge", "--out", &arg(&out), &arg(&parts[2]), &arg(&parts[0]), &arg(&parts[1])]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        String::from_utf8_lossy(&o.stdout)
            .contains("merged 3 partitions: 8 shards (8 hard-linked, 0 copied, 0 pruned)")
    );
    assert_eq!(shard_hashes(&out), shard_hashes(single.path()), "byte-identical shards");
    assert_eq!(
        std::fs::read(out.join("manifest.toml")).unwrap(),
        std::fs::read(single.path().join("manifest.toml")).unwrap()
    );
    let set = |d: &Path| ledger_entries(d).iter().map(|e| format!("{e:?}")).collect::<BTreeSet<_>>();
    assert_eq!(set(&out), set(single.path()), "the same ledger records");
    assert_verifies(&out);
    // Merging again into the same place is refused, not mixed.
    let o = dynforge(&["merge", "--out", &arg(&out), &arg(&parts[0]), &arg(&parts[1]), &arg(&parts[2])]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("must be new or empty"), "{o:?}");
}

/// Name -> bytes of every file in a run directory's cache.
fn caches(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir.join("cache"))
        .map(|l| {
            l.map(|e| e.unwrap())
                .map(|e| (e.file_name().to_string_lossy().to_string(), std::fs::read(e.path()).unwrap()))
                .collect()
        })
        .unwrap_or_default()
}

/// The bounded-disk path: each partition cached and its shards deleted, the partitions merged by their caches, and
/// the result the same as the single-host directory's (same cache files byte for byte, the same trained weights).
#[test]
fn pruned_partitions_merge_into_the_caches_and_model_of_the_single_host_run() {
    let ok = |o: Output| {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).to_string()
    };
    let arg = |p: &Path| p.to_str().unwrap().to_string();
    let transformer = ["--model", "transformer", "--window", "32:64:16"];
    let root = tempfile::tempdir().unwrap();
    let single = root.path().join("single");
    ok(dynforge(&generate_args(&single, "6", "2", &["--workers", "2"])));
    let parts: Vec<std::path::PathBuf> = (0..3).map(|i| root.path().join(format!("part{i}"))).collect();
    for (i, p) in parts.iter().enumerate() {
        let part = format!("{i}/3");
        ok(dynforge(&generate_args(p, "6", "2", &["--workers", "1", "--partition", &part])));
    }
    let before = shard_hashes(&parts[0]);
    let said = ok(dynforge(&["dataset", "prepare", &arg(&parts[0]), "--prune"]));
    assert!(said.contains(&format!("{} shards pruned", before.len())), "{said}");
    assert!(shard_hashes(&parts[0]).is_empty());
    let listed = dynforge_proto::run_dir::read_pruned(&parts[0]).unwrap();
    assert_eq!(listed, before.keys().cloned().collect::<BTreeSet<_>>());
    // Pruned is not missing: verify passes and says so, a resume does not remake them, the run cannot grow.
    let said = ok(dynforge(&["verify", &arg(&parts[0])]));
    assert!(said.contains(&format!("({} pruned", before.len())), "{said}");
    ok(dynforge(&generate_args(&parts[0], "6", "2", &["--workers", "1", "--partition", "0/3"])));
    assert!(shard_hashes(&parts[0]).is_empty(), "a resume remade pruned shards");
    let o = dynforge(&generate_args(&parts[0], "9", "2", &["--workers", "1", "--partition", "0/3"]));
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("cannot grow"), "{o:?}");

    // A cache of other settings cannot be made from pruned shards.
    let o = dynforge(&[&["dataset", "prepare", &arg(&parts[0])][..], &transformer].concat());
    assert!(String::from_utf8_lossy(&o.stderr).contains("pruned.txt"), "{o:?}");

    // Partition 1 gets both caches before pruning, partition 2 only the physics one, and keeps its shards: the merge
    // is refused (the pruned partition 0 has no windows cache) before it writes anything.
    ok(dynforge(&[&["dataset", "prepare", &arg(&parts[1])][..], &transformer].concat()));
    ok(dynforge(&["dataset", "prepare", &arg(&parts[1]), "--prune"]));
    ok(dynforge(&["dataset", "prepare", &arg(&parts[2])]));
    let out = root.path().join("merged");
    let merge = || dynforge(&["merge", "--out", &arg(&out), &arg(&parts[0]), &arg(&parts[1]), &arg(&parts[2])]);
    let o = merge();
    assert!(String::from_utf8_lossy(&o.stderr).contains("has no current windows cache"), "{o:?}");
    assert!(!out.exists());
    // Giving partition 0's pruned shards up: without the list, the next generate remakes them, byte for byte.
    std::fs::remove_file(parts[0].join("pruned.txt")).unwrap();
    ok(dynforge(&generate_args(&parts[0], "6", "2", &["--workers", "1", "--partition", "0/3"])));
    assert_eq!(shard_hashes(&parts[0]), before);
    ok(dynforge(&[&["dataset", "prepare", &arg(&parts[0])][..], &transformer].concat()));
    ok(dynforge(&["dataset", "prepare", &arg(&parts[0]), "--prune"]));
    ok(dynforge(&[&["dataset", "prepare", &arg(&parts[2])][..], &transformer].concat()));
    // Partition 2 keeps its shards: they are linked, the rest come from the caches.
    let said = ok(merge());
    assert!(
        said.contains("12 shards (4 hard-linked, 0 copied, 8 pruned)") && said.contains("2 caches combined"),
        "{said}"
    );
    ok(dynforge(&["verify", &arg(&out)]));
    ok(dynforge(&["dataset", "prepare", &arg(&single)]));
    ok(dynforge(&[&["dataset", "prepare", &arg(&single)][..], &transformer].concat()));
    let (merged, whole) = (caches(&out), caches(&single));
    assert_eq!(merged.len(), 2);
    assert_eq!(merged.keys().collect::<Vec<_>>(), whole.keys().collect::<Vec<_>>(), "the same cache names");
    assert!(merged == whole, "the combined caches differ from the single-host run's");

    // Both train the same weights; other settings than the prepared ones are refused, naming the pruned shards.
    for (data, ckpt) in [(&out, "c-merged"), (&single, "c-single")] {
        let c = root.path().join(ckpt);
        ok(dynforge(&["train", &arg(data), "--out", &arg(&c), "--epochs", "1", "--generated", "512", "--dim", "32"]));
    }
    let weights = |c: &str| std::fs::read(root.path().join(c).join("model.safetensors")).unwrap();
    assert!(weights("c-merged") == weights("c-single"), "different weights from the same data");
    let o = dynforge(&["train", &arg(&out), "--out", &arg(&root.path().join("c-other")), "--len", "16"]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("pruned.txt"), "{o:?}");
    // With no shard left, the kinematics come from the generator: the same features, so the same windows cache.
    let c = root.path().join("c-transformer");
    let o = dynforge(
        &[
            &["train", &arg(&parts[1]), "--out", &arg(&c), "--epochs", "1", "--preset", "fast", "--len", "32"][..],
            &transformer[..2],
        ]
        .concat(),
    );
    ok(o);
    assert!(c.join("model.safetensors").exists());
}

/// Nested subsets of one large run: partitions 1/4 and 3/4 hold exactly the robots of partition 1/2 (r % 2 == 1), so,
/// pruned to their window caches, they merge into what `generate --partition 1/2` and `prepare` write, byte for byte
/// (the caches combined block by block from the files).
#[test]
fn partitions_of_a_coarser_partition_merge_into_it() {
    let ok = |o: Output| {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).to_string()
    };
    let arg = |p: &Path| p.to_str().unwrap().to_string();
    let prepare = |d: &Path, prune: bool| {
        let mut a = vec!["dataset".to_string(), "prepare".into(), arg(d), "--model".into(), "transformer".into()];
        a.extend(["--window".into(), "32:64:16".into()]);
        if prune {
            a.push("--prune".into());
        }
        ok(dynforge(&a.iter().map(String::as_str).collect::<Vec<_>>()))
    };
    let root = tempfile::tempdir().unwrap();
    let direct = root.path().join("direct");
    ok(dynforge(&generate_args(&direct, "8", "2", &["--workers", "2", "--partition", "1/2"])));
    prepare(&direct, false);
    let parts: Vec<std::path::PathBuf> = [1, 3].iter().map(|i| root.path().join(format!("part{i}"))).collect();
    for (i, p) in [1, 3].iter().zip(&parts) {
        let part = format!("{i}/4");
        ok(dynforge(&generate_args(p, "8", "2", &["--workers", "1", "--partition", &part])));
        prepare(p, true);
    }
    let out = root.path().join("merged");
    let said = ok(dynforge(&["merge", "--out", &arg(&out), &arg(&parts[1]), &arg(&parts[0])]));
    assert!(said.contains("merged 2 partitions") && said.contains("1 caches combined"), "{said}");
    assert_eq!(
        std::fs::read_to_string(out.join("manifest.toml")).unwrap(),
        std::fs::read_to_string(direct.join("manifest.toml")).unwrap(),
        "the manifest of partition 1/2"
    );
    let set = |d: &Path| ledger_entries(d).iter().map(|e| format!("{e:?}")).collect::<BTreeSet<_>>();
    assert_eq!(set(&out), set(&direct), "the same ledger records");
    let (merged, single) = (caches(&out), caches(&direct));
    assert_eq!(merged.keys().collect::<Vec<_>>(), single.keys().collect::<Vec<_>>(), "the same cache names");
    assert!(merged == single, "the combined windows cache differs from partition 1/2's own");
    assert_verifies(&out);
    // Partitions 0/4 and 1/4 are robots r % 4 in {0, 1}: no partition of the run.
    let zero = root.path().join("part0");
    ok(dynforge(&generate_args(&zero, "8", "2", &["--workers", "1", "--partition", "0/4"])));
    let o = dynforge(&["merge", "--out", &arg(&root.path().join("no")), &arg(&zero), &arg(&parts[0])]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("partition(s) 2/4, 3/4 missing"), "{o:?}");
}

/// The live display on a real terminal (a pty from util-linux `script`, 80 columns): the bar line is cut to the
/// width instead of wrapping, the worker spinners turn, and after Ctrl-C the bar stays at the jobs recorded.
#[test]
fn the_display_fits_the_terminal_and_an_interrupted_bar_stays_where_the_ledger_is() {
    if Command::new("script").arg("--version").output().is_err() {
        eprintln!("skipped: no `script` (util-linux) to make a terminal");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (out, typescript) = (dir.path().join("run"), dir.path().join("typescript"));
    let command = format!(
        "stty cols 80 rows 30; exec {EXE} generate --out {} --robots 12 --trajectories 16 --workers 2 --seed 5",
        out.display()
    );
    let mut script = Command::new("script")
        .args(["-qfec", &command, typescript.to_str().unwrap()])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let recorded = || std::fs::read_to_string(out.join("ledger.tsv")).map_or(0, |l| l.lines().count());
    let start = Instant::now();
    while recorded() < 10 {
        assert!(start.elapsed() < Duration::from_secs(120), "no progress");
        std::thread::sleep(Duration::from_millis(50));
    }
    // `script` runs a shell that execs dynforge: its child is the coordinator.
    let coordinator = children_of(script.id())
        .into_iter()
        .find(|&p| std::fs::read_to_string(format!("/proc/{p}/cmdline")).unwrap_or_default().contains("generate"))
        .expect("the coordinator runs under script");
    assert!(Command::new("kill").args(["-INT", &coordinator.to_string()]).status().unwrap().success());
    assert_eq!(script.wait().unwrap().code(), Some(130), "an interrupted run exits as the shell's Ctrl-C does");

    // What the terminal was sent, as the lines it showed: cursor movements end a line, other escapes draw nothing.
    let raw = String::from_utf8_lossy(&std::fs::read(&typescript).unwrap()).to_string();
    let mut text = String::new();
    let mut chars = raw.chars().peekable();
    while let Some(c) = chars.next() {
        if c != '\x1b' {
            text.push(c);
            continue;
        }
        if chars.next_if_eq(&'[').is_some() {
            let mut last = ' ';
            for d in chars.by_ref() {
                last = d;
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
            if "ABEFGH".contains(last) {
                text.push('\n');
            }
        }
    }
    let spinner = |c: char| ('\u{2800}'..='\u{28ff}').contains(&c);
    let frames: Vec<&str> = text.split(['\r', '\n']).filter(|l| l.contains(" jobs, ETA ")).collect();
    assert!(!frames.is_empty(), "no progress bar drawn:\n{text}");
    for f in &frames {
        // From the bar's start (a message printed above it may share the line's bytes) to the first spinner.
        let from = f.find(['█', '░']).unwrap_or(0);
        let bar = f[from..].split(spinner).next().unwrap();
        assert!(bar.chars().count() <= 80, "a bar line wider than the terminal: {bar:?}");
    }
    let glyphs: BTreeSet<char> = text.chars().filter(|&c| spinner(c)).collect();
    assert!(glyphs.len() >= 2, "the worker spinners never moved: {glyphs:?}");
    let last = frames.last().unwrap();
    let shown: usize =
        last.split(" jobs").next().unwrap().rsplit(' ').next().unwrap().split('/').next().unwrap().parse().unwrap();
    assert!(shown < 192 && shown == recorded(), "the bar ended at {shown}/192, the ledger has {}: {last}", recorded());
}

/// What a monitor reads of a live run that resumed most of its jobs: the pool is counted after the freed workers got
/// their next job (never one idle worker while jobs wait), and the rate counts this run's jobs only, so the ETA does
/// not take the resumed ones for instant progress.
#[test]
fn a_resumed_runs_live_status_shows_a_full_pool_and_its_own_rate() {
    let dir = tempfile::tempdir().unwrap();
    let args = generate_args(dir.path(), "12", "16", &["--workers", "2"]);
    let mut first = spawn(&args);
    wait_for_entries(dir.path(), 120, &mut first);
    kill(first.id(), "-INT");
    assert_eq!(first.wait().unwrap().code(), Some(130), "an interrupted run exits as the shell's Ctrl-C does");
    let resumed = ledger_entries(dir.path()).len() as u64;
    assert!(resumed < 192, "the run finished before it was interrupted");

    let mut run = spawn(&args);
    let start = Instant::now();
    let mut samples = Vec::new();
    while run.try_wait().unwrap().is_none() && start.elapsed() < Duration::from_secs(120) {
        let out = dynforge(&["status", dir.path().to_str().unwrap(), "--json"]);
        let Ok(v) = serde_json::from_slice::<serde_json::Value>(&out.stdout) else { continue };
        if v["live"] == true && v.get("in_flight").is_some() {
            samples.push((start.elapsed().as_secs_f64(), v));
        }
    }
    assert!(run.wait().unwrap().success());
    assert_exactly_once(dir.path(), 192);
    let n = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
    let finished = |v: &serde_json::Value| n(v, "done") + n(v, "discarded") + n(v, "failed");
    // Once every worker has reported a job (so both are connected) and while at least two jobs are left.
    let steady: Vec<_> = samples
        .iter()
        .filter(|(_, v)| finished(v) >= resumed as f64 + 2.0 && n(v, "total") - finished(v) >= 2.0)
        .collect();
    assert!(steady.len() >= 3, "too few live samples: {samples:?}");
    for (t, v) in &steady {
        assert_eq!(n(v, "workers_alive"), 2.0, "{v}");
        assert_eq!(n(v, "in_flight"), 2.0, "a worker shown idle while jobs wait: {v}");
        // This run's rate is (finished - resumed) / its own time, at most the monitor's time t (it started later);
        // counting the resumed jobs it would exceed resumed / t. While few new jobs are done the two are far apart.
        let new = finished(v) - resumed as f64;
        if new <= resumed as f64 / 4.0 {
            let rate = n(v, "rate_per_s");
            assert!(rate < resumed as f64 / t, "the rate counts resumed jobs: {rate} jobs/s at {t:.2} s, {v}");
            let eta = n(v, "eta_s");
            assert!((eta * rate - (n(v, "total") - finished(v))).abs() < 1e-6 * n(v, "total"), "{v}");
        }
    }
}
