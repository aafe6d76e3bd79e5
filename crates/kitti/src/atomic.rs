//! Atomic file writes: results, checkpoints and simulated frames are written to a
//! temporary sibling and renamed into place, so an interrupted run never leaves a
//! torn file that looks complete.
//!
//! The temporary file is created exclusively under an unpredictable name (tempfile's
//! `O_EXCL` creation), so a link planted at a guessable name cannot redirect the write
//! outside the target directory. One left by a killed process is named
//! `.<file name>.<random>.tmp`; [`temp_target`] recognises it (and burn-pack's scratch
//! files) for [`remove_temp_files`]. [`try_lock_file`] keeps a directory to one writer.

use crate::error::{FormatError, Result};
use std::io::Write;
use std::path::Path;

/// Writes `bytes` to `path` atomically (temp file in the same directory, fsync, rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let file_name = path
        .file_name()
        .ok_or_else(|| FormatError::file(path, "not a file path"))?
        .to_string_lossy();
    let result = (|| {
        let prefix = format!(".{file_name}.");
        let mut builder = tempfile::Builder::new();
        builder.prefix(&prefix).suffix(".tmp");
        // tempfile's default mode is 0600; the file a user keeps gets what any new file
        // gets (0666 less the umask), like `File::create`.
        #[cfg(unix)]
        builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
        let mut tmp = builder.tempfile_in(dir)?;
        tmp.write_all(bytes)?;
        tmp.as_file().sync_all()?;
        // On failure the temporary file is removed when `tmp` drops.
        tmp.persist(path).map(|_| ()).map_err(|e| e.error)
    })();
    result.map_err(|e| FormatError::io(path, e))
}

/// The file (name) whose write left the temporary file `name`: ours
/// (`.<target>.<random>.tmp`) or burn-pack's checkpoint scratch file
/// (`<target>.<pid>-<n>.tmp`); `None` for any other name.
pub fn temp_target(name: &str) -> Option<&str> {
    let (head, tail) = name.strip_suffix(".tmp")?.rsplit_once('.')?;
    if tail.is_empty() {
        return None;
    }
    if let Some(target) = head.strip_prefix('.') {
        return (!target.is_empty()).then_some(target);
    }
    let digits = |p: &str| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit());
    let burn_pack = tail
        .split_once('-')
        .is_some_and(|(pid, n)| digits(pid) && digits(n));
    (burn_pack && !head.is_empty()).then_some(head)
}

/// Whether `name` is a temporary file that a write of `target` (a file name) left behind.
pub fn is_temp_of(name: &str, target: &str) -> bool {
    temp_target(name) == Some(target)
}

/// Removes the temporary files in `dir` that killed writes of the files `ours` accepts (by
/// name) left behind; nothing else. Only for a directory no writer of those files is using.
pub fn remove_temp_files(dir: &Path, ours: impl Fn(&str) -> bool) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        if name.to_str().and_then(temp_target).is_some_and(&ours) {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// An advisory lock on the file `path` (created if absent, never truncated), held until the
/// returned file is dropped; `None` when another process holds it. Writers of one directory
/// (a training run, a simulated data set) take it so that a second one is refused instead of
/// mixing its files in.
pub fn try_lock_file(path: &Path) -> std::io::Result<Option<std::fs::File>> {
    let file = std::fs::File::options()
        .create(true)
        .truncate(false)
        .write(true)
        .open(path)?;
    match file.try_lock() {
        Ok(()) => Ok(Some(file)),
        Err(std::fs::TryLockError::WouldBlock) => Ok(None),
        Err(std::fs::TryLockError::Error(e)) => Err(e),
    }
}

/// The lock file that every command writing frames into a directory (detect's results,
/// depth maps, pseudo points) holds while it writes.
pub const WRITER_LOCK_FILE: &str = ".fusiondet.lock";

/// A held writer lock on a directory ([`lock_dir`]); released when dropped.
#[derive(Debug)]
pub struct DirLock {
    _file: std::fs::File,
}

/// Takes the writer lock of `dir` (which must exist): `shared` for one shard of a sharded
/// run (shards of one run write disjoint frames side by side), exclusive otherwise. `None`
/// when another writer holds it in a conflicting way: two runs never mix their files.
pub fn lock_dir(dir: &Path, shared: bool) -> std::io::Result<Option<DirLock>> {
    let file = std::fs::File::options()
        .create(true)
        .truncate(false)
        .write(true)
        .open(dir.join(WRITER_LOCK_FILE))?;
    let taken = if shared {
        file.try_lock_shared()
    } else {
        file.try_lock()
    };
    match taken {
        Ok(()) => Ok(Some(DirLock { _file: file })),
        Err(std::fs::TryLockError::WouldBlock) => Ok(None),
        Err(std::fs::TryLockError::Error(e)) => Err(e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writers_of_one_directory_exclude_each_other_and_shards_share() {
        let dir = tempfile::tempdir().unwrap();
        let whole = lock_dir(dir.path(), false).unwrap().expect("free");
        assert!(lock_dir(dir.path(), false).unwrap().is_none());
        assert!(lock_dir(dir.path(), true).unwrap().is_none());
        drop(whole);
        let a = lock_dir(dir.path(), true).unwrap().expect("free");
        let b = lock_dir(dir.path(), true).unwrap().expect("shards share");
        assert!(lock_dir(dir.path(), false).unwrap().is_none());
        drop((a, b));
        assert!(lock_dir(dir.path(), false).unwrap().is_some());
    }

    /// A written file is as readable as one `File::create` makes (not tempfile's 0600), so
    /// result files and pages can be shared or served.
    #[cfg(unix)]
    #[test]
    fn written_files_get_the_modes_of_new_files() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let plain = dir.path().join("plain.txt");
        std::fs::File::create(&plain).unwrap();
        let atomic = dir.path().join("atomic.txt");
        write_atomic(&atomic, b"x").unwrap();
        let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode(&atomic), mode(&plain));
    }

    #[test]
    fn writes_and_replaces_without_leaving_temp_files() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_atomic(&path, b"one").unwrap();
        write_atomic(&path, b"two").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"two");
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1);
    }

    #[cfg(unix)]
    #[test]
    fn a_link_planted_at_the_old_predictable_name_is_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let outside = tempfile::tempdir().unwrap();
        let victim = outside.path().join("victim.txt");
        std::fs::write(&victim, b"precious").unwrap();
        let path = dir.path().join("a.txt");
        let old_name = dir.path().join(format!(".a.txt.tmp{}", std::process::id()));
        std::os::unix::fs::symlink(&victim, &old_name).unwrap();
        write_atomic(&path, b"result").unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
        assert_eq!(std::fs::read(&path).unwrap(), b"result");
    }

    #[test]
    fn unwritable_directory_is_an_error_naming_the_file() {
        let err = write_atomic(Path::new("/nonexistent-dir/x.txt"), b"x").unwrap_err();
        assert!(err.to_string().contains("/nonexistent-dir/x.txt"));
    }

    #[test]
    fn temp_files_of_a_target_are_recognised() {
        assert!(is_temp_of(".state.json.Ab3xYz.tmp", "state.json"));
        assert!(is_temp_of("model.bpk.4242-2.tmp", "model.bpk"));
        assert!(!is_temp_of("model.bpk", "model.bpk"));
        assert!(!is_temp_of(".state.json.tmp", "state.json"));
        assert!(!is_temp_of("model.bpk.x-2.tmp", "model.bpk"));
        assert!(!is_temp_of("notes.txt.tmp", "model.bpk"));
        assert!(!is_temp_of(".other.json.Ab3.tmp", "state.json"));
        assert_eq!(temp_target(".000001.txt.k3Jx9a.tmp"), Some("000001.txt"));
        assert_eq!(
            temp_target("epoch-0003.optim.bpk.4242-1.tmp"),
            Some("epoch-0003.optim.bpk")
        );
        assert_eq!(temp_target("notes.tmp"), None);
    }

    #[test]
    fn a_held_lock_is_refused_until_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(".lock");
        let held = try_lock_file(&path).unwrap().expect("free");
        assert!(try_lock_file(&path).unwrap().is_none());
        drop(held);
        assert!(try_lock_file(&path).unwrap().is_some());
    }

    #[test]
    fn only_temporary_files_of_accepted_targets_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        for name in [".a.txt.Xk3.tmp", ".b.txt.Xk3.tmp", "a.txt", "c.tmp"] {
            std::fs::write(dir.path().join(name), b"x").unwrap();
        }
        remove_temp_files(dir.path(), |t| t == "a.txt");
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        left.sort();
        assert_eq!(left, [".b.txt.Xk3.tmp", "a.txt", "c.tmp"]);
    }
}
