//! The window cache: a hit returns identical tensors; a changed configuration or dataset misses; a damaged file is
//! rebuilt.

mod common;

use common::write_shard;
use dynforge_dataset::cache::windows::{CachedWindows, cache_path};
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::window::WindowSpec;
use dynforge_proto::job::Job;
use dynforge_proto::ledger::{self, Entry, Ledger, Status};
use dynforge_proto::manifest::{Manifest, Partition};

/// A run directory with `trajectories` shards of robot 1 of seed 5, its manifest and its ledger (the cache key reads
/// both as bytes); the default window geometry and the robot's features.
fn run_dir(dir: &std::path::Path, trajectories: u32) -> (WindowSpec, JacobianFeatures) {
    let shards = dir.join("shards");
    std::fs::create_dir_all(&shards).unwrap();
    let written: Vec<_> =
        (0..trajectories).map(|t| write_shard(&Job { seed: 5, robot: 1, trajectory: t }, &shards)).collect();
    let manifest = Manifest::new(5, 2, trajectories, Partition::WHOLE, Default::default(), Default::default());
    manifest.create_or_check(dir).unwrap();
    let entries: Vec<Entry> = written
        .iter()
        .enumerate()
        .map(|(t, (path, _))| {
            let shard_hash = dynforge_proto::content_hash(&std::fs::read(path).unwrap());
            let status = Status::Done { samples: 1, shard_hash };
            Entry { job_id: (trajectories + t as u32) as u64, robot: 1, trajectory: t as u32, status }
        })
        .collect();
    write_ledger(dir, &entries);
    (WindowSpec::default(), JacobianFeatures::new(&written[0].1.model))
}

fn write_ledger(dir: &std::path::Path, entries: &[Entry]) {
    let path = dir.join("ledger.tsv");
    let _ = std::fs::remove_file(&path);
    let (mut ledger, _) = Ledger::open(&path).unwrap();
    for e in entries {
        ledger.append(e).unwrap();
    }
}

#[test]
fn cache_hits_misses_and_rebuilds() {
    let dir = tempfile::tempdir().unwrap();
    let (spec, features) = run_dir(dir.path(), 2);

    let (built, skipped) = CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| true).unwrap();
    assert!(!built.hit && skipped.is_empty());
    assert!(built.count() >= 2);
    assert_eq!(built.data.len(), built.count() * spec.len * built.width);
    assert!(built.robots.iter().all(|&r| r == 1));
    let (again, _) =
        CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| panic!("a hit reads no shard")).unwrap();
    assert!(again.hit);
    assert_eq!(CachedEq(&again), CachedEq(&built));

    // Ledger lines in another order are the same dataset; an extra record is not.
    let mut entries = ledger::read(&dir.path().join("ledger.tsv")).unwrap();
    entries.reverse();
    write_ledger(dir.path(), &entries);
    assert!(CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| true).unwrap().0.hit);
    let failed = Status::Failed { message: "full disk".into() };
    entries.push(Entry { job_id: 0, robot: 0, trajectory: 0, status: failed });
    write_ledger(dir.path(), &entries);
    assert!(!CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| true).unwrap().0.hit);

    // Another geometry misses.
    let other = WindowSpec::new(32, 64, 16);
    let (w, _) = CachedWindows::load_or_build(dir.path(), &other, &features, |_, _| true).unwrap();
    assert!(!w.hit && w.count() > built.count());

    // A damaged cache file fails its checksum and is rebuilt to the same content.
    let path = cache_path(dir.path(), &spec, &features).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 1;
    std::fs::write(&path, &bytes).unwrap();
    let (rebuilt, _) = CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| true).unwrap();
    assert!(!rebuilt.hit);
    assert_eq!(CachedEq(&rebuilt), CachedEq(&built));
    // A truncated file (a crash before the atomic rename cannot produce one, a disk error can) is rebuilt too.
    std::fs::write(&path, &bytes[..bytes.len() / 3]).unwrap();
    assert!(!CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| true).unwrap().0.hit);
    // A length or count that claims more than the file holds is refused before anything is allocated for it (the
    // list of shards' length; the number of windows, after the magic and four numbers of the windows' encoding).
    let good = std::fs::read(&path).unwrap();
    let list = u64::from_le_bytes(good[8..16].try_into().unwrap()) as usize;
    for (at, claim) in [(8, u64::MAX / 2), (16 + list + 8 + 4 * 8, 1 << 40), (16 + list + 8 + 4 * 8, u64::MAX / 2)] {
        let mut bad = good.clone();
        bad[at..at + 8].copy_from_slice(&claim.to_le_bytes());
        std::fs::write(&path, &bad).unwrap();
        let (w, _) = CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| true).unwrap();
        assert!(!w.hit, "byte {at}: {claim}");
        assert_eq!(CachedEq(&w), CachedEq(&built));
    }
}

/// Equality of the cached content, ignoring whether it came from disk.
#[derive(Debug)]
struct CachedEq<'a>(&'a dynforge_dataset::cache::windows::CachedWindows);

impl PartialEq for CachedEq<'_> {
    fn eq(&self, o: &Self) -> bool {
        let (a, b) = (self.0, o.0);
        a.spec == b.spec && a.width == b.width && a.data == b.data && a.labels == b.labels && a.robots == b.robots
    }
}

#[test]
fn shards_read_on_all_cores_join_in_path_order() {
    let dir = tempfile::tempdir().unwrap();
    let mut robot = None;
    for r in [3, 1, 2] {
        for t in 0..2 {
            robot = Some(write_shard(&Job { seed: 5, robot: r, trajectory: t }, dir.path()).1);
        }
    }
    let features = JacobianFeatures::new(&robot.unwrap().model);
    let paths = dynforge_recording::dataset::list_shards(dir.path()).unwrap();
    assert_eq!(paths.len(), 6);
    let empty = || CachedWindows::new(WindowSpec::default());
    let mut together = empty();
    let added = together.add_shards(&paths, &features);
    let mut one_by_one = empty();
    for p in &paths {
        one_by_one.add_shards(std::slice::from_ref(p), &features);
    }
    assert_eq!(CachedEq(&together), CachedEq(&one_by_one));
    // Each shard's reported range holds its own robot's windows, and the robots follow the (sorted) file names.
    let robots: Vec<u64> = added.iter().map(|a| a.as_ref().unwrap().0).collect();
    assert_eq!(robots, [1, 1, 2, 2, 3, 3]);
    for a in &added {
        let (robot, range) = a.as_ref().unwrap();
        assert!(!range.is_empty() && together.robots[range.clone()].iter().all(|r| r == robot));
    }
}

#[test]
fn an_interrupted_build_is_an_error_and_caches_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (spec, features) = run_dir(dir.path(), 1);
    let e = CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| false).expect_err("stopped");
    assert!(e.to_string().contains("interrupted while reading the shards; nothing was cached"), "{e}");
    assert!(
        !CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| true).unwrap().0.hit,
        "a partial cache was written"
    );
}

/// A cache is never partial (it may be all that is left of pruned shards): a shard that does not hash to its ledger
/// record, a recorded shard that is missing, or a shard the ledger does not record leaves it unwritten; a written one
/// lists every shard it holds with its hash.
#[test]
fn a_cache_holds_every_recorded_shard_as_recorded_or_is_not_written() {
    let dir = tempfile::tempdir().unwrap();
    let (spec, features) = run_dir(dir.path(), 2);
    let shards = dynforge_recording::dataset::list_shards(dir.path()).unwrap();
    let good = std::fs::read(&shards[1]).unwrap();
    let cache_files = || std::fs::read_dir(dir.path().join("cache")).map_or(0, |l| l.count());

    // Changed after it was written: a byte of its labels, as a tool that does not keep the CRC would leave it.
    let mut changed = good.clone();
    let at = changed.windows(7).position(|w| w == b"mass_l2").unwrap();
    let digit = (at..changed.len()).find(|&k| changed[k].is_ascii_digit()).unwrap();
    changed[digit] = if changed[digit] == b'9' { b'8' } else { b'9' };
    std::fs::write(&shards[1], &changed).unwrap();
    let l = CachedWindows::load(dir.path(), &spec, &features, None, |_, _| true).unwrap();
    assert_eq!(l.skipped.len(), 1, "{:?}", l.skipped);
    assert!(l.skipped[0].to_string().contains("the run's ledger records"), "{}", l.skipped[0]);
    assert!(l.unwritten.as_deref().is_some_and(|w| w.contains("1 shard(s) skipped")), "{:?}", l.unwritten);
    assert_eq!(cache_files(), 0, "a cache without the changed shard was written");

    // Missing, and an extra file the ledger does not record.
    std::fs::remove_file(&shards[1]).unwrap();
    std::fs::write(shards[0].with_file_name("r000009-t00-native.mcap"), &good).unwrap();
    let l = CachedWindows::load(dir.path(), &spec, &features, None, |_, _| true).unwrap();
    let said: Vec<String> = l.skipped.iter().map(|s| s.to_string()).collect();
    assert!(said.iter().any(|s| s.contains("r000009") && s.contains("not recorded done")), "{said:?}");
    assert!(said.iter().any(|s| s.contains("r000001-t01") && s.contains("missing")), "{said:?}");
    assert_eq!(cache_files(), 0);

    // Restored: the cache is written, and lists both shards with their ledger hashes.
    std::fs::remove_file(shards[0].with_file_name("r000009-t00-native.mcap")).unwrap();
    std::fs::write(&shards[1], &good).unwrap();
    let l = CachedWindows::load(dir.path(), &spec, &features, None, |_, _| true).unwrap();
    assert!(l.skipped.is_empty() && l.unwritten.is_none() && !l.hit, "{:?}", l.unwritten);
    let recorded = dynforge_recording::dataset::recorded_shards(dir.path()).unwrap().unwrap();
    assert_eq!(l.held.as_ref(), Some(&recorded));
    let again = CachedWindows::load(dir.path(), &spec, &features, None, |_, _| panic!("a hit")).unwrap();
    assert!(again.hit && again.held == Some(recorded));
}

/// A cache file from before caches listed their shards (one could be partial) is not trusted where
/// the shards are still there: it is rebuilt, with its list. Only where shards were pruned, and it is all that is
/// left, is it read, without a list (on which `prepare --prune` deletes no shard).
#[test]
fn a_cache_without_its_list_of_shards_is_rebuilt_where_the_shards_remain() {
    let dir = tempfile::tempdir().unwrap();
    let (spec, features) = run_dir(dir.path(), 2);
    let built = CachedWindows::load(dir.path(), &spec, &features, None, |_, _| true).unwrap();
    assert!(built.held.as_ref().is_some_and(|h| h.len() == 2), "{:?}", built.held);
    let path = cache_path(dir.path(), &spec, &features).unwrap();
    let listed = std::fs::read(&path).unwrap();
    // The file: its magic, the list's length, the list, then the kind's own encoding, which older files held alone.
    assert_eq!(&listed[..8], b"DFCACHE2");
    let unlisted = &listed[16 + u64::from_le_bytes(listed[8..16].try_into().unwrap()) as usize..];
    std::fs::write(&path, unlisted).unwrap();
    let again = CachedWindows::load(dir.path(), &spec, &features, None, |_, _| true).unwrap();
    assert!(!again.hit && again.held == built.held, "an unlisted cache was trusted");
    assert_eq!(std::fs::read(&path).unwrap(), listed, "rebuilt, with its list");

    std::fs::write(&path, unlisted).unwrap();
    let shards = dynforge_recording::dataset::list_shards(dir.path()).unwrap();
    let name = shards[0].file_name().unwrap().to_string_lossy().into_owned();
    dynforge_proto::run_dir::write_pruned(dir.path(), [&name]).unwrap();
    std::fs::remove_file(&shards[0]).unwrap();
    let pruned = CachedWindows::load(dir.path(), &spec, &features, None, |_, _| panic!("a hit")).unwrap();
    assert!(pruned.hit && pruned.held.is_none());
    assert_eq!(CachedEq(&pruned.cache), CachedEq(&built.cache));
}
