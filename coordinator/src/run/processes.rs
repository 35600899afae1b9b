//! The worker processes: started with the run directory and a slot, their stderr into `logs/worker-K.log`, killed
//! when hung or at the end.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

use dynforge_proto::run_dir::LOGS;

use super::GenerateError;

pub(super) struct Processes {
    command: Vec<OsString>,
    dir: PathBuf,
    children: Vec<Option<Child>>,
}

impl Processes {
    pub(super) fn new(command: Vec<OsString>, dir: PathBuf, slots: usize) -> Self {
        Processes { command, dir, children: (0..slots).map(|_| None).collect() }
    }

    /// Slots with a started process.
    pub(super) fn alive(&self) -> usize {
        self.children.iter().filter(|c| c.is_some()).count()
    }

    pub(super) fn spawn(&mut self, slot: usize) -> Result<(), GenerateError> {
        self.kill(slot);
        let logs = self.dir.join(LOGS);
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(logs.join(format!("worker-{slot}.log")))
            .map_err(|source| GenerateError::Dir { dir: logs.display().to_string(), source })?;
        let (program, args) = self.command.split_first().expect("a worker command");
        let child = Command::new(program)
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

    /// Slots whose process has exited (before or without the coordinator noticing through iceoryx2).
    pub(super) fn exited(&mut self) -> Vec<usize> {
        let mut out = Vec::new();
        for (k, c) in self.children.iter_mut().enumerate() {
            if let Some(child) = c
                && matches!(child.try_wait(), Ok(Some(_)))
            {
                out.push(k);
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
