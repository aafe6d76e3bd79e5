//! Where the files of a KITTI-format dataset live:
//! `ROOT/training/{velodyne,calib,label_2,image_2}/NNNNNN.*` (and `depth_2/` in simulated
//! data sets), `ROOT/ImageSets/*.txt`,
//! `ROOT/rgb_detections/rgb_detection_{split}.txt`. A split is given by name or as a
//! file, the same in every command ([`split_file`]).

use std::path::{Path, PathBuf};

/// Paths inside one `training/` (or `testing/`) directory.
#[derive(Debug, Clone)]
pub struct FrameDir {
    pub root: PathBuf,
}

impl FrameDir {
    pub fn new(root: impl Into<PathBuf>) -> Self {
        FrameDir { root: root.into() }
    }
    pub fn velodyne(&self, id: &str) -> PathBuf {
        self.root.join("velodyne").join(format!("{id}.bin"))
    }
    pub fn calib(&self, id: &str) -> PathBuf {
        self.root.join("calib").join(format!("{id}.txt"))
    }
    pub fn label(&self, id: &str) -> PathBuf {
        self.root.join("label_2").join(format!("{id}.txt"))
    }
    pub fn image(&self, id: &str) -> PathBuf {
        self.root.join("image_2").join(format!("{id}.png"))
    }
    /// The dense depth of the image_2 view (KITTI depth-completion PNG), which the
    /// simulator writes as ground truth for depth completion.
    pub fn depth(&self, id: &str) -> PathBuf {
        self.root.join("depth_2").join(format!("{id}.png"))
    }
}

/// A dataset root holding `training/`, `ImageSets/` and optionally `rgb_detections/`.
#[derive(Debug, Clone)]
pub struct DatasetDir {
    pub root: PathBuf,
}

impl DatasetDir {
    pub fn new(root: impl Into<PathBuf>) -> Self {
        DatasetDir { root: root.into() }
    }
    pub fn training(&self) -> FrameDir {
        FrameDir::new(self.root.join("training"))
    }
    /// The id list of `--split`: a name (`val` is `ImageSets/val.txt`) or a file (see
    /// [`split_file`]).
    pub fn split(&self, split: &str) -> PathBuf {
        split_file(&self.root.join("ImageSets"), split)
    }
    /// The 2D detections of a split: `rgb_detections/rgb_detection_<name>.txt`, with the
    /// name of a split file its stem (`ImageSets/val.txt` or `my/val.txt` → `val`).
    pub fn rgb_detections(&self, split: &str) -> PathBuf {
        self.root
            .join("rgb_detections")
            .join(format!("rgb_detection_{}.txt", split_name(split)))
    }
}

/// Whether `--split` names a file rather than a list of the data set: it has a path
/// separator or ends in `.txt`. One rule for every command, so `val` and
/// `DATA/ImageSets/val.txt` mean the same frames everywhere.
pub fn split_is_file(split: &str) -> bool {
    split.contains('/') || split.contains(std::path::MAIN_SEPARATOR) || split.ends_with(".txt")
}

/// The file `--split` stands for: itself if it names a file, else `<lists>/<split>.txt`
/// (`lists`: KITTI's `ImageSets/`, SUN RGB-D's `splits/`).
pub fn split_file(lists: &Path, split: &str) -> PathBuf {
    if split_is_file(split) {
        PathBuf::from(split)
    } else {
        lists.join(format!("{split}.txt"))
    }
}

/// A split's name: itself, or a split file's stem.
pub fn split_name(split: &str) -> &str {
    if split_is_file(split) {
        Path::new(split)
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or(split)
    } else {
        split
    }
}

/// Formats a frame index as KITTI's six-digit id.
pub fn frame_id(index: usize) -> String {
    format!("{index:06}")
}

/// A frame id as a user gives it (`4`, `000004`): digits only, zero-padded to KITTI's six,
/// so that every command names a frame the same way; anything else (`../evil`, `4.bin`) is
/// refused before it can become part of a path.
pub fn parse_frame_id(text: &str) -> std::result::Result<String, String> {
    let id = text.trim();
    if id.is_empty() || id.len() > 10 || !id.bytes().all(|b| b.is_ascii_digit()) {
        return Err(format!(
            "`{text}` is not a frame id (digits only, e.g. 4 or 000004)"
        ));
    }
    Ok(format!("{id:0>6}"))
}

/// Lists the frame ids present in a directory (files `NNNNNN.<ext>`), sorted.
pub fn list_frame_ids(dir: &Path, ext: &str) -> std::io::Result<Vec<String>> {
    let mut ids = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        let stem = path.file_stem().and_then(|s| s.to_str());
        if path.extension().and_then(|e| e.to_str()) == Some(ext)
            && let Some(stem) = stem
            && !stem.is_empty()
            && stem.bytes().all(|b| b.is_ascii_digit())
        {
            ids.push(stem.to_string());
        }
    }
    ids.sort();
    Ok(ids)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_split_is_a_name_or_a_file() {
        let ds = DatasetDir::new("/data/kitti");
        assert_eq!(ds.split("val"), Path::new("/data/kitti/ImageSets/val.txt"));
        assert_eq!(ds.split("lists/mine.txt"), Path::new("lists/mine.txt"));
        assert_eq!(ds.split("mine.txt"), Path::new("mine.txt"));
        assert_eq!(
            ds.rgb_detections("/data/kitti/ImageSets/val.txt"),
            Path::new("/data/kitti/rgb_detections/rgb_detection_val.txt")
        );
        assert_eq!(
            ds.rgb_detections("train"),
            Path::new("/data/kitti/rgb_detections/rgb_detection_train.txt")
        );
        assert_eq!(split_name("a/b/trainval.txt"), "trainval");
    }

    #[test]
    fn frame_ids_are_digits_padded_to_six() {
        assert_eq!(parse_frame_id("4").unwrap(), "000004");
        assert_eq!(parse_frame_id("000004").unwrap(), "000004");
        assert_eq!(parse_frame_id("1234567").unwrap(), "1234567");
        for bad in ["", "../evil", "4.bin", "-1", "00/1", "12345678901"] {
            assert!(parse_frame_id(bad).is_err(), "{bad}");
        }
    }
}
