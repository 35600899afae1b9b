//! The messages that cross the process boundary. All are `#[repr(C)]`, `Copy` and carry an explicit type name, so
//! the coordinator and the worker binaries agree on them even when they are built separately.

use iceoryx2::prelude::ZeroCopySend;

/// Capacity of [`FixedStr`] in bytes.
pub const FIXED_STR_CAPACITY: usize = 128;

/// A short UTF-8 string of at most [`FIXED_STR_CAPACITY`] bytes stored inline (zero-padded), for reason codes and
/// error messages. Longer input is truncated at a character boundary.
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
        let mut end = s.len().min(FIXED_STR_CAPACITY);
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        let mut bytes = [0; FIXED_STR_CAPACITY];
        bytes[..end].copy_from_slice(&s.as_bytes()[..end]);
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

/// A job as the coordinator sends it: simulate trajectory `trajectory` of robot `robot` of dataset seed `seed` with
/// engine `engine`. `job_id` is the coordinator's identifier, echoed in every [`JobReport`].
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("dynforge::JobRequest")]
pub struct JobRequest {
    pub job_id: u64,
    pub seed: u64,
    pub robot: u64,
    pub trajectory: u32,
    pub engine: u32,
}

/// What a worker answers to one [`JobRequest`]: any number of `Progress`, then exactly one final report (`Done`,
/// `Discarded` or `Failed`). The coordinator never delivers anything for a job after its final report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("dynforge::JobReport")]
pub enum JobReport {
    /// Still working; `permille` of the job done.
    Progress { job_id: u64, permille: u32 },
    /// Shard written.
    Done { job_id: u64, samples: u64, content_hash: u64 },
    /// The simulation was discarded (reason code such as "timeout", "collision"); no shard.
    Discarded { job_id: u64, reason: FixedStr },
    /// Worker-side error (I/O etc.). The coordinator also synthesizes one when a live worker drops a job without a
    /// final report.
    Failed { job_id: u64, message: FixedStr },
}

impl JobReport {
    /// The job this report belongs to.
    pub fn job_id(&self) -> u64 {
        match *self {
            JobReport::Progress { job_id, .. }
            | JobReport::Done { job_id, .. }
            | JobReport::Discarded { job_id, .. }
            | JobReport::Failed { job_id, .. } => job_id,
        }
    }

    /// Whether this is the job's last report (everything but `Progress`).
    pub fn is_final(&self) -> bool {
        !matches!(self, JobReport::Progress { .. })
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
    fn fixed_str_round_trips_and_truncates_at_char_boundary() {
        assert_eq!(FixedStr::from("timeout").as_str(), "timeout");
        assert_eq!(FixedStr::from("").as_str(), "");
        let long = "é".repeat(100); // 200 bytes, 2 per char
        let s = FixedStr::from(long.as_str());
        assert_eq!(s.as_str().len(), 128);
        assert_eq!(s.as_str(), "é".repeat(64));
        let odd = format!("a{}", "é".repeat(100)); // boundary falls inside a char at 128
        assert_eq!(FixedStr::from(odd.as_str()).as_str().len(), 127);
    }

    #[test]
    fn report_helpers() {
        let p = JobReport::Progress { job_id: 3, permille: 10 };
        let d = JobReport::Discarded { job_id: 4, reason: "collision".into() };
        assert_eq!((p.job_id(), p.is_final()), (3, false));
        assert_eq!((d.job_id(), d.is_final()), (4, true));
    }
}
