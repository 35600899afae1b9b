//! The coordinator's side: one client per worker slot, one listener for every worker's notifications, the status
//! publisher, and liveness polling.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use iceoryx2::node::NodeView;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use iceoryx2_bb_posix::signal::SignalHandler;

use crate::error::{Context, IpcError};
use crate::run::{self, RunId};
use crate::services::{self, EventService, JobsClient, JobsService, Pending, StatusService, Svc};
use crate::types::{StatusMsg, WireReport, WireRequest};
use dynforge_proto::job::{JobReport, JobRequest};

/// A worker that has not answered a sent job yet is poked again this often (guards against lost wake-ups).
pub const REPOKE_INTERVAL: Duration = Duration::from_millis(200);

struct Slot {
    jobs: JobsService,
    client: JobsClient,
    _poke_service: EventService,
    poke: Notifier<Svc>,
    /// The worker's node: the owner of the slot's server, learned by `attach_worker`, `send` or `dead_workers`.
    node_id: Option<iceoryx2::identifiers::UniqueNodeId>,
    pid: Option<i32>,
    /// Reported by `dead_workers`; stays so until the slot is attached again.
    dead: bool,
    /// The job sent and not finally answered (kept after the worker's death, see `Coordinator::in_flight`).
    job: Option<JobRequest>,
    pending: Option<Pending>,
    answered: bool,
    last_heard: Instant,
    last_poke: Instant,
}

/// The coordinator's end of the transport. Lives in the coordinator process (not `Send`: iceoryx2 ports are
/// bound to their thread). Dropping it asks every attached worker to exit.
pub struct Coordinator {
    run: RunId,
    cfg: Config,
    slots: Vec<Option<Slot>>,
    listener: Listener<Svc>,
    _reports: EventService,
    publisher: Publisher<Svc, StatusMsg, ()>,
    _status: StatusService,
    waitset: WaitSet<Svc>,
    node: Node<Svc>,
}

impl Coordinator {
    /// Starts the coordinator of `run` with room for `max_workers` worker slots (0..max_workers). Removes the
    /// dead nodes of a previous coordinator of the same run; fails if a coordinator of the run is alive.
    pub fn new(run: &RunId, max_workers: usize) -> Result<Self, IpcError> {
        let cfg = run::config(run)?;
        let mut other = None;
        let mut old_workers = Vec::new();
        run::list_nodes(&cfg, |state| {
            if let NodeState::Alive(view) = &state {
                if run::is_coordinator(view.details()) {
                    other = view.details().as_ref().map(|d| d.process_id().value());
                } else if let Some(k) = run::worker_slot_of(view.details()) {
                    old_workers.push(k);
                }
            }
        });
        if let Some(pid) = other {
            return Err(IpcError::CoordinatorAlreadyRunning { pid: Some(pid) });
        }
        run::cleanup_stale(run)?;
        // From here on SIGINT/SIGTERM are recorded (and returned by `wait`) instead of killing the process.
        SignalHandler::termination_requested();

        let node = NodeBuilder::new()
            .name(&run::node_name(run::COORDINATOR_NODE)?)
            .config(&cfg)
            .create::<Svc>()
            .ctx(|| format!("creating the coordinator node of run {run}"))?;
        run::restrict_to_owner(run)?;
        // Two coordinators started at the same moment both saw none: both give up.
        let mut others = 0;
        run::list_nodes(&cfg, |state| {
            if let NodeState::Alive(view) = &state {
                others += usize::from(run::is_coordinator(view.details()) && view.id() != node.id());
            }
        });
        if others > 0 {
            return Err(IpcError::CoordinatorAlreadyRunning { pid: None });
        }
        // Workers of a crashed predecessor exit by themselves once they notice; ask them now.
        for k in old_workers {
            if let Some(poke) = services::poke_open(&node, k)
                && let Ok(notifier) = poke.notifier_builder().create()
            {
                let _ = notifier.notify_with_custom_event_id(services::POKE_STOP);
            }
        }
        let reports = services::reports_create(&node, max_workers)?;
        let listener = reports.listener_builder().create().ctx(|| "creating the reports listener".into())?;
        let status = services::status_create(&node)?;
        let publisher = status.publisher_builder().create().ctx(|| "creating the status publisher".into())?;
        let waitset = WaitSetBuilder::new().create::<Svc>().ctx(|| "creating the coordinator's WaitSet".into())?;
        Ok(Self {
            run: run.clone(),
            cfg,
            slots: (0..max_workers).map(|_| None).collect(),
            listener,
            _reports: reports,
            publisher,
            _status: status,
            waitset,
            node,
        })
    }

    pub fn run_id(&self) -> &RunId {
        &self.run
    }

    pub fn max_workers(&self) -> usize {
        self.slots.len()
    }

    fn check(&self, k: usize) -> Result<(), IpcError> {
        if k < self.slots.len() {
            Ok(())
        } else {
            Err(IpcError::SlotOutOfRange { slot: k, max_workers: self.slots.len() })
        }
    }

    /// Opens the services of worker slot `k`. Call it after spawning the process for slot `k`, also for a
    /// replacement worker (it resets the slot: a job still in flight there is forgotten). Removes the remains of
    /// dead predecessors in the slot first, so they are not mistaken for the new worker.
    pub fn attach_worker(&mut self, k: usize) -> Result<(), IpcError> {
        self.check(k)?;
        self.slots[k] = None;
        run::list_nodes(&self.cfg, |state| {
            if let NodeState::Dead(view) = state
                && run::worker_slot_of(view.details()) == Some(k)
            {
                let _ = view.try_remove_stale_resources();
            }
        });
        let jobs = services::jobs(&self.node, k)?;
        let client = jobs.client_builder().create().ctx(|| format!("creating the client of worker slot {k}"))?;
        let poke_service = services::poke(&self.node, k)?;
        let poke = poke_service.notifier_builder().create().ctx(|| format!("creating the notifier of slot {k}"))?;
        let now = Instant::now();
        let mut slot = Slot {
            jobs,
            client,
            _poke_service: poke_service,
            poke,
            node_id: None,
            pid: None,
            dead: false,
            job: None,
            pending: None,
            answered: false,
            last_heard: now,
            last_poke: now,
        };
        slot.learn_worker();
        self.slots[k] = Some(slot);
        Ok(())
    }

    /// Whether slot `k`'s worker has opened its server (and so can receive a job).
    pub fn worker_ready(&self, k: usize) -> bool {
        match self.slots.get(k) {
            Some(Some(slot)) => !slot.dead && slot.jobs.dynamic_config().number_of_servers() > 0,
            _ => false,
        }
    }

    /// Sends `job` to slot `k`'s worker and pokes it. At most one job is in flight per worker: `Busy` until its
    /// final report has been returned by [`Coordinator::wait`]. `WorkerNotReady` if no worker server is open.
    pub fn send(&mut self, k: usize, job: &JobRequest) -> Result<(), IpcError> {
        self.check(k)?;
        let slot = self.slots[k].as_mut().ok_or(IpcError::NotAttached(k))?;
        if slot.dead {
            return Err(IpcError::WorkerNotReady(k));
        }
        if let (Some(_), Some(busy)) = (&slot.pending, &slot.job) {
            return Err(IpcError::Busy { slot: k, job_id: busy.job_id });
        }
        slot.learn_worker();
        let pending =
            slot.client.send_copy(WireRequest::from(job)).ctx(|| format!("sending job {} to slot {k}", job.job_id))?;
        if pending.number_of_server_connections() == 0 {
            return Err(IpcError::WorkerNotReady(k));
        }
        slot.poke.notify_with_custom_event_id(services::POKE_JOB).ctx(|| format!("poking worker slot {k}"))?;
        let now = Instant::now();
        slot.job = Some(*job);
        slot.pending = Some(pending);
        slot.answered = false;
        slot.last_heard = now;
        slot.last_poke = now;
        Ok(())
    }

    /// Blocks up to `timeout` until reports arrive and returns all of them, as (worker slot, report), in arrival
    /// order per slot. Returns early as soon as there is at least one; an empty vector means the timeout passed.
    /// Every job gets exactly one final report; a live worker that drops a job without one yields a synthesized
    /// `Failed`. Workers that have not answered a job are re-poked every [`REPOKE_INTERVAL`].
    ///
    /// `Err(IpcError::Interrupted)` once per SIGINT/SIGTERM (iceoryx2 handles these signals after the first
    /// wait); later calls work normally, so a caller can still drain the jobs in flight.
    pub fn wait(&mut self, timeout: Duration) -> Result<Vec<(usize, JobReport)>, IpcError> {
        let deadline = Instant::now() + timeout;
        let mut out = Vec::new();
        // Monitors that subscribed since the last call get the latest status (history) now.
        let _ = self.publisher.update_connections();
        loop {
            let _ = self.listener.try_wait(|_| {});
            self.collect(&mut out)?;
            if !out.is_empty() {
                return Ok(out);
            }
            let now = Instant::now();
            self.repoke(now);
            if now >= deadline {
                return Ok(out);
            }
            let step = (deadline - now).min(REPOKE_INTERVAL);
            let result = {
                let _guard =
                    self.waitset.attach_notification(&self.listener).ctx(|| "attaching to the WaitSet".into())?;
                self.waitset
                    .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, step)
                    .ctx(|| "waiting for reports".into())?
            };
            match result {
                WaitSetRunResult::TerminationRequest => return Err(IpcError::Interrupted),
                // EINTR: a termination signal, or some other signal with a handler.
                WaitSetRunResult::Interrupt if SignalHandler::termination_requested() => {
                    return Err(IpcError::Interrupted);
                }
                _ => {}
            }
        }
    }

    /// Drains the responses of every job in flight.
    fn collect(&mut self, out: &mut Vec<(usize, JobReport)>) -> Result<(), IpcError> {
        let now = Instant::now();
        for (k, slot) in self.slots.iter_mut().enumerate() {
            let Some(slot) = slot else { continue };
            let Some(pending) = &slot.pending else { continue };
            // Before draining: a worker that answered and then dropped the request is not an abandoned job.
            let connected = pending.is_connected();
            let mut finished = false;
            while let Some(response) = pending.receive().ctx(|| format!("receiving from worker slot {k}"))? {
                let wire: WireReport = *response;
                slot.last_heard = now;
                slot.answered = true;
                out.push((k, JobReport::from(&wire)));
                if wire.is_final() {
                    finished = true;
                    break;
                }
            }
            if !finished && !connected {
                let job_id = slot.job.map_or(0, |j| j.job_id);
                let message = "the worker dropped the job without a final report".into();
                out.push((k, JobReport::Failed { job_id, message }));
                finished = true;
            }
            if finished {
                slot.pending = None;
                slot.job = None;
            }
        }
        Ok(())
    }

    fn repoke(&mut self, now: Instant) {
        for slot in self.slots.iter_mut().flatten() {
            if slot.pending.is_some() && !slot.answered && now - slot.last_poke >= REPOKE_INTERVAL {
                let _ = slot.poke.notify_with_custom_event_id(services::POKE_JOB);
                slot.last_poke = now;
            }
        }
    }

    /// Slots whose worker died (its node is dead, or it exited) since the last call, each reported once, after
    /// their stale resources have been removed. The caller re-queues the slot's job ([`Coordinator::in_flight`]
    /// still tells which) and respawns + re-attaches. Also removes other dead nodes of the run (killed monitors).
    /// Costs one scan of the run's nodes (~0.1-0.3 ms per node): call it on a tick, e.g. every 100 ms.
    ///
    /// A worker that dies before it created its node is not seen here: watch the child process too.
    pub fn dead_workers(&mut self) -> Vec<usize> {
        for slot in self.slots.iter_mut().flatten() {
            slot.learn_worker();
        }
        let mut alive = HashMap::new();
        let mut dead = Vec::new();
        let complete = run::list_nodes(&self.cfg, |state| match state {
            NodeState::Alive(view) => {
                alive.insert(*view.id(), view.details().as_ref().map(|d| d.process_id().value()));
            }
            NodeState::Dead(view) => dead.push(view),
            // Not known to be dead: count as alive.
            NodeState::Inaccessible(id) | NodeState::Undefined(id) => {
                alive.insert(id, None);
            }
        });
        let mut out = Vec::new();
        for view in dead {
            for (k, slot) in self.slots.iter_mut().enumerate() {
                if let Some(slot) = slot
                    && !slot.dead
                    && slot.node_id == Some(*view.id())
                {
                    slot.dead = true;
                    out.push(k);
                }
            }
            let _ = view.try_remove_stale_resources();
        }
        for (k, slot) in self.slots.iter_mut().enumerate() {
            let Some(slot) = slot else { continue };
            let Some(id) = slot.node_id else { continue };
            if !complete {
                break; // a node missing from an incomplete list may still be alive
            }
            match alive.get(&id) {
                Some(pid) if slot.pid.is_none() => slot.pid = *pid,
                Some(_) => {}
                None if !slot.dead => {
                    // Exited (cleanly, or died and was cleaned up by someone else).
                    slot.dead = true;
                    out.push(k);
                }
                None => {}
            }
        }
        for &k in &out {
            if let Some(Some(slot)) = self.slots.get_mut(k) {
                slot.pending = None;
            }
        }
        out.sort_unstable();
        out
    }

    /// The job sent to slot `k` and not finally answered yet. After [`Coordinator::dead_workers`] reported the
    /// slot, this is the job its worker lost; cleared by the next `attach_worker(k)`.
    pub fn in_flight(&self, k: usize) -> Option<JobRequest> {
        self.slots.get(k)?.as_ref()?.job
    }

    /// When slot `k` last sent a response, or was sent its job: with a deadline, the caller spots hung workers.
    pub fn last_heard(&self, k: usize) -> Option<Instant> {
        Some(self.slots.get(k)?.as_ref()?.last_heard)
    }

    /// Process id of slot `k`'s worker, once `dead_workers` has seen it.
    pub fn worker_pid(&self, k: usize) -> Option<i32> {
        self.slots.get(k)?.as_ref()?.pid
    }

    /// Asks slot `k`'s worker to exit: its `next_job` returns `None` (a job it is running is finished first).
    pub fn stop_worker(&mut self, k: usize) -> Result<(), IpcError> {
        self.check(k)?;
        let slot = self.slots[k].as_ref().ok_or(IpcError::NotAttached(k))?;
        slot.poke.notify_with_custom_event_id(services::POKE_STOP).ctx(|| format!("stopping worker slot {k}"))?;
        Ok(())
    }

    /// Publishes the run's status for monitors (each new monitor gets the latest one).
    pub fn publish_status(&mut self, s: &StatusMsg) -> Result<(), IpcError> {
        self.publisher.send_copy(*s).ctx(|| "publishing the status".into())?;
        Ok(())
    }
}

impl Coordinator {
    /// Ends the run: asks every worker to exit (a worker finishes its current job first), waits up to `timeout`
    /// for all worker nodes to be gone, then removes the run's leftovers ([`cleanup_stale`](crate::cleanup_stale)).
    /// `Ok(false)` if some worker was still alive at the timeout (kill it, then call `cleanup_stale`). The caller
    /// still reaps its child processes.
    pub fn shutdown(self, timeout: Duration) -> Result<bool, IpcError> {
        let (run, cfg) = (self.run.clone(), self.cfg.clone());
        drop(self);
        let start = Instant::now();
        loop {
            let mut workers = false;
            run::list_nodes(&cfg, |state| {
                if let NodeState::Alive(view) = &state {
                    workers |= run::worker_slot_of(view.details()).is_some();
                }
            });
            if !workers {
                break;
            }
            if start.elapsed() >= timeout {
                return Ok(false);
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        run::cleanup_stale(&run)?;
        Ok(true)
    }
}

impl Slot {
    /// Learns which node is the slot's worker: the owner of the slot's server (there is at most one).
    fn learn_worker(&mut self) {
        if self.node_id.is_none() && !self.dead {
            self.jobs.dynamic_config().list_servers(|server| {
                self.node_id = Some(server.node_id);
                CallbackProgression::Stop
            });
        }
    }
}

impl Drop for Coordinator {
    fn drop(&mut self) {
        for slot in self.slots.iter().flatten() {
            let _ = slot.poke.notify_with_custom_event_id(services::POKE_STOP);
        }
    }
}
