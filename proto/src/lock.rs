//! One writer per run directory: an advisory lock on `DIR/lock`, taken before anything in the directory is read
//! for writing, cleaned or rewritten. `generate` holds it for the whole run (and its worker processes with it),
//! `dataset prepare` and `prepare --prune` while they cache and prune, `verify --repair` while it marks jobs, `merge`
//! on its output, and `train` or `evaluate` for the moment they write a cache. Whoever holds it names itself in the
//! file ([`Holder`]), so a refused command says what it waits for ("another dataset prepare --prune", not "another
//! generate").
//!
//! Why a lock file and not only the coordinator check over shared memory: `/dev/shm` is per host, so two hosts that
//! share the directory (a cluster's filesystem) cannot see each other there, and the check comes after the manifest,
//! the ledger and the leftover temporary files have been handled. `flock` on a file of the directory itself is seen
//! by every process on the host and, on NFSv4 and Lustre, across hosts (Linux maps it to a byte-range lock there).
//!
//! The workers of a generation inherit the lock (the same open file description), so it is released only when the
//! coordinator *and* every worker it started are gone: a resume after `kill -9` of the coordinator cannot start while
//! one of its orphans still writes. Orphans do not linger: each worker gets `SIGKILL` when its coordinator dies, and
//! their writes follow the temporary-file rule ([`crate::run_dir`]), so nothing partial is left.

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, Write};
use std::path::Path;
use std::time::{Duration, Instant};

/// The lock file's name in the run directory.
pub const LOCK: &str = "lock";

/// How long a refused process waits for the holder's description (written right after it takes the lock).
const DESCRIPTION_WAIT: Duration = Duration::from_millis(500);

#[derive(Debug, thiserror::Error)]
pub enum LockError {
    #[error("{dir}: another {} is using this directory ({}); wait for it or stop it first", .holder.what, .holder.process)]
    Busy { dir: String, holder: Holder },
    #[error("{file}: cannot lock the run directory: {source}")]
    Io { file: String, source: std::io::Error },
}

/// Who holds a run directory's lock: the command (`generate`, `dataset prepare --prune`, ...) and its process.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holder {
    pub what: String,
    /// `pid N on HOST`, or what the file said when it was written by something else.
    pub process: String,
}

impl Holder {
    /// The holder that the lock file's text `text` describes: `pid N on HOST: WHAT`.
    fn parse(text: &str) -> Holder {
        match text.split_once(": ") {
            Some((process, what)) if process.starts_with("pid ") => {
                Holder { what: what.to_string(), process: process.to_string() }
            }
            _ => Holder { what: "dynforge process".into(), process: text.to_string() },
        }
    }

    fn unknown() -> Holder {
        Holder { what: "dynforge process".into(), process: "holder unknown".into() }
    }

    /// Whether the holder is a process of this host that no longer runs.
    fn is_gone(&self) -> bool {
        let Some((pid, host)) = self.process.strip_prefix("pid ").and_then(|r| r.split_once(" on ")) else {
            return false;
        };
        if host != hostname() {
            return false;
        }
        match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
            // State is the field after the parenthesised command name; Z: exited, not yet reaped.
            Ok(stat) => stat.rsplit_once(')').is_some_and(|(_, rest)| rest.trim_start().starts_with('Z')),
            Err(_) => true,
        }
    }
}

impl std::fmt::Display for Holder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({})", self.what, self.process)
    }
}

/// The held lock; released when dropped (and when the last worker that inherited it exits).
#[derive(Debug)]
pub struct RunLock {
    file: File,
}

impl RunLock {
    /// Takes the lock of `dir` (created if missing) for the command `what` (named to anyone refused). A holder that
    /// is alive (or on another host) refuses it at once; when the process that took it is dead, orphan workers may
    /// still hold it until their kill signal lands (a few milliseconds), so that case is waited for, up to `wait`.
    pub fn acquire(dir: &Path, wait: Duration, what: &str) -> Result<RunLock, LockError> {
        let path = dir.join(LOCK);
        let io = |source| LockError::Io { file: path.display().to_string(), source };
        std::fs::create_dir_all(dir).map_err(io)?;
        let mut file = crate::run_dir::open_for_writing(
            OpenOptions::new().read(true).write(true).create(true).truncate(false),
            &path,
        )
        .map_err(io)?;
        let start = Instant::now();
        loop {
            match file.try_lock() {
                Ok(()) => break,
                Err(TryLockError::WouldBlock) => {
                    // A holder that has just taken the lock writes who it is a moment later.
                    let holder = describe(&mut file);
                    let unwritten = holder.is_none() && start.elapsed() < DESCRIPTION_WAIT;
                    let gone = holder.as_ref().is_some_and(Holder::is_gone) && start.elapsed() < wait;
                    if !(unwritten || gone) {
                        let holder = holder.unwrap_or_else(Holder::unknown);
                        return Err(LockError::Busy { dir: dir.display().to_string(), holder });
                    }
                    std::thread::sleep(Duration::from_millis(5));
                }
                Err(TryLockError::Error(e)) => return Err(io(e)),
            }
        }
        // Who holds it, for the message of anyone refused. Not synced: it is a courtesy, the lock is the flock.
        let holder = format!("pid {} on {}: {what}", std::process::id(), hostname());
        file.set_len(0).and_then(|()| file.rewind()).and_then(|()| file.write_all(holder.as_bytes())).map_err(io)?;
        Ok(RunLock { file })
    }

    /// The lock's file descriptor, for worker processes to inherit.
    pub fn fd(&self) -> std::os::fd::RawFd {
        use std::os::fd::AsRawFd;
        self.file.as_raw_fd()
    }
}

/// Who holds the lock of `dir`, if anyone does (a generation, a prune, ... is live there).
pub fn holder(dir: &Path) -> Option<Holder> {
    let mut file = crate::run_dir::open_for_writing(OpenOptions::new().read(true).write(true), &dir.join(LOCK)).ok()?;
    match file.try_lock() {
        Ok(()) => None,
        Err(TryLockError::WouldBlock) => Some(describe(&mut file).unwrap_or_else(Holder::unknown)),
        Err(TryLockError::Error(_)) => None,
    }
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default().trim().to_string()
}

/// The holder's description in the lock file, if written yet.
fn describe(file: &mut File) -> Option<Holder> {
    let mut text = String::new();
    let _ = file.rewind().and_then(|()| file.read_to_string(&mut text));
    match text.trim() {
        "" => None,
        t => Some(Holder::parse(&t.chars().take(200).collect::<String>())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refused_command_is_told_what_holds_the_directory() {
        let dir = tempfile::tempdir().unwrap();
        let _held = RunLock::acquire(dir.path(), Duration::ZERO, "dataset prepare --prune").unwrap();
        let e = RunLock::acquire(dir.path(), Duration::ZERO, "generate").unwrap_err().to_string();
        assert!(e.contains("another dataset prepare --prune is using this directory (pid "), "{e}");
        let h = holder(dir.path()).unwrap();
        assert_eq!(h.what, "dataset prepare --prune");
        assert!(h.process.starts_with(&format!("pid {} on ", std::process::id())), "{h}");
        // A file written by something else is shown as it is.
        assert_eq!(Holder::parse("someone"), Holder { what: "dynforge process".into(), process: "someone".into() });
    }

    #[test]
    fn a_lock_file_that_is_a_link_is_refused_and_its_target_untouched() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("precious");
        std::fs::write(&target, b"keep me").unwrap();
        let run = dir.path().join("run");
        std::fs::create_dir(&run).unwrap();
        std::os::unix::fs::symlink(&target, run.join(LOCK)).unwrap();
        let e = RunLock::acquire(&run, Duration::ZERO, "generate").unwrap_err().to_string();
        assert!(e.contains("run/lock") && e.contains("symbolic link"), "{e}");
        assert_eq!(std::fs::read(&target).unwrap(), b"keep me");
    }
}
