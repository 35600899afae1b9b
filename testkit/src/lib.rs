//! Helpers shared by dynforge's test suites.

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};

/// The Python of the reference-tool venv (`DYNFORGE_PYTHON`, set by `scripts/test.sh`). Without it, tests that
/// compare against independent references report that they were skipped, unless `DYNFORGE_REQUIRE_REFERENCE=1`
/// (also set by the test script), where a missing venv is an error.
pub fn reference_python() -> Option<String> {
    match std::env::var("DYNFORGE_PYTHON") {
        Ok(p) => Some(p),
        Err(_) if std::env::var("DYNFORGE_REQUIRE_REFERENCE").is_ok_and(|v| v == "1") => {
            panic!("DYNFORGE_REQUIRE_REFERENCE=1 but DYNFORGE_PYTHON is not set")
        }
        Err(_) => {
            eprintln!("SKIPPED: this reference test needs DYNFORGE_PYTHON (scripts/test.sh sets it)");
            None
        }
    }
}

/// Runs `python script args...` with `stdin`, panicking with its stderr if it fails; returns its stdout.
pub fn run_python(python: &str, script: &Path, args: &[&str], stdin: &str) -> String {
    let mut child = Command::new(python)
        .arg(script)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {python}: {e}"));
    child.stdin.take().expect("piped").write_all(stdin.as_bytes()).expect("stdin accepted");
    let out = child.wait_with_output().expect("python finishes");
    assert!(out.status.success(), "{} failed:\n{}", script.display(), String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).expect("UTF-8 output")
}
