//! Where the files of a KITTI-format dataset live:
//! `ROOT/training/{velodyne,calib,label_2,image_2}/NNNNNN.*` (and `depth_2/` in simulated
//! data sets), `ROOT/ImageSets/*.txt`,
//! `ROOT/rgb_detections/rgb_detection_{split}.txt`.

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
    pub fn split(&self, name: &str) -> PathBuf {
        self.root.join("ImageSets").join(format!("{name}.txt"))
    }
    pub fn rgb_detections(&self, split: &str) -> PathBuf {
        self.root
            .join("rgb_detections")
            .join(format!("rgb_detection_{split}.txt"))
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
    use super::parse_frame_id;

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
