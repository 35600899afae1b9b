//! `dynforge/reports`: workers wake the coordinator after each report.

use iceoryx2::prelude::*;

use super::{EventService, Svc};
use crate::error::{Context, IpcError};
use crate::run::service_name;

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
