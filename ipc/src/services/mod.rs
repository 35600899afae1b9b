//! The services of a run, one module each, and their QoS. Every limit is set explicitly and identically on every
//! side that opens a service (iceoryx2's defaults are small, and a mismatch fails the open).

mod jobs;
mod poke;
mod reports;
mod status;

use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe, request_response};

use crate::types::{StatusMsg, WireReport, WireRequest};

pub(crate) use jobs::jobs;
pub(crate) use poke::{POKE_JOB, POKE_STOP, poke, poke_open};
pub(crate) use reports::{reports_create, reports_open};
pub(crate) use status::{status_create, status_open};

pub(crate) type Svc = ipc::Service;
pub(crate) type JobsService = request_response::PortFactory<Svc, WireRequest, (), WireReport, ()>;
pub(crate) type JobsClient = iceoryx2::port::client::Client<Svc, WireRequest, (), WireReport, ()>;
pub(crate) type JobsServer = iceoryx2::port::server::Server<Svc, WireRequest, (), WireReport, ()>;
pub(crate) type Pending = iceoryx2::pending_response::PendingResponse<Svc, WireRequest, (), WireReport, ()>;
pub(crate) type Active = iceoryx2::active_request::ActiveRequest<Svc, WireRequest, (), WireReport, ()>;
pub(crate) type EventService = event::PortFactory<Svc>;
pub(crate) type StatusService = publish_subscribe::PortFactory<Svc, StatusMsg, ()>;
