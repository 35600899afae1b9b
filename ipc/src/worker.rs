//! The worker's side: the server of its slot, a listener for the coordinator's pokes, a notifier for its answers.

use std::time::{Duration, Instant};

use iceoryx2::node::NodeView;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::server::ServerCreateError;
use iceoryx2::waitset::WaitSetRunResult;
use iceoryx2_bb_posix::signal::SignalHandler;

use crate::error::{Context, IpcError};
use crate::run::{self, RunId};
use crate::services::{self, Active, EventService, JobsServer, JobsService, Svc};
use crate::types::{WireReport, WireRequest};
use dynforge_proto::job::{JobReport, JobRequest};

/// How often a waiting worker checks that its coordinator is still alive.
pub const COORDINATOR_CHECK_INTERVAL: Duration = Duration::from_millis(500);
/// How long `Worker::new` waits for a previous worker of the same slot to go away.
pub const SLOT_WAIT: Duration = Duration::from_secs(10);

/// A worker process's end of the transport (not `Send`).
pub struct Worker {
    slot: usize,
    active: Option<Active>,
    active_job: u64,
    server: JobsServer,
    _jobs: JobsService,
    listener: Listener<Svc>,
    _poke: EventService,
    notifier: Notifier<Svc>,
    reports: EventService,
    coordinator: iceoryx2::identifiers::UniqueNodeId,
    waitset: WaitSet<Svc>,
    stop: bool,
    last_check: Instant,
    _node: Node<Svc>,
}

impl Worker {
    /// Joins `run` as the worker of slot `k`. Fails with `CoordinatorNotRunning` if the run has no live
    /// coordinator, and with `SlotTaken` if another worker process keeps the slot for longer than [`SLOT_WAIT`].
    pub fn new(run: &RunId, k: usize) -> Result<Self, IpcError> {
        let cfg = run::config(run)?;
        let mut coordinator_alive = false;
        run::list_nodes(&cfg, |state| {
            if let NodeState::Alive(view) = &state {
                coordinator_alive |= run::is_coordinator(view.details());
            }
        });
        if !coordinator_alive {
            return Err(IpcError::CoordinatorNotRunning); // before creating anything
        }
        // From here on SIGINT/SIGTERM are recorded (`next_job` then returns `None`) instead of killing the process:
        // kill a hung worker with SIGKILL.
        SignalHandler::termination_requested();
        let node = NodeBuilder::new()
            .name(&run::node_name(&run::worker_node_name(k))?)
            .config(&cfg)
            .create::<Svc>()
            .ctx(|| format!("creating the node of worker {k} of run {run}"))?;
        let reports = services::reports_open(&node, k)?;
        let coordinator = find_coordinator(&reports).ok_or(IpcError::CoordinatorNotRunning)?;

        // The listener before the server: once the coordinator sees the server, pokes reach us.
        let poke = services::poke(&node, k)?;
        let listener = poke.listener_builder().create().ctx(|| format!("creating the listener of slot {k}"))?;
        let jobs = services::jobs(&node, k)?;
        let start = Instant::now();
        let server = loop {
            match jobs.server_builder().create() {
                Ok(server) => break server,
                Err(ServerCreateError::ExceedsMaxSupportedServers) if start.elapsed() < SLOT_WAIT => {
                    std::thread::sleep(Duration::from_millis(10));
                }
                Err(ServerCreateError::ExceedsMaxSupportedServers) => {
                    return Err(IpcError::SlotTaken { slot: k, waited_ms: start.elapsed().as_millis() as u64 });
                }
                Err(e) => {
                    return Err(IpcError::Iceoryx {
                        what: format!("creating the server of slot {k}"),
                        source: e.into(),
                    });
                }
            }
        };
        let notifier = reports.notifier_builder().create().ctx(|| "creating the reports notifier".into())?;
        let waitset = WaitSetBuilder::new().create::<Svc>().ctx(|| "creating the worker's WaitSet".into())?;
        Ok(Self {
            slot: k,
            active: None,
            active_job: 0,
            server,
            _jobs: jobs,
            listener,
            _poke: poke,
            notifier,
            reports,
            coordinator,
            waitset,
            stop: false,
            last_check: Instant::now(),
            _node: node,
        })
    }

    pub fn slot(&self) -> usize {
        self.slot
    }

    /// Blocks until a job arrives (`Ok(Some)`), or until the worker should exit (`Ok(None)`): the coordinator asked
    /// it to stop, is gone (checked every [`COORDINATOR_CHECK_INTERVAL`]), or SIGINT/SIGTERM arrived. A job still
    /// active without a final report is given up (the coordinator reports it as `Failed`).
    pub fn next_job(&mut self) -> Result<Option<JobRequest>, IpcError> {
        self.active = None;
        loop {
            // Consume the pokes first (or the WaitSet spins), then look for a request: a poke that arrives after
            // the look wakes the wait below.
            if self.stop_requested() {
                return Ok(None);
            }
            if let Some(request) = self.server.receive().ctx(|| format!("receiving a job in slot {}", self.slot))? {
                let job = JobRequest::from(request.payload() as &WireRequest);
                self.active = Some(request);
                self.active_job = job.job_id;
                return Ok(Some(job));
            }
            let result = {
                let _guard =
                    self.waitset.attach_notification(&self.listener).ctx(|| "attaching to the WaitSet".into())?;
                self.waitset
                    .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, COORDINATOR_CHECK_INTERVAL)
                    .ctx(|| "waiting for a job".into())?
            };
            match result {
                WaitSetRunResult::TerminationRequest => self.stop = true,
                WaitSetRunResult::Interrupt if SignalHandler::termination_requested() => self.stop = true,
                _ => {}
            }
        }
    }

    /// Whether the worker should exit: the coordinator asked it to stop or is gone (checked at most every
    /// [`COORDINATOR_CHECK_INTERVAL`]), or SIGINT/SIGTERM arrived. Cheap: a long job may poll it to stop early.
    pub fn stop_requested(&mut self) -> bool {
        let mut stop = false;
        let _ = self.listener.try_wait(|event| stop |= event.id == services::POKE_STOP);
        if stop || SignalHandler::termination_requested() {
            self.stop = true;
        }
        if !self.stop && self.last_check.elapsed() >= COORDINATOR_CHECK_INTERVAL {
            self.last_check = Instant::now();
            self.stop = !self.coordinator_alive();
        }
        self.stop
    }

    /// Sends `r` as a response to the current job and notifies the coordinator. A final report (`Done`,
    /// `Discarded`, `Failed`) ends the job. `JobAbandoned` if the coordinator no longer waits for it.
    pub fn report(&mut self, r: &JobReport) -> Result<(), IpcError> {
        let active = self.active.as_ref().ok_or(IpcError::NoActiveJob)?;
        if r.job_id() != self.active_job {
            return Err(IpcError::WrongJob { active: self.active_job, got: r.job_id() });
        }
        if !active.is_connected() {
            self.active = None;
            return Err(IpcError::JobAbandoned(r.job_id()));
        }
        active.send_copy(WireReport::from(r)).ctx(|| format!("sending a report for job {}", r.job_id()))?;
        if r.is_final() {
            self.active = None;
        }
        self.notifier.notify().ctx(|| "notifying the coordinator".into())?;
        Ok(())
    }

    /// Whether the coordinator this worker joined is still alive.
    pub fn coordinator_alive(&self) -> bool {
        let mut alive = false;
        let _ = self.reports.nodes(|state| {
            if let NodeState::Alive(view) = &state
                && *view.id() == self.coordinator
            {
                alive = true;
                return CallbackProgression::Stop;
            }
            CallbackProgression::Continue
        });
        alive
    }
}

fn find_coordinator(reports: &EventService) -> Option<iceoryx2::identifiers::UniqueNodeId> {
    let mut found = None;
    let _ = reports.nodes(|state| {
        if let NodeState::Alive(view) = &state
            && run::is_coordinator(view.details())
        {
            found = Some(*view.id());
            return CallbackProgression::Stop;
        }
        CallbackProgression::Continue
    });
    found
}
