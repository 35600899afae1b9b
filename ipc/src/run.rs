//! Run identity, the shared iceoryx2 configuration, service and node names, and leftover cleanup.

use std::path::Path;

use iceoryx2::prelude::*;

use crate::error::{Context, IpcError};

/// Identifies one run (one output directory). It becomes the iceoryx2 `global.prefix` (followed by `_`), so every
/// shared-memory file, node and service of the run is private to it: two coordinators on one host never interfere.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct RunId(String);

const MAX_RUN_ID_LEN: usize = 24;

impl RunId {
    /// The run id of an output directory: `df-` and a 64-bit FNV-1a hash of its canonical path (or of its absolute
    /// path when it does not exist yet), the same in every process.
    pub fn for_dir(dir: &Path) -> Result<Self, IpcError> {
        let path = match dir.canonicalize() {
            Ok(p) => p,
            Err(_) => std::path::absolute(dir)
                .map_err(|source| IpcError::Io { what: format!("resolving {}", dir.display()), source })?,
        };
        let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
        for &b in path.as_os_str().as_encoded_bytes() {
            hash ^= u64::from(b);
            hash = hash.wrapping_mul(0x0100_0000_01b3);
        }
        Ok(Self(format!("df-{hash:016x}")))
    }

    /// A run id given by name (tests, tools): 1-24 characters of `[A-Za-z0-9-]`.
    pub fn new(name: &str) -> Result<Self, IpcError> {
        let ok = !name.is_empty()
            && name.len() <= MAX_RUN_ID_LEN
            && name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-');
        if ok { Ok(Self(name.to_owned())) } else { Err(IpcError::InvalidRunId(name.to_owned())) }
    }

    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The iceoryx2 file prefix of the run.
    pub(crate) fn prefix(&self) -> String {
        format!("{}_", self.0)
    }
}

impl core::fmt::Display for RunId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(&self.0)
    }
}

/// The configuration every node of a run uses (built in code: no config file is looked up).
///
/// Automatic dead-node cleanup is off everywhere: only the coordinator removes dead nodes, after it has seen them
/// (a monitor or a replacement worker cleaning first would hide a worker's death from the coordinator).
pub(crate) fn config(run: &RunId) -> Result<Config, IpcError> {
    let mut cfg = Config::default();
    cfg.global.prefix = FileName::new(run.prefix().as_bytes()).ctx(|| format!("prefix of run {run}"))?;
    cfg.global.node.cleanup_dead_nodes_on_creation = false;
    cfg.global.node.cleanup_dead_nodes_on_destruction = false;
    cfg.global.service.cleanup_dead_nodes_on_open = false;
    Ok(cfg)
}

pub(crate) const COORDINATOR_NODE: &str = "dynforge-coordinator";
pub(crate) const STATUS_NODE: &str = "dynforge-status";
const WORKER_NODE_PREFIX: &str = "dynforge-worker-";

pub(crate) fn worker_node_name(k: usize) -> String {
    format!("{WORKER_NODE_PREFIX}{k}")
}

/// The worker slot of a node, from its name.
pub(crate) fn worker_slot_of(details: &Option<iceoryx2::node::NodeDetails>) -> Option<usize> {
    details.as_ref()?.name().as_str().strip_prefix(WORKER_NODE_PREFIX)?.parse().ok()
}

pub(crate) fn is_coordinator(details: &Option<iceoryx2::node::NodeDetails>) -> bool {
    details.as_ref().is_some_and(|d| d.name().as_str() == COORDINATOR_NODE)
}

pub(crate) fn node_name(name: &str) -> Result<NodeName, IpcError> {
    NodeName::new(name).ctx(|| format!("node name {name:?}"))
}

pub(crate) fn service_name(name: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(name).ctx(|| format!("service name {name:?}"))
}

/// Lists the nodes of the run. `false` if the listing failed part-way (e.g. interrupted by a signal) or there is
/// no node directory (nothing ever ran): what was seen may then be incomplete.
pub(crate) fn list_nodes(cfg: &Config, mut f: impl FnMut(NodeState<ipc::Service>)) -> bool {
    Node::<ipc::Service>::list(cfg, |state| {
        f(state);
        CallbackProgression::Continue
    })
    .is_ok()
}

/// Removes the leftovers of a crashed run: the resources of its dead nodes and, when no node of the run is alive
/// any more, every file with the run's prefix in `/dev/shm` and under iceoryx2's root directory. Harmless when
/// nothing is left; a live run keeps everything but its dead nodes.
pub fn cleanup_stale(run: &RunId) -> Result<(), IpcError> {
    let cfg = config(run)?;
    let mut alive = 0usize;
    let mut dead = Vec::new();
    let complete = list_nodes(&cfg, |state| match state {
        NodeState::Dead(view) => dead.push(view),
        // Not known to be dead (Undefined: e.g. a node being created): count as alive.
        NodeState::Alive(_) | NodeState::Inaccessible(_) | NodeState::Undefined(_) => alive += 1,
    });
    for view in dead {
        let _ = view.blocking_remove_stale_resources(std::time::Duration::from_secs(1));
    }
    let root = String::from_utf8_lossy(cfg.global.root_path().as_bytes()).into_owned();
    let node_dir = String::from_utf8_lossy(cfg.global.node_dir().as_bytes()).into_owned();
    if alive == 0 && (complete || !Path::new(&node_dir).exists()) {
        let prefix = run.prefix();
        remove_prefixed(Path::new(SHM), &prefix, 0)?;
        remove_prefixed(Path::new(&root), &prefix, 3)?;
    }
    Ok(())
}

/// Makes every shared-memory file of `run` readable and writable by its owner only, and checks that it is ours.
/// iceoryx2 creates its management segment (`/dev/shm/PREFIX..._node..global_mgmt`) writable by everyone, so any
/// local user could write into the run's bookkeeping: 16 bytes there, and every worker started after fails to
/// create its node. The coordinator calls this right after creating its node, before any worker exists.
pub(crate) fn restrict_to_owner(run: &RunId) -> Result<(), IpcError> {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let prefix = run.prefix();
    let Ok(entries) = std::fs::read_dir(SHM) else { return Ok(()) };
    // SAFETY: geteuid has no preconditions and cannot fail.
    let me = unsafe { libc::geteuid() };
    for entry in entries.flatten() {
        if !entry.file_name().as_encoded_bytes().starts_with(prefix.as_bytes()) {
            continue;
        }
        let path = entry.path();
        let io = |source| IpcError::Io { what: format!("restricting {} to its owner", path.display()), source };
        let meta = match std::fs::symlink_metadata(&path) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(io(e)),
        };
        if meta.uid() != me || !meta.file_type().is_file() {
            return Err(IpcError::Io {
                what: format!("{}: a file of this run that is not ours (owner uid {})", path.display(), meta.uid()),
                source: std::io::Error::from(std::io::ErrorKind::PermissionDenied),
            });
        }
        if meta.mode() & 0o077 != 0 {
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).map_err(io)?;
        }
    }
    Ok(())
}

/// Where POSIX shared memory lives.
const SHM: &str = "/dev/shm";

/// Removes the files named `prefix*` in `dir` and, up to `depth` levels, in its subdirectories.
fn remove_prefixed(dir: &Path, prefix: &str, depth: usize) -> Result<(), IpcError> {
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(()) };
    for entry in entries.flatten() {
        let path = entry.path();
        let Ok(kind) = entry.file_type() else { continue };
        if kind.is_dir() {
            if depth > 0 {
                remove_prefixed(&path, prefix, depth - 1)?;
            }
        } else if entry.file_name().as_encoded_bytes().starts_with(prefix.as_bytes()) {
            match std::fs::remove_file(&path) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(source) => return Err(IpcError::Io { what: format!("removing {}", path.display()), source }),
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_ids() {
        let a = RunId::for_dir(Path::new("/tmp/some/run")).unwrap();
        let b = RunId::for_dir(Path::new("/tmp/some/other")).unwrap();
        assert_ne!(a, b);
        assert_eq!(a, RunId::for_dir(Path::new("/tmp/some/run")).unwrap());
        assert_eq!(a.as_str().len(), 19);
        assert!(RunId::new("t-1").is_ok());
        assert!(RunId::new("a_b").is_err());
        assert!(RunId::new("").is_err());
        assert!(RunId::new(&"x".repeat(25)).is_err());
        config(&a).unwrap();
    }
}
