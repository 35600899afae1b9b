//! End-to-end tests of the hostile cases an operator campaign found (issue 24, items 14-22): the real binary, real
//! processes, real kills. Each case is one that failed before its fix.

mod common;

use common::dynforge;
use std::path::Path;
use std::process::Output;
use std::time::Duration;

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
