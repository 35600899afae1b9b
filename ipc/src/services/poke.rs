//! `dynforge/worker/{k}/poke`: the coordinator wakes worker `k` (a job was sent, or stop).

use iceoryx2::prelude::*;

use super::{EventService, Svc};
use crate::error::{Context, IpcError};
use crate::run::service_name;

/// Poke event ids (coordinator -> worker).
pub(crate) const POKE_JOB: EventId = EventId::new(0);
pub(crate) const POKE_STOP: EventId = EventId::new(1);

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
