//! The run directory: what `generate` writes and everyone else reads, and the one rule by which every file of the
//! project appears on disk.
//!
//! ```text
//! DIR/manifest.toml   what the dataset is (seed, sizes, generator and simulation settings, versions)
//! DIR/ledger.tsv      one checksummed, fsync'd line per finished job (done with its shard's hash, discarded, failed)
//! DIR/shards/         one MCAP file per kept job (schema: `crate::shard`)
//! DIR/logs/           one log per worker slot
//! DIR/cache/          the trainer's preprocessed windows and physics, keyed by what determines them
//! DIR/pruned.txt      shards deleted once their data were cached (`dataset prepare --prune`), one name per line
//! ```
//!
//! **Pruned shards.** A shard named in `pruned.txt` was recorded done, cached, and then deleted to bound the disk a
//! paper-scale run needs: its data live on only in the caches that were current when it was pruned. It is not
//! missing (verify counts it apart, generate does not remake it); deleting `pruned.txt` turns the absent shards
//! into missing ones, which the next `generate` remakes (jobs are deterministic).
//!
//! **The temporary-file rule.** A file is written to a temporary file beside it, `.NAME.PID.tmp` (hidden, named after
//! the final file and the writing process, so concurrent writers never share one), fsync'd, renamed over `NAME`, and
//! the directory is fsync'd: readers see the old file or the new one, whole, never a part. Readers skip temporary
//! files ([`is_temporary`]); a crashed writer's leftovers are removed by whoever holds the directory's lock
//! ([`crate::lock`], [`remove_temporaries`]).
//!
//! **No writing through links.** A temporary file is created anew (`O_EXCL`: whatever is in its place, a link
//! included, is removed first, never written through), and the files appended to or locked in place (the ledger, the
//! lock, the workers' logs) are opened with `O_NOFOLLOW` ([`open_for_writing`]): a symbolic link planted in a run
//! directory can make dynforge refuse, never truncate, overwrite or append to the file it points at. (Directories
//! are followed: `shards/` on another disk is a legitimate layout.)

use std::fs::{File, OpenOptions};
use std::path::{Path, PathBuf};

pub const MANIFEST: &str = "manifest.toml";
pub const LEDGER: &str = "ledger.tsv";
pub const SHARDS: &str = "shards";
pub const LOGS: &str = "logs";
pub const CACHE: &str = "cache";
pub const PRUNED: &str = "pruned.txt";

const PRUNED_HEADER: &str = "# dynforge: shards deleted after their data were cached (dataset prepare --prune)";

/// The shards of `dir` recorded as pruned (empty when there is no `pruned.txt`). An error is the OS's alone, as
/// [`write_atomic`]'s: the caller names `dir.join(PRUNED)`.
pub fn read_pruned(dir: &Path) -> std::io::Result<std::collections::BTreeSet<String>> {
    match std::fs::read_to_string(dir.join(PRUNED)) {
        Ok(text) => {
            Ok(text.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with('#')).map(String::from).collect())
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Default::default()),
        Err(e) => Err(e),
    }
}

/// Records `names` as the pruned shards of `dir` (the whole list, replaced atomically).
pub fn write_pruned<'a>(dir: &Path, names: impl IntoIterator<Item = &'a String>) -> std::io::Result<()> {
    let mut text = format!("{PRUNED_HEADER}\n");
    for n in names {
        text.push_str(n);
        text.push('\n');
    }
    write_atomic(&dir.join(PRUNED), text.as_bytes())
}

/// `path` as the filesystem resolves it, also when its last components do not exist yet: the longest existing
/// ancestor canonicalized (links followed, `.` and `..` gone), the rest appended. What tells whether two spellings
/// (`./out`, `run/../run/out`, a link) are one place, or one inside the other.
pub fn resolve(path: &Path) -> PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut rest = Vec::new();
    let mut base = absolute.as_path();
    loop {
        if let Ok(c) = base.canonicalize() {
            return rest.iter().rev().fold(c, |p: PathBuf, name| p.join(name));
        }
        match (base.parent(), base.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                base = parent;
            }
            _ => return absolute,
        }
    }
}

/// Whether a file name is a writer's temporary file (never a finished file).
pub fn is_temporary(name: &str) -> bool {
    name.starts_with('.') && name.ends_with(".tmp")
}

/// The temporary file this process writes `path` through.
pub fn temporary_path(path: &Path) -> PathBuf {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    dir.join(format!(".{name}.{}.tmp", std::process::id()))
}

/// Removes the temporary files that killed writers left in `dir` ([`is_temporary`]); returns how many. Only the
/// holder of the run directory's lock may call it (every writer holds the lock, so none is live). A missing
/// directory has none.
pub fn remove_temporaries(dir: &Path) -> std::io::Result<usize> {
    let listing = match std::fs::read_dir(dir) {
        Ok(l) => l,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let mut n = 0;
    for entry in listing {
        let entry = entry?;
        if is_temporary(&entry.file_name().to_string_lossy()) {
            match std::fs::remove_file(entry.path()) {
                Ok(()) => n += 1,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(e),
            }
        }
    }
    Ok(n)
}

/// Opens `path` with `options` (which write, append or lock it in place) without following a symbolic link there:
/// a link is refused with an error saying so, and the file it points at is not touched.
pub fn open_for_writing(options: &mut OpenOptions, path: &Path) -> std::io::Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    options.custom_flags(libc::O_NOFOLLOW).open(path).map_err(|e| match e.raw_os_error() {
        Some(libc::ELOOP) => std::io::Error::new(
            e.kind(),
            "it is a symbolic link: dynforge does not write through links in a run directory (remove the link)",
        ),
        _ => e,
    })
}

/// Creates the temporary file `tmp` of the rule for writing: new (`O_EXCL`, which never follows a link), after
/// removing whatever a crashed writer or anyone else left in its place.
pub fn create_temporary(tmp: &Path) -> std::io::Result<File> {
    match std::fs::remove_file(tmp) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(e),
    }
    OpenOptions::new().write(true).create_new(true).open(tmp)
}

/// Writes `bytes` to `path` by the temporary-file rule. On failure the temporary file is removed and `path` is
/// untouched. The directory must exist.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    write_with(
        path,
        |mut f| {
            f.write_all(bytes)?;
            Ok(f)
        },
        |_, e| e,
    )
}

/// [`write_atomic`] of a file whose bytes `fill` writes into the temporary file it is given (streamed, never all in
/// memory: a cache of several gigabytes); `io` turns a file-system error into `E`.
pub fn write_with<E>(
    path: &Path,
    fill: impl FnOnce(File) -> Result<File, E>,
    io: impl Fn(&Path, std::io::Error) -> E,
) -> Result<(), E> {
    let write = |tmp: &Path| fill(create_temporary(tmp).map_err(|e| io(tmp, e))?)?.sync_all().map_err(|e| io(tmp, e));
    replace_atomically(path, write, &io)
}

/// The temporary-file rule for writers that produce the file themselves: `fill` creates the temporary file with
/// [`create_temporary`], writes and syncs it; it then replaces `path` (a link at `path` is replaced, not followed),
/// and the rename is made durable. `io` turns a rename or sync error into `E`.
pub fn replace_atomically<T, E>(
    path: &Path,
    fill: impl FnOnce(&Path) -> Result<T, E>,
    io: impl Fn(&Path, std::io::Error) -> E,
) -> Result<T, E> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let tmp = temporary_path(path);
    let result = fill(&tmp).and_then(|value| {
        std::fs::rename(&tmp, path).map_err(|e| io(path, e))?;
        std::fs::File::open(dir).and_then(|d| d.sync_all()).map_err(|e| io(dir, e))?;
        Ok(value)
    });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temporary_files_are_hidden_per_process_and_recognised() {
        let tmp = temporary_path(Path::new("d/shards/r000001-t00-native.mcap"));
        let name = tmp.file_name().unwrap().to_str().unwrap();
        assert_eq!(tmp.parent().unwrap(), Path::new("d/shards"));
        assert_eq!(name, format!(".r000001-t00-native.mcap.{}.tmp", std::process::id()));
        assert!(is_temporary(name));
        assert!(!is_temporary("r000001-t00-native.mcap") && !is_temporary(".hidden.mcap"));
    }

    #[test]
    fn the_pruned_list_reads_back_and_is_empty_when_absent() {
        let dir = std::env::temp_dir().join(format!("dynforge-pruned-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(read_pruned(&dir).unwrap().is_empty());
        let names: std::collections::BTreeSet<String> =
            ["r000001-t00-native.mcap", "r000002-t03-native.mcap"].map(String::from).into();
        write_pruned(&dir, &names).unwrap();
        assert_eq!(read_pruned(&dir).unwrap(), names);
        assert!(std::fs::read_to_string(dir.join(PRUNED)).unwrap().starts_with('#'));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = std::env::temp_dir().join(format!("dynforge-run-dir-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("f");
        write_atomic(&path, b"old").unwrap();
        let r: Result<(), std::io::Error> = replace_atomically(
            &path,
            |tmp| std::fs::write(tmp, b"half").and(Err(std::io::Error::other("full"))),
            |_, e| e,
        );
        assert!(r.is_err());
        assert_eq!(std::fs::read(&path).unwrap(), b"old");
        assert!(std::fs::read_dir(&dir).unwrap().all(|e| !is_temporary(&e.unwrap().file_name().to_string_lossy())));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn paths_resolve_to_one_spelling_also_where_they_do_not_exist_yet() {
        let dir = tempfile::tempdir().unwrap();
        let real = dir.path().canonicalize().unwrap();
        std::fs::create_dir(real.join("a")).unwrap();
        std::os::unix::fs::symlink(real.join("a"), real.join("link")).unwrap();
        assert_eq!(resolve(&real.join("link/new/x")), real.join("a/new/x"));
        assert_eq!(resolve(&real.join("a/../a/./y")), real.join("a/y"));
    }

    #[test]
    fn links_in_a_run_directory_are_never_written_through() {
        let dir = tempfile::tempdir().unwrap();
        let outside = dir.path().join("outside");
        std::fs::write(&outside, b"keep me").unwrap();
        // A link planted where the temporary file goes, and one at the final name.
        let path = dir.path().join("ledger.tsv");
        std::os::unix::fs::symlink(&outside, temporary_path(&path)).unwrap();
        write_atomic(&path, b"new").unwrap();
        assert_eq!(std::fs::read(&outside).unwrap(), b"keep me");
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
        let manifest = dir.path().join("manifest.toml");
        std::os::unix::fs::symlink(&outside, &manifest).unwrap();
        write_atomic(&manifest, b"replaced").unwrap();
        assert!(!manifest.is_symlink() && std::fs::read(&outside).unwrap() == b"keep me");
        // Files written in place refuse the link, naming the problem.
        let log = dir.path().join("worker-0.log");
        std::os::unix::fs::symlink(&outside, &log).unwrap();
        let e = open_for_writing(OpenOptions::new().append(true).create(true), &log).unwrap_err();
        assert!(e.to_string().contains("symbolic link"), "{e}");
        assert_eq!(std::fs::read(&outside).unwrap(), b"keep me");
    }
}
