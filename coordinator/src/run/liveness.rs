//! Workers that died (their iceoryx2 node is dead, or their process exited) or hung (no final report within the
//! job timeout) are killed and replaced; their jobs go back to the queue through `settle`.

use super::{GenerateError, Observer, Run};

impl Run<'_> {
    pub(super) fn liveness(&mut self, observer: &mut dyn Observer) -> Result<(), GenerateError> {
        let mut lost: Vec<(usize, String)> =
            self.ipc.dead_workers().into_iter().map(|k| (k, "its worker died".to_string())).collect();
        for k in self.procs.exited() {
            if !lost.iter().any(|(s, _)| *s == k) {
                lost.push((k, "its worker exited".into()));
            }
        }
        let timeout = self.cfg.job_timeout;
        for (k, started) in self.running.iter().enumerate().filter_map(|(k, r)| r.map(|(_, t)| (k, t))) {
            if started.elapsed() > timeout && !lost.iter().any(|(s, _)| *s == k) {
                lost.push((k, format!("its worker hung (no result after {} s)", timeout.as_secs_f64())));
            }
        }
        for (k, why) in lost {
            self.procs.kill(k);
            if let Some((job, _)) = self.running[k].take() {
                self.settle(job, None, &why, observer)?;
            }
            if !self.interrupted && !self.pending.is_empty() {
                self.progress.respawns += 1;
                self.procs.spawn(k)?;
                self.ipc.attach_worker(k)?;
            }
        }
        Ok(())
    }
}
