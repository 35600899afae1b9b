//! The messages as they cross the process boundary: fixed-size wire forms of the job contract
//! (`dynforge_proto::job`) and the status record. All are `#[repr(C)]`, `Copy` and carry an explicit type name, so
//! the coordinator and the worker binaries agree on them even when they are built separately.

use dynforge_proto::job::{Job, JobReport, JobRequest};

use iceoryx2::prelude::ZeroCopySend;

/// Capacity of [`FixedStr`] in bytes.
pub const FIXED_STR_CAPACITY: usize = dynforge_proto::job::MESSAGE_CAPACITY;

/// A short UTF-8 string of at most [`FIXED_STR_CAPACITY`] bytes stored inline (zero-padded), for reason codes and
/// error messages. Longer input keeps its first third and its end, joined by ` … ` at character boundaries: an
/// error names what failed first and its cause (`No space left on device (os error 28)`) last.
#[derive(Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("dynforge::FixedStr")]
pub struct FixedStr([u8; FIXED_STR_CAPACITY]);

impl FixedStr {
    /// The stored text (up to the first NUL byte).
    pub fn as_str(&self) -> &str {
        let len = self.0.iter().position(|&b| b == 0).unwrap_or(FIXED_STR_CAPACITY);
        match core::str::from_utf8(&self.0[..len]) {
            Ok(s) => s,
            // Only reachable if a peer wrote raw bytes: keep the valid prefix.
            Err(e) => core::str::from_utf8(&self.0[..e.valid_up_to()]).unwrap_or_default(),
        }
    }
}

impl Default for FixedStr {
    fn default() -> Self {
        Self([0; FIXED_STR_CAPACITY])
    }
}

impl From<&str> for FixedStr {
    fn from(s: &str) -> Self {
        const GAP: &str = " … ";
        let mut bytes = [0; FIXED_STR_CAPACITY];
        if s.len() <= FIXED_STR_CAPACITY {
            bytes[..s.len()].copy_from_slice(s.as_bytes());
            return Self(bytes);
        }
        let budget = FIXED_STR_CAPACITY - GAP.len();
        let mut head = budget / 3;
        while !s.is_char_boundary(head) {
            head -= 1;
        }
        let mut tail = s.len() - (budget - head);
        while !s.is_char_boundary(tail) {
            tail += 1;
        }
        let text = [&s[..head], GAP, &s[tail..]].concat();
        bytes[..text.len()].copy_from_slice(text.as_bytes());
        Self(bytes)
    }
}

impl core::fmt::Debug for FixedStr {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        core::fmt::Debug::fmt(self.as_str(), f)
    }
}

impl core::fmt::Display for FixedStr {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// [`JobRequest`] on the wire.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("dynforge::JobRequest")]
pub(crate) struct WireRequest {
    job_id: u64,
    seed: u64,
    robot: u64,
    trajectory: u32,
}

impl From<&JobRequest> for WireRequest {
    fn from(j: &JobRequest) -> Self {
        let Job { seed, robot, trajectory } = j.job;
        WireRequest { job_id: j.job_id, seed, robot, trajectory }
    }
}

impl From<&WireRequest> for JobRequest {
    fn from(j: &WireRequest) -> Self {
        JobRequest { job_id: j.job_id, job: Job { seed: j.seed, robot: j.robot, trajectory: j.trajectory } }
    }
}

/// [`JobReport`] on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("dynforge::JobReport")]
pub(crate) enum WireReport {
    Progress { job_id: u64, permille: u32 },
    Done { job_id: u64, samples: u64, content_hash: u64 },
    Discarded { job_id: u64, reason: FixedStr },
    Failed { job_id: u64, message: FixedStr },
}

impl WireReport {
    pub(crate) fn is_final(&self) -> bool {
        !matches!(self, WireReport::Progress { .. })
    }
}

impl From<&JobReport> for WireReport {
    fn from(r: &JobReport) -> Self {
        match r {
            &JobReport::Progress { job_id, permille } => WireReport::Progress { job_id, permille },
            &JobReport::Done { job_id, samples, content_hash } => WireReport::Done { job_id, samples, content_hash },
            JobReport::Discarded { job_id, reason } => {
                WireReport::Discarded { job_id: *job_id, reason: reason.as_str().into() }
            }
            JobReport::Failed { job_id, message } => {
                WireReport::Failed { job_id: *job_id, message: message.as_str().into() }
            }
        }
    }
}

impl From<&WireReport> for JobReport {
    fn from(r: &WireReport) -> Self {
        match *r {
            WireReport::Progress { job_id, permille } => JobReport::Progress { job_id, permille },
            WireReport::Done { job_id, samples, content_hash } => JobReport::Done { job_id, samples, content_hash },
            WireReport::Discarded { job_id, reason } => JobReport::Discarded { job_id, reason: reason.as_str().into() },
            WireReport::Failed { job_id, message } => JobReport::Failed { job_id, message: message.as_str().into() },
        }
    }
}

/// Live status of a run, published by the coordinator for monitors (`dynforge status DIR`).
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("dynforge::StatusMsg")]
pub struct StatusMsg {
    pub done: u64,
    pub discarded: u64,
    pub failed: u64,
    pub in_flight: u32,
    pub workers_alive: u32,
    pub total: u64,
    pub rate_per_s: f64,
    pub updated_unix_ms: u64,
    /// Seconds until the remaining jobs are done at the current rate (0 if unknown).
    pub eta_s: f64,
    /// Process id of the publishing coordinator.
    pub coordinator_pid: u32,
    /// Workers respawned since the run started.
    pub respawns: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_str_round_trips_and_keeps_both_ends_of_long_text_at_char_boundaries() {
        assert_eq!(FixedStr::from("timeout").as_str(), "timeout");
        assert_eq!(FixedStr::from("").as_str(), "");
        let whole = "é".repeat(FIXED_STR_CAPACITY / 2);
        assert_eq!(FixedStr::from(whole.as_str()).as_str(), whole);
        // A full disk deep in a long path: the file and the OS error both survive.
        let path = format!("/tmp/{}/shards/r000001-t03-native.mcap.tmp", "d".repeat(700));
        let long = format!("writing {path}: finishing the compression stream: No space left on device (os error 28)");
        let cut = FixedStr::from(long.as_str());
        let text = cut.as_str();
        assert!(text.len() <= FIXED_STR_CAPACITY && text.len() > FIXED_STR_CAPACITY - 4, "{}", text.len());
        assert!(text.starts_with("writing /tmp/ddd") && text.contains(" … "), "{text}");
        assert!(
            text.ends_with(
                "r000001-t03-native.mcap.tmp: finishing the compression stream: No space left on device (os error 28)"
            ),
            "{text}"
        );
        // Two-byte characters on every side of both cuts: still valid UTF-8, nothing but whole characters.
        for pad in 0..3 {
            let odd = format!("{}{}", "a".repeat(pad), "é".repeat(FIXED_STR_CAPACITY));
            let t = FixedStr::from(odd.as_str()).as_str().to_string();
            assert!(t.len() <= FIXED_STR_CAPACITY && t.ends_with('é') && t.contains(" … "), "{t}");
            assert_eq!(t.chars().filter(|&c| c != 'é' && c != 'a').collect::<String>(), " … ");
        }
    }

    #[test]
    fn reports_cross_the_wire_whole_or_cut_at_the_capacity() {
        let long = format!("{}{}", "x".repeat(300), "y".repeat(300));
        for r in [
            JobReport::Progress { job_id: 3, permille: 10 },
            JobReport::Done { job_id: 4, samples: 6500, content_hash: u64::MAX },
            JobReport::Discarded { job_id: 5, reason: "collision".into() },
            JobReport::Failed { job_id: 6, message: long.clone() },
        ] {
            let back = JobReport::from(&WireReport::from(&r));
            match (&r, &back) {
                (JobReport::Failed { .. }, JobReport::Failed { message, .. }) => {
                    assert!(message.starts_with("xxx") && message.ends_with("yyy") && message.contains(" … "))
                }
                _ => assert_eq!(back, r),
            }
        }
        let j = JobRequest { job_id: 1, job: Job { seed: 2, robot: 3, trajectory: 4 } };
        assert_eq!(JobRequest::from(&WireRequest::from(&j)), j);
    }
}
