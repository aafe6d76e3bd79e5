//! The output directory rule both simulators (streets and rooms) follow: a non-empty
//! directory is refused unless `--force` is given and its marker names a run of the same
//! simulator, whose own files are then removed (nothing else: no other file, nothing behind a
//! symbolic link); an advisory lock is held while writing, so two runs cannot mix frames.

use crate::dataset::{MARKER_FILE, SimError, io_err};
use std::path::Path;

/// The advisory lock a simulator holds on its output directory while writing.
const LOCK_FILE: &str = ".fusiondet-sim.lock";

/// The frame count a marker file records, if its first line is `head`.
pub(crate) fn marked_frames(text: &str, head: &str) -> Option<usize> {
    let mut lines = text.lines();
    (lines.next()? == head).then_some(())?;
    lines.next()?.strip_prefix("frames: ")?.parse().ok()
}

/// Writes the marker of a run of `frames` frames (before any frame, so that a killed run
/// can still be replaced with --force).
pub(crate) fn write_marker(root: &Path, head: &str, frames: usize) -> Result<(), SimError> {
    fusiondet_kitti::write_atomic(
        &root.join(MARKER_FILE),
        format!("{head}\nframes: {frames}\n").as_bytes(),
    )?;
    Ok(())
}

/// A locked output directory and the frame count of the earlier run `--force` replaces.
pub(crate) struct ClaimedDir {
    pub lock: std::fs::File,
    pub earlier_frames: Option<usize>,
}

/// Creates or claims `root` for a run whose marker starts with `head`. `replaceable` says in
/// the refusal what `--force` replaces (e.g. "a data set that `fusiondet simulate` wrote").
pub(crate) fn claim(
    root: &Path,
    force: bool,
    head: &str,
    replaceable: &str,
) -> Result<ClaimedDir, SimError> {
    let mut earlier_frames = None;
    if root.exists() {
        if !root.is_dir() {
            return Err(SimError::InvalidArgument(format!(
                "{}: the output path exists and is not a directory",
                root.display()
            )));
        }
        let non_empty = std::fs::read_dir(root)
            .map_err(io_err(root))?
            .next()
            .is_some();
        if non_empty && !force {
            return Err(SimError::NotEmpty(root.to_path_buf()));
        }
        if non_empty {
            let text = std::fs::read_to_string(root.join(MARKER_FILE)).unwrap_or_default();
            let Some(frames) = marked_frames(&text, head) else {
                return Err(SimError::InvalidArgument(format!(
                    "{}: --force replaces only {replaceable}, and this directory holds other \
                     files; choose an empty directory",
                    root.display()
                )));
            };
            earlier_frames = Some(frames);
        }
    }
    refuse_linked_folders(root)?;
    std::fs::create_dir_all(root).map_err(io_err(root))?;
    let lock_path = root.join(LOCK_FILE);
    let Some(lock) =
        fusiondet_kitti::atomic::try_lock_file(&lock_path).map_err(io_err(&lock_path))?
    else {
        return Err(SimError::InvalidArgument(format!(
            "{}: another `fusiondet simulate` is writing into this directory",
            root.display()
        )));
    };
    Ok(ClaimedDir {
        lock,
        earlier_frames,
    })
}

/// Refuses an output directory with a folder inside that is a symbolic link (`training` ->
/// someone's data set): every frame would be written, and `--force` would remove files,
/// outside the directory.
pub(crate) fn refuse_linked_folders(root: &Path) -> Result<(), SimError> {
    match fusiondet_kitti::paths::linked_folder_below(root, 3) {
        Some(link) => Err(SimError::InvalidArgument(format!(
            "{}: is a symbolic link to {}; a simulator writes only inside its own output \
             directory: remove the link or choose another directory",
            link.display(),
            fusiondet_kitti::paths::resolve(&link).display()
        ))),
        None => Ok(()),
    }
}

/// Is `name` `<6 digits>.<ext>`, a file of a frame below `frames`? Returns the extension
/// when it is.
pub(crate) fn frame_file(name: &str, frames: usize) -> Option<&str> {
    let (stem, ext) = name.rsplit_once('.').unwrap_or((name, ""));
    let frame = stem.len() == 6
        && stem.bytes().all(|b| b.is_ascii_digit())
        && stem.parse::<usize>().is_ok_and(|i| i < frames);
    frame.then_some(ext)
}

/// Removes the plain files `is_ours(kind, name)` claims in each `(folder, kind)` under
/// `root`; a folder that is a symbolic link (it leads outside the data set) or cannot be
/// read is left alone.
pub(crate) fn remove_own_files(
    root: &Path,
    dirs: &[(&str, &str)],
    is_ours: impl Fn(&str, &str) -> bool,
) -> Result<(), SimError> {
    for &(sub, kind) in dirs {
        let dir = root.join(sub);
        let real_dir = std::fs::symlink_metadata(&dir).is_ok_and(|m| m.is_dir());
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        if !real_dir {
            continue;
        }
        for entry in entries {
            let entry = entry.map_err(io_err(&dir))?;
            let path = entry.path();
            let plain_file = entry.file_type().is_ok_and(|t| t.is_file());
            if plain_file && is_ours(kind, &entry.file_name().to_string_lossy()) {
                std::fs::remove_file(&path).map_err(io_err(&path))?;
            }
        }
    }
    Ok(())
}
