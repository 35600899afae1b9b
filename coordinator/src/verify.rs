//! `verify`: checks a run directory's shards against its ledger and manifest.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use dynforge_proto::LABELS;
use dynforge_proto::job::Job;
use dynforge_proto::run_dir::{LEDGER, SHARDS, is_temporary};
use dynforge_proto::shard::{JobRecord, META_JOB, META_LABELS};

use crate::plan::{self, Plan};
use dynforge_proto::ledger::{self, Entry, Status};
use dynforge_proto::lock::Holder;
use dynforge_proto::manifest::Manifest;

/// What `verify` found.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Report {
    /// Jobs of the manifest's partition.
    pub planned: usize,
    pub done: usize,
    pub discarded: usize,
    pub failed: usize,
    /// Planned jobs with no ledger entry yet.
    pub pending: usize,
    /// Shards recorded as done but absent.
    pub missing: Vec<String>,
    /// Shards recorded as done and absent because they were pruned (their data are in the caches).
    pub pruned: usize,
    /// Shard files no ledger entry accounts for.
    pub extra: Vec<String>,
    /// Shards that exist but fail a check, with the reason.
    pub corrupt: Vec<(String, String)>,
    /// Discards by reason code.
    pub reasons: BTreeMap<String, usize>,
    /// Who holds the directory's lock, when a generation (or a prune, ...) is live there (a generation's files in
    /// flight are not counted).
    pub live: Option<Holder>,
}

impl Report {
    /// Whether a generation holds the directory: its workers may have shards in place not yet recorded.
    pub fn generating(&self) -> bool {
        self.live.as_ref().is_some_and(|h| h.what == crate::run::GENERATING)
    }

    pub fn is_ok(&self) -> bool {
        self.missing.is_empty() && self.extra.is_empty() && self.corrupt.is_empty()
    }

    /// What an intact run's report says of its shards.
    pub fn intact(&self) -> String {
        let pruned = if self.pruned > 0 { " (or pruned, its data cached)" } else { "" };
        format!("ok: every recorded shard is present{pruned} and intact")
    }

    /// The verdict `dynforge verify` exits with: damaged shards first, then failed jobs.
    pub fn verdict(&self) -> Result<(), Unverified> {
        if !self.is_ok() {
            let (missing, extra, corrupt) = (self.missing.len(), self.extra.len(), self.corrupt.len());
            return Err(Unverified::Damaged { missing, extra, corrupt });
        }
        match self.failed {
            0 => Ok(()),
            n => Err(Unverified::Failed(n)),
        }
    }
}

/// Why a run directory does not verify.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Unverified {
    #[error("{missing} missing, {extra} extra, {corrupt} corrupt{}", if *missing + *corrupt > 0 { " (`--repair` redoes them)" } else { "" })]
    Damaged { missing: usize, extra: usize, corrupt: usize },
    #[error("incomplete: {0} job(s) failed; rerun the same `generate` command to retry them")]
    Failed(usize),
}

impl std::fmt::Display for Report {
    /// The counts, then one line per missing, extra and corrupt shard.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.live {
            Some(h) if self.generating() => {
                writeln!(f, "a generation is live ({}): its files in flight are not counted", h.process)?
            }
            Some(h) => writeln!(f, "in use by {h}")?,
            None => {}
        }
        let reasons: Vec<String> = self.reasons.iter().map(|(r, n)| format!("{r} {n}")).collect();
        let reasons = if reasons.is_empty() { String::new() } else { format!(" ({})", reasons.join(", ")) };
        let pruned = if self.pruned > 0 { format!(" ({} pruned: cached only)", self.pruned) } else { String::new() };
        writeln!(
            f,
            "{} jobs planned: {} done{pruned}, {} discarded{reasons}, {} failed, {} pending",
            self.planned, self.done, self.discarded, self.failed, self.pending
        )?;
        for m in &self.missing {
            writeln!(f, "missing: {m}")?;
        }
        for m in &self.extra {
            writeln!(f, "extra: {m}")?;
        }
        for (m, why) in &self.corrupt {
            writeln!(f, "corrupt: {m}: {why}")?;
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum VerifyError {
    #[error("{0}: no run manifest here (not a dynforge generate directory)")]
    NoManifest(String),
    #[error(transparent)]
    Manifest(#[from] dynforge_proto::manifest::ManifestError),
    #[error(transparent)]
    Ledger(#[from] ledger::LedgerError),
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error(transparent)]
    Lock(#[from] dynforge_proto::lock::LockError),
}

/// The robot and trajectory of the shard named `name` of a run simulated by `engine`; `None` for a name no job of
/// such a run writes.
fn job_of_shard(name: &str, engine: &str) -> Option<(u64, u32)> {
    use dynforge_proto::shard::{file_name, robot_of_file_name};
    let robot = robot_of_file_name(name)?;
    let trajectory = name.split_once("-t")?.1.split_once('-')?.0.parse().ok()?;
    (file_name(robot, trajectory, engine) == name).then_some((robot, trajectory))
}

/// Why a shard does not match its ledger entry.
#[derive(Debug, thiserror::Error)]
pub enum ShardProblem {
    #[error("{0}")]
    Read(#[from] std::io::Error),
    #[error("content hash differs from the ledger")]
    Hash,
    #[error("{0}")]
    Shard(#[from] dynforge_shard::ShardError),
    #[error("no /robot_description")]
    NoDescription,
    #[error("{found} joint states, the ledger says {ledger}")]
    Samples { found: usize, ledger: u64 },
    #[error("no label metadata")]
    NoLabels,
    #[error("label {0} missing or not a number")]
    Label(String),
    #[error("{labels} labels for {joints} joints (a family's shard has 12 per joint)")]
    FamilyLabels { labels: usize, joints: usize },
    #[error("no job metadata")]
    NoJob,
    #[error("job metadata does not match the file name")]
    JobMismatch,
}

/// Checks one shard against its ledger entry. A family's shard is labelled with its standard parameters (12 per
/// joint), the generator's with the paper's 38.
fn check_shard(path: &Path, job: &Job, samples: u64, hash: u64, family: bool) -> Result<(), ShardProblem> {
    let bytes = std::fs::read(path)?;
    if dynforge_proto::content_hash(&bytes) != hash {
        return Err(ShardProblem::Hash);
    }
    let bag = dynforge_shard::read_bytes(&bytes, path)?;
    if bag.robot_description.is_none() {
        return Err(ShardProblem::NoDescription);
    }
    if bag.joint_states.len() as u64 != samples {
        return Err(ShardProblem::Samples { found: bag.joint_states.len(), ledger: samples });
    }
    let labels = bag.metadata.get(META_LABELS).ok_or(ShardProblem::NoLabels)?;
    let names: Vec<&str> = match family {
        true => labels.keys().map(String::as_str).collect(),
        false => LABELS.iter().map(|l| l.name).collect(),
    };
    if let Some(l) = names.iter().find(|l| labels.get(**l).and_then(|v| v.parse::<f64>().ok()).is_none()) {
        return Err(ShardProblem::Label(l.to_string()));
    }
    let joints = bag.joint_states.first().map_or(0, |m| m.name.len());
    if family && labels.len() != 12 * joints {
        return Err(ShardProblem::FamilyLabels { labels: labels.len(), joints });
    }
    let record = bag.metadata.get(META_JOB).ok_or(ShardProblem::NoJob)?;
    if JobRecord::job_of(record) != Some(*job) {
        return Err(ShardProblem::JobMismatch);
    }
    Ok(())
}

/// Verifies the run directory `dir`, calling `progress` after each shard checked.
pub fn verify(dir: &Path, mut progress: impl FnMut(usize, usize)) -> Result<Report, VerifyError> {
    let manifest = Manifest::load(dir)?.ok_or_else(|| VerifyError::NoManifest(dir.display().to_string()))?;
    let entries = ledger::read(&dir.join(LEDGER))?;
    let engine = manifest.sim.engine.name();
    let shards = dir.join(SHARDS);
    let mut report = Report { live: dynforge_proto::lock::holder(dir), ..Report::default() };
    let pruned = dynforge_proto::run_dir::read_pruned(dir).map_err(|source| VerifyError::Io {
        path: dir.join(dynforge_proto::run_dir::PRUNED).display().to_string(),
        source,
    })?;
    let plan = Plan::of(&manifest);
    report.planned = plan.len() as usize;
    let latest = ledger::latest(&entries);
    let mut expected_files = BTreeSet::new();
    let total = latest.len();
    let mut recorded = 0;
    for (k, (id, e)) in latest.iter().enumerate() {
        let job = e.job(manifest.seed);
        match &e.status {
            Status::Done { samples, shard_hash } => {
                report.done += 1;
                let name = job.shard_name(engine);
                let path = shards.join(&name);
                expected_files.insert(name.clone());
                if !path.exists() {
                    if pruned.contains(&name) {
                        report.pruned += 1;
                    } else {
                        report.missing.push(name);
                    }
                } else if let Err(reason) = check_shard(&path, &job, *samples, *shard_hash, manifest.family.is_some()) {
                    report.corrupt.push((name, reason.to_string()));
                }
            }
            Status::Discarded { reason } => {
                report.discarded += 1;
                *report.reasons.entry(reason.clone()).or_default() += 1;
            }
            Status::Failed { .. } => report.failed += 1,
        }
        match plan.records(e) {
            true => recorded += 1,
            false => report.corrupt.push((format!("ledger job {id}"), "not a job of this run's manifest".into())),
        }
        progress(k + 1, total);
    }
    report.pending = report.planned.saturating_sub(recorded);
    // While a generation is live, a shard its worker has renamed into place is recorded a moment later: a planned
    // job's shard without a record (or with a failed one, being retried) is in flight, not extra.
    let generating = report.generating();
    let in_flight = |name: &str| {
        generating
            && job_of_shard(name, engine).is_some_and(|(robot, trajectory)| {
                let e = Entry { job_id: 0, robot, trajectory, status: Status::Failed { message: String::new() } };
                let id = plan::job_id(&e.job(manifest.seed), manifest.trajectories);
                plan.records(&Entry { job_id: id, ..e })
                    && latest.get(&id).is_none_or(|l| matches!(l.status, Status::Failed { .. }))
            })
    };
    let mut extra = Vec::new();
    match std::fs::read_dir(&shards) {
        Ok(listing) => {
            for entry in listing {
                let entry = entry.map_err(|source| VerifyError::Io { path: shards.display().to_string(), source })?;
                let name = entry.file_name().to_string_lossy().to_string();
                let writing = generating && is_temporary(&name);
                if !expected_files.contains(&name) && !writing && !in_flight(&name) {
                    extra.push(name);
                }
            }
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(source) => return Err(VerifyError::Io { path: shards.display().to_string(), source }),
    }
    report.extra = extra;
    report.extra.sort();
    Ok(report)
}

/// Directory the damaged shards are moved to by [`repair`] (kept, not deleted: they may be all there is of a job's
/// data if its rerun fails).
pub const QUARANTINE: &str = "quarantine";

/// Makes what `report` found missing or corrupt rerun on the next `generate`: corrupt shards move to
/// `DIR/quarantine/`, and each of those jobs gets a `failed` ledger entry naming the reason (a resume retries failed
/// jobs). Takes the directory's lock, so it refuses while a generation runs. Returns the jobs marked.
pub fn repair(dir: &Path, report: &Report) -> Result<usize, VerifyError> {
    let _lock = dynforge_proto::lock::RunLock::acquire(dir, std::time::Duration::ZERO, "verify --repair")?;
    let manifest = Manifest::load(dir)?.ok_or_else(|| VerifyError::NoManifest(dir.display().to_string()))?;
    let (mut ledger, entries) = ledger::Ledger::open(&dir.join(LEDGER))?;
    let engine = manifest.sim.engine.name();
    let latest = ledger::latest(&entries);
    let corrupt: BTreeMap<&str, &str> = report.corrupt.iter().map(|(n, why)| (n.as_str(), why.as_str())).collect();
    let quarantine = dir.join(QUARANTINE);
    let io = |path: &Path, source| VerifyError::Io { path: path.display().to_string(), source };
    let mut marked = 0;
    for e in latest.values().filter(|e| matches!(e.status, Status::Done { .. })) {
        let name = e.shard_name(manifest.seed, engine);
        let message = if report.missing.contains(&name) {
            "shard missing (found by verify)".to_string()
        } else if let Some(why) = corrupt.get(name.as_str()) {
            std::fs::create_dir_all(&quarantine).map_err(|s| io(&quarantine, s))?;
            let from = dir.join(SHARDS).join(&name);
            std::fs::rename(&from, quarantine.join(&name)).map_err(|s| io(&from, s))?;
            format!("shard corrupt (found by verify, moved to {QUARANTINE}/): {why}")
        } else {
            continue;
        };
        ledger.append(&ledger::Entry { status: Status::Failed { message }, ..(*e).clone() })?;
        marked += 1;
    }
    Ok(marked)
}

#[cfg(test)]
mod tests {
    use super::job_of_shard;
    use dynforge_proto::shard::file_name;

    #[test]
    fn a_shard_name_gives_its_job_only_in_its_canonical_spelling() {
        assert_eq!(job_of_shard(&file_name(315, 6, "native"), "native"), Some((315, 6)));
        assert_eq!(job_of_shard(&file_name(1_234_567, 15, "rapier"), "rapier"), Some((1_234_567, 15)));
        assert_eq!(job_of_shard(&file_name(315, 6, "native"), "rapier"), None, "another engine's");
        for other in ["r0315-t6-native.mcap", "r000315-t06-native.mcap.tmp", ".r000315-t06-native.mcap.9.tmp", "x.mcap"]
        {
            assert_eq!(job_of_shard(other, "native"), None, "{other}");
        }
    }
}
