//! The window cache: a hit returns identical tensors; a changed configuration or dataset misses; a damaged file is
//! rebuilt.

mod common;

use common::write_shard;
use dynforge_dataset::cache::windows::{CachedWindows, cache_path};
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::window::WindowSpec;
use dynforge_proto::job::Job;

/// A run directory with `trajectories` shards of robot 1 of seed 5, a manifest and a ledger (the cache key reads
/// both as bytes); the default window geometry and the robot's features.
fn run_dir(dir: &std::path::Path, trajectories: u32) -> (WindowSpec, JacobianFeatures) {
    let shards = dir.join("shards");
    std::fs::create_dir_all(&shards).unwrap();
    let robots: Vec<_> =
        (0..trajectories).map(|t| write_shard(&Job { seed: 5, robot: 1, trajectory: t }, &shards).1).collect();
    std::fs::write(dir.join("manifest.toml"), "seed = 5\n").unwrap();
    std::fs::write(dir.join("ledger.tsv"), "b\na\n").unwrap();
    (WindowSpec::default(), JacobianFeatures::new(&robots[0].model))
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
    std::fs::write(dir.path().join("ledger.tsv"), "a\nb\n").unwrap();
    assert!(CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| true).unwrap().0.hit);
    std::fs::write(dir.path().join("ledger.tsv"), "a\nb\nc\n").unwrap();
    assert!(!CachedWindows::load_or_build(dir.path(), &spec, &features, |_, _| true).unwrap().0.hit);

    // Another geometry misses.
    let other = WindowSpec { len: 32, stride: 64, ssr: 16 };
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
    let empty = || CachedWindows {
        spec: WindowSpec::default(),
        width: 0,
        data: Vec::new(),
        labels: Vec::new(),
        robots: Vec::new(),
        hit: false,
    };
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
