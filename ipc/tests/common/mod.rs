//! Helpers for the transport tests: worker processes, unique runs, leftover checks.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use dynforge_ipc::{Coordinator, RunId, cleanup_stale};

pub const WORKER_EXE: &str = env!("CARGO_BIN_EXE_dynforge-ipc-test-worker");

/// A run id unique to this test process and `tag`; its leftovers are removed (and checked) on drop.
pub struct TestRun {
    pub id: RunId,
}

impl TestRun {
    pub fn new(tag: &str) -> Self {
        let id = RunId::new(&format!("{tag}-{}", std::process::id())).unwrap();
        cleanup_stale(&id).unwrap();
        Self { id }
    }

    /// Files of this run in /dev/shm and under /tmp/iceoryx2.
    pub fn files(&self) -> Vec<PathBuf> {
        let prefix = format!("{}_", self.id);
        let mut out = Vec::new();
        collect(Path::new("/dev/shm"), &prefix, 0, &mut out);
        collect(Path::new("/tmp/iceoryx2"), &prefix, 3, &mut out);
        out
    }
}

fn collect(dir: &Path, prefix: &str, depth: usize, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let path = e.path();
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            if depth > 0 {
                collect(&path, prefix, depth - 1, out);
            }
        } else if e.file_name().to_string_lossy().starts_with(prefix) {
            out.push(path);
        }
    }
}

impl Drop for TestRun {
    fn drop(&mut self) {
        cleanup_stale(&self.id).unwrap();
        let left = self.files();
        if !std::thread::panicking() {
            assert!(left.is_empty(), "leftovers of run {}: {left:?}", self.id);
        }
    }
}

/// Worker processes, killed (and reaped) on drop.
#[derive(Default)]
pub struct Workers(pub Vec<Option<Child>>);

impl Workers {
    /// Spawns the test worker for slot `k` (with `DYNFORGE_TEST_HANG=1` if `hang`: jobs of robot 666 sleep 60 s).
    pub fn spawn(&mut self, run: &RunId, k: usize, hang: bool) {
        let mut cmd = Command::new(WORKER_EXE);
        cmd.arg(run.as_str()).arg(k.to_string()).stdin(Stdio::null());
        if hang {
            cmd.env("DYNFORGE_TEST_HANG", "1");
        }
        let child = cmd.spawn().expect("spawning the test worker");
        if self.0.len() <= k {
            self.0.resize_with(k + 1, || None);
        }
        if let Some(mut old) = self.0[k].replace(child) {
            let _ = old.kill();
            let _ = old.wait();
        }
    }

    pub fn pid(&self, k: usize) -> u32 {
        self.0[k].as_ref().unwrap().id()
    }

    pub fn kill(&mut self, k: usize) {
        if let Some(mut c) = self.0[k].take() {
            c.kill().unwrap();
            c.wait().unwrap();
        }
    }

    /// Waits for every worker to exit by itself (after the coordinator is dropped), up to `timeout`.
    pub fn join(&mut self, timeout: Duration) {
        let start = Instant::now();
        for c in self.0.iter_mut() {
            let Some(child) = c else { continue };
            loop {
                if let Some(status) = child.try_wait().unwrap() {
                    assert!(status.success(), "worker exited with {status}");
                    break;
                }
                assert!(start.elapsed() < timeout, "worker did not exit within {timeout:?}");
                std::thread::sleep(Duration::from_millis(5));
            }
            *c = None;
        }
    }
}

impl Drop for Workers {
    fn drop(&mut self) {
        for k in 0..self.0.len() {
            self.kill(k);
        }
    }
}

/// Spawns workers for `slots` and attaches them; waits until all are ready.
pub fn start(coord: &mut Coordinator, workers: &mut Workers, run: &RunId, slots: usize) {
    for k in 0..slots {
        workers.spawn(run, k, false);
        coord.attach_worker(k).unwrap();
    }
    for k in 0..slots {
        wait_ready(coord, k);
    }
}

pub fn wait_ready(coord: &Coordinator, k: usize) {
    let start = Instant::now();
    while !coord.worker_ready(k) {
        assert!(start.elapsed() < Duration::from_secs(10), "worker {k} not ready within 10 s");
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// CPU time of process `pid`'s main thread.
pub fn process_cpu(pid: u32) -> Duration {
    let s = std::fs::read_to_string(format!("/proc/{pid}/schedstat")).unwrap();
    Duration::from_nanos(s.split_whitespace().next().unwrap().parse().unwrap())
}

/// CPU time of the calling thread.
pub fn thread_cpu() -> Duration {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").unwrap();
    Duration::from_nanos(s.split_whitespace().next().unwrap().parse().unwrap())
}
