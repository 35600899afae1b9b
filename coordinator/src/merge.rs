//! Partitions of one run (`generate --partition i/n` on n hosts or array tasks) merged into the directory a single
//! host would have written: the same manifest (partition 0/1), every partition's ledger records, and the shards,
//! hard-linked where the filesystem allows (nothing is copied on a shared filesystem) and copied otherwise.
//!
//! A merge is refused unless the partitions are of one run (same settings, each index once) and make either the
//! whole run (indices `0..n`) or one coarser partition of it: partitions `j/n` with `j % m == i`, for a divisor `m` of
//! `n`, hold exactly the robots of partition `i/m`, and merge into the directory `generate --partition i/m` would
//! have written. That is how nested subsets of one large run are had (robots `r % 8 == 0`, then `r % 4 == 0`, ...).
//! Each partition must verify complete: every planned job recorded done or discarded, every shard present with its
//! recorded hash or pruned. The output then needs no further check, and training reads it like any run directory.
//!
//! Pruned partitions (`dataset prepare --prune`: shards deleted once cached) merge into a pruned directory: their
//! pruned lists are joined, and the output's caches are combined from the partitions' (`dynforge_dataset::cache::
//! partitions`) before the manifest, which comes last.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dynforge_dataset::cache::partitions::{self, PartitionsError};
use dynforge_proto::family::Sources;
use dynforge_proto::manifest::{Manifest, ManifestError, Partition};
use dynforge_proto::run_dir::{self, LEDGER, SHARDS};

use crate::verify::{VerifyError, verify};
use dynforge_proto::ledger::{self, Status};
use dynforge_proto::lock::RunLock;

#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    #[error("{0}: no run manifest here (not a dynforge generate directory)")]
    NoManifest(String),
    #[error("{dir}: {problem}")]
    Partition { dir: String, problem: String },
    #[error("the partitions do not make one run: {0}")]
    Set(String),
    #[error(
        "{0}: the output directory must be new or empty (a merge that was interrupted leaves one without \
         manifest.toml: delete it and merge again; the partitions are untouched)"
    )]
    OutputNotEmpty(String),
    #[error("combining the partitions' caches: {0}")]
    Caches(#[from] PartitionsError),
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error(transparent)]
    Manifest(#[from] ManifestError),
    #[error(transparent)]
    Verify(#[from] VerifyError),
    #[error(transparent)]
    Ledger(#[from] ledger::LedgerError),
    #[error(transparent)]
    Lock(#[from] dynforge_proto::lock::LockError),
    #[error(transparent)]
    Family(#[from] dynforge_proto::family::FamilyError),
}

/// What a merge did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Merged {
    pub partitions: usize,
    pub shards: usize,
    /// Shards that had to be copied (another filesystem); the rest are hard links.
    pub copied: usize,
    pub ledger_entries: usize,
    /// Shards recorded pruned in the partitions (not linked: their data are in the caches).
    pub pruned: usize,
    /// The cache files combined from the partitions' (file names in `out/cache/`).
    pub caches: Vec<String>,
}

impl std::fmt::Display for Merged {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "merged {} partitions: {} shards ({} hard-linked, {} copied, {} pruned), {} ledger records, {} caches \
             combined",
            self.partitions,
            self.shards + self.pruned,
            self.shards - self.copied,
            self.copied,
            self.pruned,
            self.ledger_entries,
            self.caches.len()
        )
    }
}

/// Merges the partition directories `parts` into the new directory `out`. `progress(k, n)` follows the verification
/// of each partition's shards.
pub fn merge(parts: &[PathBuf], out: &Path, mut progress: impl FnMut(usize, usize)) -> Result<Merged, MergeError> {
    // Written inside a partition, the output would be part of it (an extra file of its shards, a directory in its
    // caches): the partition would no longer verify, or would be merged into itself.
    let target = run_dir::resolve(out);
    for dir in parts {
        let part = run_dir::resolve(dir);
        if target.starts_with(&part) || part.starts_with(&target) {
            return Err(MergeError::Partition {
                dir: dir.display().to_string(),
                problem: format!(
                    "--out {} is inside it (or it inside --out): merge into a directory of its own",
                    out.display()
                ),
            });
        }
    }
    let (first, by_index, covered) = one_run(parts)?;
    for dir in parts {
        check_complete(dir, &mut progress)?;
    }
    // Which caches the partitions share: an error now, before anything is written, if pruned data would be lost.
    let caches = partitions::plan(parts)?;

    // The output: ours before anything is written.
    let _lock = RunLock::acquire(out, std::time::Duration::ZERO, "merge")?;
    let listing = std::fs::read_dir(out).map_err(|e| io(out, e))?;
    if listing.filter_map(Result::ok).any(|e| e.file_name() != dynforge_proto::lock::LOCK) {
        return Err(MergeError::OutputNotEmpty(out.display().to_string()));
    }
    let mut merged = join_ledgers_and_shards(&by_index, out, &first)?;
    merged.partitions = parts.len();
    let manifest = Manifest { partition: covered, ..first };
    merged.caches = caches.combine(parts, out, manifest.to_toml().as_bytes())?;
    if let Some(family) = &manifest.family {
        // A family's workers read the URDF and the excitations from the run directory: the merged run has them too.
        let sources = Sources::of_run(by_index[&0], family)?;
        sources.write_to(out).map_err(|e| io(out, e))?;
    }
    // Last, so that an interrupted merge leaves no directory that passes for a finished run.
    manifest.create_or_check(out)?;
    Ok(merged)
}

fn io(path: &Path, source: std::io::Error) -> MergeError {
    MergeError::Io { path: path.display().to_string(), source }
}

/// The manifest of the run the partitions `parts` belong to (the first's), the partitions by index, and the part of
/// the run they make; an error unless they are partitions of one run that make the whole run or one coarser
/// partition of it.
fn one_run(parts: &[PathBuf]) -> Result<(Manifest, BTreeMap<u32, &PathBuf>, Partition), MergeError> {
    let mut manifests = Vec::new();
    for dir in parts {
        let m = Manifest::load(dir)?.ok_or_else(|| MergeError::NoManifest(dir.display().to_string()))?;
        manifests.push(m);
    }
    let Some(first) = manifests.first().cloned() else {
        return Err(MergeError::Set("no partition directories given".into()));
    };
    let n = first.partition.count;
    let mut by_index: BTreeMap<u32, &PathBuf> = BTreeMap::new();
    for (dir, m) in parts.iter().zip(&manifests) {
        let whole = Manifest { partition: Partition::WHOLE, ..m.clone() };
        if whole != (Manifest { partition: Partition::WHOLE, ..first.clone() }) {
            return Err(MergeError::Partition {
                dir: dir.display().to_string(),
                problem: format!("its settings differ from {}'s", parts[0].display()),
            });
        }
        if m.partition.count != n {
            return Err(MergeError::Partition {
                dir: dir.display().to_string(),
                problem: format!("partition {}/{}, the others are of {n}", m.partition.index, m.partition.count),
            });
        }
        if let Some(other) = by_index.insert(m.partition.index, dir) {
            return Err(MergeError::Set(format!(
                "partition {}/{n} is given twice ({} and {})",
                m.partition.index,
                other.display(),
                dir.display()
            )));
        }
    }
    match covered(by_index.keys().copied(), n) {
        Some(part) => Ok((first, by_index, part)),
        None => {
            let missing: Vec<String> =
                (0..n).filter(|i| !by_index.contains_key(i)).map(|i| format!("{i}/{n}")).collect();
            Err(MergeError::Set(format!(
                "partition(s) {} missing (or give those j/{n} with j % m == i, for a divisor m of {n}: partition i/m)",
                missing.join(", ")
            )))
        }
    }
}

/// The part of a run that its partitions `indices` (each once) of `n` make: the whole run, or partition `i/m` when
/// they are exactly the `j` in `0..n` with `j % m == i` for a divisor `m` of `n`; `None` otherwise.
fn covered(indices: impl Iterator<Item = u32> + Clone, n: u32) -> Option<Partition> {
    let k = indices.clone().count() as u32;
    let first = indices.clone().min()?;
    let m = n.is_multiple_of(k).then(|| n / k)?;
    let part = Partition { index: first % m, count: m };
    let expected = (0..n).filter(|j| j % m == part.index);
    expected.eq(indices).then_some(part)
}

/// An error unless the partition `dir` is complete and intact (and no generation runs in it).
fn check_complete(dir: &Path, progress: &mut impl FnMut(usize, usize)) -> Result<(), MergeError> {
    let report = verify(dir, progress)?;
    let problem = if report.live.is_some() {
        "a generation is still running in it".to_string()
    } else if !report.is_ok() {
        format!("does not verify: {}", report.to_string().trim_end().replace('\n', "; "))
    } else if report.pending + report.failed > 0 {
        format!("incomplete: {} job(s) pending, {} failed; rerun its generate command", report.pending, report.failed)
    } else {
        return Ok(());
    };
    Err(MergeError::Partition { dir: dir.display().to_string(), problem })
}

/// Every partition's ledger records into `out`'s ledger, their shards hard-linked (or copied) into `out/shards/`,
/// and their pruned lists joined.
fn join_ledgers_and_shards(
    by_index: &BTreeMap<u32, &PathBuf>,
    out: &Path,
    run: &Manifest,
) -> Result<Merged, MergeError> {
    let shards_out = out.join(SHARDS);
    std::fs::create_dir_all(&shards_out).map_err(|e| io(&shards_out, e))?;
    let (mut ledger, _) = ledger::Ledger::open(&out.join(LEDGER))?;
    let engine = run.sim.engine.name();
    let mut merged = Merged::default();
    let mut pruned_out = std::collections::BTreeSet::new();
    for dir in by_index.values() {
        let entries = ledger::read(&dir.join(LEDGER))?;
        let pruned = run_dir::read_pruned(dir).map_err(|e| io(&dir.join(run_dir::PRUNED), e))?;
        for e in ledger::latest(&entries).values() {
            if let Status::Done { .. } = e.status {
                let name = e.shard_name(run.seed, engine);
                let (from, to) = (dir.join(SHARDS).join(&name), shards_out.join(&name));
                if pruned.contains(&name) && !from.exists() {
                    pruned_out.insert(name);
                    merged.pruned += 1;
                } else {
                    if std::fs::hard_link(&from, &to).is_err() {
                        std::fs::copy(&from, &to).map_err(|e| io(&from, e))?;
                        merged.copied += 1;
                    }
                    merged.shards += 1;
                }
            }
            ledger.append(e)?;
            merged.ledger_entries += 1;
        }
    }
    if !pruned_out.is_empty() {
        run_dir::write_pruned(out, &pruned_out).map_err(|e| io(&out.join(run_dir::PRUNED), e))?;
    }
    Ok(merged)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::{Plan, job_id};
    use dynforge_proto::generator::GeneratorConfig;
    use dynforge_proto::ledger::Entry;
    use dynforge_proto::sim::SimConfig;
    use std::collections::BTreeSet;

    const ROBOTS: u64 = 5;
    const TRAJECTORIES: u32 = 2;

    fn manifest(seed: u64, index: u32, count: u32) -> Manifest {
        let partition = Partition { index, count };
        Manifest::new(seed, ROBOTS, TRAJECTORIES, partition, GeneratorConfig::default(), SimConfig::default())
    }

    /// The run directory `root/name` of `m` whose ledger records every planned job discarded (complete, no shards),
    /// less the last `short` of them.
    fn partition_dir(root: &Path, name: &str, m: &Manifest, short: usize) -> PathBuf {
        let dir = root.join(name);
        std::fs::create_dir_all(&dir).unwrap();
        m.create_or_check(&dir).unwrap();
        let (mut ledger, _) = ledger::Ledger::open(&dir.join(LEDGER)).unwrap();
        let jobs: Vec<_> = Plan::of(m).jobs().collect();
        for j in &jobs[..jobs.len() - short] {
            let status = Status::Discarded { reason: "collision".into() };
            let e = Entry { job_id: job_id(j, m.trajectories), robot: j.robot, trajectory: j.trajectory, status };
            ledger.append(&e).unwrap();
        }
        dir
    }

    fn partitions(root: &Path, count: u32) -> Vec<PathBuf> {
        (0..count).map(|i| partition_dir(root, &format!("part{i}"), &manifest(1, i, count), 0)).collect()
    }

    #[test]
    fn the_partitions_of_one_run_make_the_run_or_one_coarser_partition() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path();
        let three = partitions(&root.join("three"), 3);
        let two = partitions(&root.join("two"), 2);
        let other_seed = partition_dir(root, "seed2", &manifest(2, 1, 2), 0);
        let again = partition_dir(root, "again", &manifest(1, 0, 2), 0);
        let no_manifest = root.join("empty");
        std::fs::create_dir_all(&no_manifest).unwrap();

        let swapped = [two[1].clone(), two[0].clone()];
        let (first, by_index, whole) = one_run(&swapped).unwrap();
        assert_eq!(by_index.keys().copied().collect::<Vec<_>>(), [0, 1], "given in any order");
        assert_eq!(Manifest { partition: Partition::WHOLE, ..first }, manifest(1, 0, 1));
        assert_eq!(whole, Partition::WHOLE);
        assert_eq!(one_run(&three).unwrap().2, Partition::WHOLE);
        let six = partitions(&root.join("six"), 6);
        let pick = |js: &[usize]| js.iter().map(|&j| six[j].clone()).collect::<Vec<_>>();
        assert_eq!(one_run(&pick(&[3, 0])).unwrap().2, Partition { index: 0, count: 3 });
        assert_eq!(one_run(&pick(&[5, 1, 3])).unwrap().2, Partition { index: 1, count: 2 });
        assert_eq!(one_run(&pick(&[4])).unwrap().2, Partition { index: 4, count: 6 });
        assert!(matches!(one_run(&pick(&[0, 2])), Err(MergeError::Set(_))), "robots r % 6 in {{0, 2}}: no partition");
        assert!(matches!(one_run(&pick(&[0, 1, 2, 3])), Err(MergeError::Set(_))), "4 does not divide 6");

        let refusal = |parts: &[PathBuf]| one_run(parts).expect_err("refused");
        let set = |parts: &[PathBuf]| matches!(refusal(parts), MergeError::Set(_));
        let part = |parts: &[PathBuf]| matches!(refusal(parts), MergeError::Partition { .. });
        assert!(set(&[]), "none given");
        assert!(set(&three[..2]), "one missing");
        assert!(set(&[two[0].clone(), again, two[1].clone()]), "one given twice");
        assert!(part(&[two[0].clone(), three[1].clone()]), "of a different split");
        assert!(part(&[two[0].clone(), other_seed]), "of another run");
        assert!(matches!(refusal(&[two[0].clone(), no_manifest]), MergeError::NoManifest(_)));
    }

    #[test]
    fn merged_partitions_make_the_whole_run_with_each_record_once() {
        let tmp = tempfile::tempdir().unwrap();
        let parts = partitions(tmp.path(), 3);
        let out = tmp.path().join("merged");
        let merged = merge(&parts, &out, |_, _| {}).unwrap();

        let whole = Manifest::load(&out).unwrap().expect("the merged run has a manifest");
        assert_eq!(whole, manifest(1, 0, 1), "the single host's manifest: partition 0/1");
        let plan = Plan::of(&whole);
        let entries = ledger::read(&out.join(LEDGER)).unwrap();
        let ids: BTreeSet<u64> = entries.iter().map(|e| e.job_id).collect();
        let planned: BTreeSet<u64> = plan.jobs().map(|j| job_id(&j, TRAJECTORIES)).collect();
        assert_eq!(ids, planned, "every planned job is recorded");
        assert_eq!(entries.len() as u64, plan.len(), "and none twice");
        assert!(entries.iter().all(|e| plan.records(e)));
        assert_eq!(merged.partitions, parts.len());
        assert_eq!(merged.ledger_entries, entries.len());
        assert_eq!((merged.shards, merged.pruned), (0, 0), "discarded jobs have no shards");
    }

    /// Checks before writing: a refused merge leaves no output behind that could pass for, or spoil, a run.
    #[test]
    fn an_incomplete_partition_or_an_output_inside_one_is_refused_before_anything_is_written() {
        let tmp = tempfile::tempdir().unwrap();
        let mut parts = partitions(tmp.path(), 2);
        let inside = parts[0].join("merged");
        assert!(matches!(merge(&parts, &inside, |_, _| {}), Err(MergeError::Partition { .. })));
        assert!(!inside.exists());

        parts[1] = partition_dir(tmp.path(), "short", &manifest(1, 1, 2), 1);
        let out = tmp.path().join("merged");
        assert!(matches!(merge(&parts, &out, |_, _| {}), Err(MergeError::Partition { .. })));
        assert!(!out.exists(), "the output is not created");
    }
}
