//! The ledger: an append-only, fsync'd text file with one line per finished job. Together with atomic,
//! deterministically named shards it makes a dataset exactly-once although jobs run at-least-once: a job is done when
//! its line is durable; a job that ran but whose line was lost (crash) runs again and rewrites the identical shard.
//!
//! Line format (tab-separated): `job_id robot trajectory status detail shard_hash check`, where `status` is
//! `done` (detail = samples), `discarded` (detail = reason code) or `failed` (detail = message), and `check` is the
//! FNV-1a hash of everything before it, so a torn or corrupted line is detected. A torn last line (a crash in the
//! middle of a write) is dropped and cut off when the ledger is reopened for writing; a corrupt line anywhere else
//! is an error naming the file and line, and nothing is changed.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::content_hash;
use crate::job::Job;

/// How a job ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Status {
    Done { samples: u64, shard_hash: u64 },
    Discarded { reason: String },
    Failed { message: String },
}

/// One ledger line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    pub job_id: u64,
    pub robot: u64,
    pub trajectory: u32,
    pub status: Status,
}

#[derive(Debug, thiserror::Error)]
pub enum LedgerError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(
        "{path}:{line}: corrupt ledger line ({problem}); refusing to continue so nothing is lost: inspect or restore the file"
    )]
    Corrupt { path: PathBuf, line: usize, problem: LineProblem },
}

/// What is wrong with a ledger line.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LineProblem {
    #[error("no checksum field")]
    NoChecksum,
    #[error("checksum '{0}' is not hex")]
    ChecksumNotHex(String),
    #[error("checksum mismatch")]
    ChecksumMismatch,
    #[error("{0} fields instead of 7")]
    Fields(usize),
    #[error("{0} '{1}' is not a number")]
    NotANumber(&'static str, String),
    #[error("hash '{0}' is not hex")]
    HashNotHex(String),
    #[error("unknown status '{0}'")]
    Status(String),
}

fn clean(text: &str) -> String {
    text.chars().map(|c| if c == '\t' || c == '\n' || c == '\r' { ' ' } else { c }).collect()
}

impl Entry {
    fn to_line(&self) -> String {
        let (status, detail, hash) = match &self.status {
            Status::Done { samples, shard_hash } => ("done", samples.to_string(), *shard_hash),
            Status::Discarded { reason } => ("discarded", clean(reason), 0),
            Status::Failed { message } => ("failed", clean(message), 0),
        };
        let body = format!("{}\t{}\t{}\t{status}\t{detail}\t{hash:016x}", self.job_id, self.robot, self.trajectory);
        format!("{body}\t{:016x}\n", content_hash(body.as_bytes()))
    }

    fn parse(line: &str) -> Result<Entry, LineProblem> {
        let (body, check) = line.rsplit_once('\t').ok_or(LineProblem::NoChecksum)?;
        let check = u64::from_str_radix(check, 16).map_err(|_| LineProblem::ChecksumNotHex(check.to_string()))?;
        if check != content_hash(body.as_bytes()) {
            return Err(LineProblem::ChecksumMismatch);
        }
        let f: Vec<&str> = body.split('\t').collect();
        if f.len() != 6 {
            return Err(LineProblem::Fields(f.len() + 1));
        }
        let num = |s: &str, what| s.parse::<u64>().map_err(|_| LineProblem::NotANumber(what, s.to_string()));
        let status = match f[3] {
            "done" => Status::Done {
                samples: num(f[4], "samples")?,
                shard_hash: u64::from_str_radix(f[5], 16).map_err(|_| LineProblem::HashNotHex(f[5].to_string()))?,
            },
            "discarded" => Status::Discarded { reason: f[4].to_string() },
            "failed" => Status::Failed { message: f[4].to_string() },
            other => return Err(LineProblem::Status(other.to_string())),
        };
        Ok(Entry {
            job_id: num(f[0], "job id")?,
            robot: num(f[1], "robot")?,
            trajectory: num(f[2], "trajectory")? as u32,
            status,
        })
    }
}

/// Parses ledger text: the entries, and the byte length of the valid prefix (shorter than the text when the last
/// line is torn).
fn parse_all(text: &str, path: &Path) -> Result<(Vec<Entry>, usize), LedgerError> {
    let mut entries = Vec::new();
    let mut valid = 0;
    let mut offset = 0;
    let lines: Vec<&str> = text.split_inclusive('\n').collect();
    for (i, raw) in lines.iter().enumerate() {
        offset += raw.len();
        let complete = raw.ends_with('\n');
        match Entry::parse(raw.trim_end_matches('\n')) {
            Ok(e) if complete => {
                entries.push(e);
                valid = offset;
            }
            // The last line without its newline is a write the crash interrupted: drop it.
            _ if !complete && i + 1 == lines.len() => break,
            Ok(_) => unreachable!("only the last line can lack a newline"),
            Err(problem) => return Err(LedgerError::Corrupt { path: path.to_path_buf(), line: i + 1, problem }),
        }
    }
    Ok((entries, valid))
}

impl Entry {
    /// The job this line records, in the run of dataset seed `seed`.
    pub fn job(&self, seed: u64) -> Job {
        Job { seed, robot: self.robot, trajectory: self.trajectory }
    }

    /// The file name of the job's shard (`engine` from the run's manifest).
    pub fn shard_name(&self, seed: u64, engine: &str) -> String {
        self.job(seed).shard_name(engine)
    }
}

/// Each job's record that counts: its last one (a failed attempt followed by the rerun that succeeded is the rerun).
pub fn latest(entries: &[Entry]) -> BTreeMap<u64, &Entry> {
    entries.iter().map(|e| (e.job_id, e)).collect()
}

/// The shards the ledger `entries` of a run with dataset seed `seed` and engine `engine` records done (each job's
/// latest record), by file name, with the content hash the worker that wrote it recorded.
pub fn done_shards(entries: &[Entry], seed: u64, engine: &str) -> BTreeMap<String, u64> {
    latest(entries)
        .values()
        .filter_map(|e| match e.status {
            Status::Done { shard_hash, .. } => Some((e.shard_name(seed, engine), shard_hash)),
            _ => None,
        })
        .collect()
}

/// Reads a ledger without changing it (for `status` and `verify`). A missing file is an empty ledger.
pub fn read(path: &Path) -> Result<Vec<Entry>, LedgerError> {
    match std::fs::read(path) {
        Ok(bytes) => Ok(parse_all(&String::from_utf8_lossy(&bytes), path)?.0),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
        Err(source) => Err(LedgerError::Io { path: path.to_path_buf(), source }),
    }
}

/// The ledger open for appending.
pub struct Ledger {
    file: File,
    path: PathBuf,
}

impl Ledger {
    /// Opens (or creates) the ledger, returning its entries; cuts off a torn last line.
    pub fn open(path: &Path) -> Result<(Ledger, Vec<Entry>), LedgerError> {
        let io = |source| LedgerError::Io { path: path.to_path_buf(), source };
        let mut file = crate::run_dir::open_for_writing(OpenOptions::new().read(true).append(true).create(true), path)
            .map_err(io)?;
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut file, &mut bytes).map_err(io)?;
        let (entries, valid) = parse_all(&String::from_utf8_lossy(&bytes), path)?;
        if valid < bytes.len() {
            file.set_len(valid as u64).map_err(io)?;
            file.sync_all().map_err(io)?;
        }
        Ok((Ledger { file, path: path.to_path_buf() }, entries))
    }

    /// Appends an entry durably (written and fsync'd before returning).
    pub fn append(&mut self, e: &Entry) -> Result<(), LedgerError> {
        let io = |source| LedgerError::Io { path: self.path.clone(), source };
        self.file.write_all(e.to_line().as_bytes()).map_err(io)?;
        self.file.sync_data().map_err(io)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entries() -> Vec<Entry> {
        vec![
            Entry {
                job_id: 0,
                robot: 0,
                trajectory: 0,
                status: Status::Done { samples: 6123, shard_hash: 0xdead_beef },
            },
            Entry { job_id: 1, robot: 0, trajectory: 1, status: Status::Discarded { reason: "timeout".into() } },
            Entry {
                job_id: 17,
                robot: 1,
                trajectory: 1,
                status: Status::Failed { message: "disk\tfull\nagain".into() },
            },
        ]
    }

    /// A ledger holding `entries()`, in a temporary directory kept alive by the first value.
    fn written_ledger() -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ledger.tsv");
        let (mut l, existing) = Ledger::open(&path).unwrap();
        assert!(existing.is_empty());
        for e in entries() {
            l.append(&e).unwrap();
        }
        (dir, path)
    }

    #[test]
    fn entries_round_trip_across_reopen() {
        let (_dir, path) = written_ledger();
        let (_, back) = Ledger::open(&path).unwrap();
        let mut want = entries();
        want[2].status = Status::Failed { message: "disk full again".into() };
        assert_eq!(back, want);
        assert_eq!(read(&path).unwrap(), want);
    }

    #[test]
    fn a_torn_last_line_is_dropped_and_cut_off() {
        let (_dir, path) = written_ledger();
        let full = std::fs::read(&path).unwrap();
        // Simulate a crash half-way through a fourth line.
        let mut torn = full.clone();
        torn.extend_from_slice(b"18\t1\t2\tdone\t61");
        std::fs::write(&path, &torn).unwrap();
        assert_eq!(read(&path).unwrap().len(), 3, "readers ignore the torn tail");
        let (mut l, back) = Ledger::open(&path).unwrap();
        assert_eq!(back.len(), 3);
        assert_eq!(std::fs::read(&path).unwrap(), full, "the torn bytes are cut off");
        l.append(&entries()[0]).unwrap();
        assert_eq!(read(&path).unwrap().len(), 4);
    }

    #[test]
    fn a_corrupt_line_is_an_error_naming_file_and_line_and_changes_nothing() {
        let (_dir, path) = written_ledger();
        let mut bytes = std::fs::read(&path).unwrap();
        let second_line = bytes.iter().position(|&b| b == b'\n').unwrap() + 1;
        bytes[second_line] = b'9'; // job id 1 -> 9: the checksum no longer matches
        std::fs::write(&path, &bytes).unwrap();
        let e = Ledger::open(&path).err().expect("corrupt");
        let msg = e.to_string();
        assert!(msg.contains("ledger.tsv:2:") && msg.contains("checksum mismatch"), "{msg}");
        assert_eq!(std::fs::read(&path).unwrap(), bytes, "nothing was changed");
    }
}
