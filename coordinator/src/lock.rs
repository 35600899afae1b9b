//! One generation per run directory: an advisory lock on `DIR/lock`, taken before anything in the directory is read
//! for writing, cleaned or rewritten, and held by the coordinator and its worker processes.
//!
//! Why a lock file and not only the coordinator check over shared memory: `/dev/shm` is per host, so two hosts that
//! share the directory (a cluster's filesystem) cannot see each other there, and the check comes after the manifest,
//! the ledger and the leftover temporary files have been handled. `flock` on a file of the directory itself is seen
//! by every process on the host and, on NFSv4 and Lustre, across hosts (Linux maps it to a byte-range lock there).
//!
//! The workers inherit the lock (the same open file description), so it is released only when the coordinator *and*
//! every worker it started are gone: a resume after `kill -9` of the coordinator cannot start while one of its
//! orphans still writes. Orphans do not linger: each worker gets `SIGKILL` when its coordinator dies
//! ([`Processes`](crate::run)), and their writes follow the temporary-file rule, so nothing partial is left.

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
    #[error("{dir}: another generate is using this directory ({holder}); wait for it or stop it first")]
    Busy { dir: String, holder: String },
    #[error("{file}: cannot lock the run directory: {source}")]
    Io { file: String, source: std::io::Error },
}

/// The held lock; released when dropped (and when the last worker that inherited it exits).
#[derive(Debug)]
pub struct RunLock {
    file: File,
}

impl RunLock {
    /// Takes the lock of `dir` (created if missing). A holder that is alive (or on another host) refuses it at once;
    /// when the coordinator that took it is dead, its orphan workers still hold it until their kill signal lands (a
    /// few milliseconds), so that case is waited for, up to `wait`.
    pub fn acquire(dir: &Path, wait: Duration) -> Result<RunLock, LockError> {
        let path = dir.join(LOCK);
        let io = |source| LockError::Io { file: path.display().to_string(), source };
        std::fs::create_dir_all(dir).map_err(io)?;
        let mut file =
            OpenOptions::new().read(true).write(true).create(true).truncate(false).open(&path).map_err(io)?;
        let start = Instant::now();
        loop {
            match file.try_lock() {
                Ok(()) => break,
                Err(TryLockError::WouldBlock) => {
                    // A holder that has just taken the lock writes who it is a moment later.
                    let holder = describe(&mut file);
                    let unwritten = holder.is_none() && start.elapsed() < DESCRIPTION_WAIT;
                    let gone = holder.as_deref().is_some_and(holder_is_gone) && start.elapsed() < wait;
                    if !(unwritten || gone) {
                        let holder = holder.unwrap_or_else(|| "holder unknown".into());
                        return Err(LockError::Busy { dir: dir.display().to_string(), holder });
                    }
                    std::thread::sleep(Duration::from_millis(5));
                }
                Err(TryLockError::Error(e)) => return Err(io(e)),
            }
        }
        // Who holds it, for the message of anyone refused. Not synced: it is a courtesy, the lock is the flock.
        let holder = format!("pid {} on {}", std::process::id(), hostname());
        file.set_len(0).and_then(|()| file.rewind()).and_then(|()| file.write_all(holder.as_bytes())).map_err(io)?;
        Ok(RunLock { file })
    }

    /// The lock's file descriptor, for worker processes to inherit.
    pub fn fd(&self) -> std::os::fd::RawFd {
        use std::os::fd::AsRawFd;
        self.file.as_raw_fd()
    }
}

/// Who holds the lock of `dir`, if anyone does (a generation is live there).
pub fn holder(dir: &Path) -> Option<String> {
    let mut file = OpenOptions::new().read(true).write(true).open(dir.join(LOCK)).ok()?;
    match file.try_lock() {
        Ok(()) => None,
        Err(TryLockError::WouldBlock) => Some(describe(&mut file).unwrap_or_else(|| "holder unknown".into())),
        Err(TryLockError::Error(_)) => None,
    }
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default().trim().to_string()
}

/// Whether the lock's description names a process of this host that no longer runs.
fn holder_is_gone(description: &str) -> bool {
    let Some((pid, host)) = description.strip_prefix("pid ").and_then(|r| r.split_once(" on ")) else {
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

/// The holder's description in the lock file, if written yet.
fn describe(file: &mut File) -> Option<String> {
    let mut text = String::new();
    let _ = file.rewind().and_then(|()| file.read_to_string(&mut text));
    match text.trim() {
        "" => None,
        t => Some(t.chars().take(200).collect()),
    }
}
