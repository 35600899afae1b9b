//! Read-only view of a running coordinator's status, for `dynforge status DIR` in another terminal.

use std::time::{Duration, Instant};

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use crate::error::{Context, IpcError};
use crate::run::{self, RunId};
use crate::services::{self, StatusService, Svc};
use crate::types::StatusMsg;

/// Subscribes to a running coordinator's status. It never disturbs the run: it looks for a live coordinator
/// without creating anything, and its node neither cleans up dead nodes nor opens the services of a dead
/// coordinator (those would be removed). When no coordinator runs, read the run's ledger instead.
pub struct StatusReader {
    cfg: Config,
    subscriber: Subscriber<Svc, StatusMsg, ()>,
    _status: StatusService,
    last: Option<StatusMsg>,
    _node: Node<Svc>,
}

impl StatusReader {
    /// `Ok(None)` quickly (nothing created, nothing removed) when no coordinator of `run` is alive.
    pub fn open(run: &RunId) -> Result<Option<Self>, IpcError> {
        let cfg = run::config(run)?;
        if !coordinator_alive(&cfg) {
            return Ok(None);
        }
        let node = NodeBuilder::new()
            .name(&run::node_name(run::STATUS_NODE)?)
            .config(&cfg)
            .create::<Svc>()
            .ctx(|| format!("creating the status node of run {run}"))?;
        let Some(status) = services::status_open(&node)? else { return Ok(None) };
        let subscriber = status.subscriber_builder().create().ctx(|| "creating the status subscriber".into())?;
        Ok(Some(Self { cfg, subscriber, _status: status, last: None, _node: node }))
    }

    /// The latest status received so far (`None` until the first one arrives: the coordinator hands a new monitor
    /// its last status at its next `wait` or `publish_status`).
    pub fn latest(&mut self) -> Option<StatusMsg> {
        while let Ok(Some(sample)) = self.subscriber.receive() {
            self.last = Some(*sample);
        }
        self.last
    }

    /// Like [`StatusReader::latest`], but polls up to `timeout` for a first status.
    pub fn latest_timeout(&mut self, timeout: Duration) -> Option<StatusMsg> {
        let start = Instant::now();
        loop {
            if let Some(s) = self.latest() {
                return Some(s);
            }
            if start.elapsed() >= timeout {
                return None;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Whether the coordinator is still alive.
    pub fn coordinator_alive(&self) -> bool {
        coordinator_alive(&self.cfg)
    }
}

fn coordinator_alive(cfg: &Config) -> bool {
    let mut alive = false;
    run::list_nodes(cfg, |state| {
        if let NodeState::Alive(view) = &state {
            alive |= run::is_coordinator(iceoryx2::node::NodeView::details(view));
        }
    });
    alive
}
