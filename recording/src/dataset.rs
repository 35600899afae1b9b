//! The shards of a dataset: a run directory's `shards/` (see [`dynforge_proto::run_dir`]) or any folder of shards,
//! listed once or followed while a generation adds them. Shards are renamed into place whole, so a listed `*.mcap`
//! is always complete; the writers' temporary files are never picked up.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::manifest::Manifest;
use dynforge_robot::Model;

use crate::error::ReadError;
use crate::read::read;

/// The shard directory of `dir`: a `generate` directory's `shards/`, or `dir` itself.
pub fn shard_dir(dir: &Path) -> PathBuf {
    let shards = dir.join(dynforge_proto::run_dir::SHARDS);
    if shards.is_dir() { shards } else { dir.to_path_buf() }
}

/// The complete shards (`*.mcap`, not the writers' `.name.tmp` files) of `dir`'s shard directory, sorted by name.
pub fn list_shards(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(shard_dir(dir))? {
        let path = entry?.path();
        let name = path.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
        if !dynforge_proto::run_dir::is_temporary(&name) && name.ends_with(".mcap") {
            out.push(path);
        }
    }
    out.sort();
    Ok(out)
}

/// The complete shards of `dir`'s shard directory by the robot their names carry (each robot's in name order, i.e.
/// by trajectory): a dataset's robots, a family's variants.
pub fn shards_by_robot(dir: &Path) -> std::io::Result<BTreeMap<u64, Vec<PathBuf>>> {
    let mut out: BTreeMap<u64, Vec<PathBuf>> = BTreeMap::new();
    for path in list_shards(dir)? {
        if let Some(r) = path.file_name().and_then(|n| dynforge_proto::shard::robot_of_file_name(&n.to_string_lossy()))
        {
            out.entry(r).or_default().push(path);
        }
    }
    Ok(out)
}

/// Remembers which shards of a directory were already handed out.
#[derive(Debug, Default)]
pub struct ShardFollower {
    dir: PathBuf,
    seen: BTreeSet<PathBuf>,
}

impl ShardFollower {
    /// Follows `dir` (a `generate` directory's `shards/`, or any folder of shards).
    pub fn new(dir: &Path) -> Self {
        ShardFollower { dir: dir.to_path_buf(), seen: BTreeSet::new() }
    }

    /// Shards that appeared since the last call, sorted by name. A missing directory yields nothing yet.
    pub fn poll(&mut self) -> std::io::Result<Vec<PathBuf>> {
        match list_shards(&self.dir) {
            Ok(all) => Ok(all.into_iter().filter(|p| self.seen.insert(p.clone())).collect()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
            Err(e) => Err(e),
        }
    }
}

/// The shards the ledger of the run directory `dir` records done, by file name, with the content hash each had when
/// its worker wrote it: what a shard read as data must still hash to (its data-section CRC covers only the bytes, a
/// rewritten file can carry a new one). `None` for a folder of shards without a manifest (not a `generate` directory).
pub fn recorded_shards(dir: &Path) -> Result<Option<BTreeMap<String, u64>>, ReadError> {
    let Some(manifest) = Manifest::load(dir)? else { return Ok(None) };
    let path = dir.join(dynforge_proto::run_dir::LEDGER);
    let entries = dynforge_proto::ledger::read(&path)
        .map_err(|e| ReadError::Content { file: path.display().to_string(), problem: e.to_string() })?;
    Ok(Some(dynforge_proto::ledger::done_shards(&entries, manifest.seed, manifest.sim.engine.name())))
}

/// The content hash the ledger of its run directory records for the shard file `path` (`DIR/shards/NAME`), if it is
/// one and the ledger records it done.
pub fn recorded_hash(path: &Path) -> Option<u64> {
    let shards = path.parent()?;
    if shards.file_name()? != dynforge_proto::run_dir::SHARDS {
        return None;
    }
    let name = path.file_name()?.to_str()?;
    recorded_shards(shards.parent()?).ok()??.get(name).copied()
}

/// An error unless the shard `bytes` (of the file `path`) hash to `recorded`, what the run's ledger says its worker
/// wrote.
pub fn check_recorded(bytes: &[u8], path: &Path, recorded: u64) -> Result<(), ReadError> {
    let actual = dynforge_proto::content_hash(bytes);
    if actual == recorded {
        return Ok(());
    }
    Err(ReadError::Content {
        file: path.display().to_string(),
        problem: format!(
            "its content hash is {actual:016x}, the run's ledger records {recorded:016x}: changed or damaged after \
             it was written"
        ),
    })
}

/// What a run directory's manifest says about the robots: the generator configuration and the dataset seed.
/// `None` for a folder of shards without a manifest (not a `generate` directory).
pub fn generator(dir: &Path) -> Result<Option<(GeneratorConfig, u64)>, ReadError> {
    Ok(Manifest::load(dir)?.map(|m| (m.generator, m.seed)))
}

/// The robot of a dataset directory: that of its first readable shard, else (a directory whose shards were all
/// pruned) robot 0 of its manifest's generator. Every robot of a dataset shares the kinematics, which is all that
/// windows and identification take from it.
pub fn dataset_robot(dir: &Path) -> Result<Model, ReadError> {
    let shards = shard_dir(dir);
    let paths = list_shards(&shards)
        .map_err(|e| ReadError::Content { file: shards.display().to_string(), problem: e.to_string() })?;
    let mut last = None;
    for p in &paths {
        match read(p, None) {
            Ok(rec) => return Ok(rec.model),
            Err(e) => last = Some(e),
        }
    }
    if let Some((cfg, seed)) = generator(dir).ok().flatten()
        && let Ok(robot) = dynforge_robot::generator::generate(&cfg, seed, 0)
    {
        return Ok(robot.model);
    }
    Err(last.unwrap_or_else(|| ReadError::Content {
        file: shards.display().to_string(),
        problem: "no shards (generate a dataset with `dynforge generate` first)".into(),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_new_complete_shards_are_handed_out_once() {
        let dir = tempfile::tempdir().unwrap();
        let mut f = ShardFollower::new(&dir.path().join("missing"));
        assert!(f.poll().unwrap().is_empty());
        let mut f = ShardFollower::new(dir.path());
        std::fs::write(dir.path().join("r000001-t00-native.mcap"), b"x").unwrap();
        std::fs::write(dir.path().join(".r000002-t00-native.mcap.77.tmp"), b"partial").unwrap();
        std::fs::write(dir.path().join("notes.txt"), b"x").unwrap();
        let first = f.poll().unwrap();
        assert_eq!(first, [dir.path().join("r000001-t00-native.mcap")]);
        assert!(f.poll().unwrap().is_empty());
        // The writer renames its temporary file into place: now it is a shard.
        std::fs::rename(dir.path().join(".r000002-t00-native.mcap.77.tmp"), dir.path().join("r000002-t00-native.mcap"))
            .unwrap();
        std::fs::write(dir.path().join("r000000-t03-native.mcap"), b"x").unwrap();
        let second = f.poll().unwrap();
        assert_eq!(second, [dir.path().join("r000000-t03-native.mcap"), dir.path().join("r000002-t00-native.mcap")]);
    }
}
