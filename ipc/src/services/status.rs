//! `dynforge/status`: the coordinator's live figures for monitors (publish-subscribe, history 1).

use iceoryx2::prelude::*;

use super::{StatusService, Svc};
use crate::error::{Context, IpcError};
use crate::run::service_name;
use crate::types::StatusMsg;

/// Status monitors that may watch a run at once.
pub(crate) const MAX_MONITORS: usize = 8;

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
