//! The worker processes: started with the run directory and a slot, their stderr into `logs/worker-K.log`, killed
//! when hung or at the end, and by the kernel when the coordinator dies. They inherit the run directory's lock, so a
//! new coordinator cannot start while one of them is still alive.

use std::ffi::OsString;
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

use dynforge_proto::run_dir::{LOGS, open_for_writing};

use super::GenerateError;
use dynforge_proto::lock::RunLock;

pub(super) struct Processes {
    command: Vec<OsString>,
    dir: PathBuf,
    children: Vec<Option<Child>>,
    lock: RunLock,
}

impl Processes {
    pub(super) fn new(command: Vec<OsString>, dir: PathBuf, slots: usize, lock: RunLock) -> Self {
        Processes { command, dir, children: (0..slots).map(|_| None).collect(), lock }
    }

    /// The log of worker slot `slot` (its stderr).
    pub(super) fn log(&self, slot: usize) -> PathBuf {
        self.dir.join(LOGS).join(format!("worker-{slot}.log"))
    }

    /// Slots with a started process.
    pub(super) fn alive(&self) -> usize {
        self.children.iter().filter(|c| c.is_some()).count()
    }

    pub(super) fn spawn(&mut self, slot: usize) -> Result<(), GenerateError> {
        self.kill(slot);
        let path = self.log(slot);
        let log = open_for_writing(std::fs::OpenOptions::new().create(true).append(true), &path)
            .map_err(|source| GenerateError::WorkerLog { file: path.display().to_string(), source })?;
        let (program, args) = self.command.split_first().expect("a worker command");
        let (lock, parent) = (self.lock.fd(), std::process::id());
        let mut command = Command::new(program);
        // SAFETY: between fork and exec the closure makes only async-signal-safe system calls.
        unsafe {
            command.pre_exec(move || {
                // Killed when the coordinator dies: the orphans of a `kill -9` would run on and race the resume.
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                // It may have died before the line above: then nobody would signal us.
                if libc::getppid() as u32 != parent {
                    libc::_exit(1);
                }
                // Keep the run directory's lock across exec.
                let flags = libc::fcntl(lock, libc::F_GETFD);
                if flags < 0 || libc::fcntl(lock, libc::F_SETFD, flags & !libc::FD_CLOEXEC) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let child = command
            .args(args)
            .arg("--dir")
            .arg(&self.dir)
            .arg("--slot")
            .arg(slot.to_string())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map_err(|source| GenerateError::Spawn { slot, program: program.to_string_lossy().into(), source })?;
        self.children[slot] = Some(child);
        Ok(())
    }

    pub(super) fn kill(&mut self, slot: usize) {
        if let Some(mut child) = self.children[slot].take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }

    /// Slots whose process has exited (before or without the coordinator noticing through iceoryx2), with how.
    pub(super) fn exited(&mut self) -> Vec<(usize, std::process::ExitStatus)> {
        let mut out = Vec::new();
        for (k, c) in self.children.iter_mut().enumerate() {
            if let Some(child) = c
                && let Ok(Some(status)) = child.try_wait()
            {
                out.push((k, status));
            }
        }
        out
    }
}

impl Drop for Processes {
    fn drop(&mut self) {
        for k in 0..self.children.len() {
            self.kill(k);
        }
    }
}
