//! `dynforge/worker/{k}/jobs`: one job at a time from the coordinator to worker `k`, answered by reports.

use iceoryx2::prelude::*;

use super::{JobsService, Svc};
use crate::error::{Context, IpcError};
use crate::run::service_name;
use crate::types::{WireReport, WireRequest};

/// Responses a pending request can buffer before the oldest is overwritten (progress reports are cheap to lose;
/// the final report is always the newest).
const RESPONSE_BUFFER: usize = 16;
/// `dynforge/worker/{k}/jobs`: coordinator = client, worker = server. Opened or created by either side (the
/// worker may start before the coordinator attaches its slot). One server: a second worker process in the same
/// slot waits until the first one is gone (see `Worker::new`).
pub(crate) fn jobs(node: &Node<Svc>, k: usize) -> Result<JobsService, IpcError> {
    let name = format!("dynforge/worker/{k}/jobs");
    node.service_builder(&service_name(&name)?)
        .request_response::<WireRequest, WireReport>()
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
