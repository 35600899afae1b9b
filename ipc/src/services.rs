//! The services of a run and their QoS. Every limit is set explicitly and identically on every side that opens a
//! service (iceoryx2's defaults are small, and a mismatch fails the open).

use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe, request_response};

use crate::error::{Context, IpcError};
use crate::run::service_name;
use crate::types::{JobReport, JobRequest, StatusMsg};

pub(crate) type Svc = ipc::Service;
pub(crate) type JobsService = request_response::PortFactory<Svc, JobRequest, (), JobReport, ()>;
pub(crate) type JobsClient = iceoryx2::port::client::Client<Svc, JobRequest, (), JobReport, ()>;
pub(crate) type JobsServer = iceoryx2::port::server::Server<Svc, JobRequest, (), JobReport, ()>;
pub(crate) type Pending = iceoryx2::pending_response::PendingResponse<Svc, JobRequest, (), JobReport, ()>;
pub(crate) type Active = iceoryx2::active_request::ActiveRequest<Svc, JobRequest, (), JobReport, ()>;
pub(crate) type EventService = event::PortFactory<Svc>;
pub(crate) type StatusService = publish_subscribe::PortFactory<Svc, StatusMsg, ()>;

/// Poke event ids (coordinator -> worker).
pub(crate) const POKE_JOB: EventId = EventId::new(0);
pub(crate) const POKE_STOP: EventId = EventId::new(1);

/// Responses a pending request can buffer before the oldest is overwritten (progress reports are cheap to lose;
/// the final report is always the newest).
const RESPONSE_BUFFER: usize = 16;
/// Status monitors that may watch a run at once.
pub(crate) const MAX_MONITORS: usize = 8;

/// `dynforge/worker/{k}/jobs`: coordinator = client, worker = server. Opened or created by either side (the
/// worker may start before the coordinator attaches its slot). One server: a second worker process in the same
/// slot waits until the first one is gone (see `Worker::new`).
pub(crate) fn jobs(node: &Node<Svc>, k: usize) -> Result<JobsService, IpcError> {
    let name = format!("dynforge/worker/{k}/jobs");
    node.service_builder(&service_name(&name)?)
        .request_response::<JobRequest, JobReport>()
        .max_servers(1)
        .max_clients(2)
        .max_nodes(4)
        .max_active_requests_per_client(2)
        .max_loaned_requests(2)
        .max_response_buffer_size(RESPONSE_BUFFER)
        .max_borrowed_responses_per_pending_response(2)
        .enable_safe_overflow_for_requests(true)
        .enable_safe_overflow_for_responses(true)
        .enable_fire_and_forget_requests(false)
        .open_or_create()
        .ctx(|| format!("opening service {name}"))
}

/// `dynforge/worker/{k}/poke`: the coordinator wakes worker k (job sent, or stop).
pub(crate) fn poke(node: &Node<Svc>, k: usize) -> Result<EventService, IpcError> {
    poke_builder(node, k)?.open_or_create().ctx(|| format!("opening service dynforge/worker/{k}/poke"))
}

/// Opens `dynforge/worker/{k}/poke` if it exists.
pub(crate) fn poke_open(node: &Node<Svc>, k: usize) -> Option<EventService> {
    poke_builder(node, k).ok()?.open().ok()
}

fn poke_builder(node: &Node<Svc>, k: usize) -> Result<iceoryx2::service::builder::event::Builder<Svc>, IpcError> {
    let name = format!("dynforge/worker/{k}/poke");
    Ok(node
        .service_builder(&service_name(&name)?)
        .event()
        .max_listeners(2)
        .max_notifiers(2)
        .max_nodes(4)
        .event_id_max_value(3)
        .disable_notifier_created_event()
        .disable_notifier_dropped_event()
        .disable_notifier_dead_event()
        .disable_deadline())
}

const REPORTS: &str = "dynforge/reports";

fn reports_builder(
    node: &Node<Svc>,
    notifiers: usize,
) -> Result<iceoryx2::service::builder::event::Builder<Svc>, IpcError> {
    Ok(node
        .service_builder(&service_name(REPORTS)?)
        .event()
        .max_listeners(2)
        .max_notifiers(notifiers)
        .max_nodes(notifiers + 4)
        .event_id_max_value(1)
        .disable_notifier_created_event()
        .disable_notifier_dropped_event()
        .disable_notifier_dead_event()
        .disable_deadline())
}

/// `dynforge/reports`: every worker notifies the coordinator after each response. The coordinator sizes it for
/// `max_workers` plus some spare (replacements that start before a dead predecessor is cleaned up).
pub(crate) fn reports_create(node: &Node<Svc>, max_workers: usize) -> Result<EventService, IpcError> {
    reports_builder(node, max_workers + 4)?.open_or_create().ctx(|| format!("opening service {REPORTS}"))
}

/// Opens `dynforge/reports` as worker `k` (requires room for at least `k + 1` notifiers). Fails when no
/// coordinator created it.
pub(crate) fn reports_open(node: &Node<Svc>, k: usize) -> Result<EventService, IpcError> {
    reports_builder(node, k + 1)?.open().map_err(|e| match e {
        iceoryx2::service::builder::event::EventOpenError::DoesNotExist => IpcError::CoordinatorNotRunning,
        e => IpcError::Iceoryx { what: format!("opening service {REPORTS}"), source: Box::new(e) },
    })
}

const STATUS: &str = "dynforge/status";

fn status_builder(
    node: &Node<Svc>,
) -> Result<iceoryx2::service::builder::publish_subscribe::Builder<StatusMsg, (), Svc>, IpcError> {
    Ok(node
        .service_builder(&service_name(STATUS)?)
        .publish_subscribe::<StatusMsg>()
        .max_publishers(2)
        .max_subscribers(MAX_MONITORS)
        .max_nodes(MAX_MONITORS + 4)
        .history_size(1)
        .subscriber_max_buffer_size(1)
        .subscriber_max_borrowed_samples(1)
        .enable_safe_overflow(true))
}

/// `dynforge/status` (publish-subscribe, history 1), created by the coordinator.
pub(crate) fn status_create(node: &Node<Svc>) -> Result<StatusService, IpcError> {
    status_builder(node)?.open_or_create().ctx(|| format!("opening service {STATUS}"))
}

/// Opens `dynforge/status` as a monitor; `None` when it does not exist (no coordinator).
pub(crate) fn status_open(node: &Node<Svc>) -> Result<Option<StatusService>, IpcError> {
    match status_builder(node)?.open() {
        Ok(s) => Ok(Some(s)),
        Err(iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError::DoesNotExist) => Ok(None),
        Err(e) => Err(IpcError::Iceoryx { what: format!("opening service {STATUS}"), source: Box::new(e) }),
    }
}
