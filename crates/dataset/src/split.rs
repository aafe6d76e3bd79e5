//! The frames a split lists (`ImageSets/<split>.txt` of a KITTI-layout data set).

use crate::error::{DataError, Result};
use crate::frame::{DerivedFrame, InMemoryFrames};
use fusiondet_kitti::{DatasetDir, read_split};
use std::path::Path;

/// The ids of a split (all of them, or the first `max_frames`; 0 = all); an empty
/// split is an error.
pub fn split_ids(data_dir: &Path, split: &str, max_frames: usize) -> Result<Vec<String>> {
    let dataset = DatasetDir::new(data_dir);
    if !data_dir.join("ImageSets").is_dir() && data_dir.join("splits").is_dir() {
        return Err(DataError::Data(format!(
            "{} is a prepared SUN RGB-D directory (splits/, no ImageSets/), but this reads \
             KITTI data; train or detect with a `[dataset] format = \"sun_rgbd\"` model",
            data_dir.display()
        )));
    }
    let mut ids = read_split(&dataset.split(split))?;
    if max_frames > 0 {
        ids.truncate(max_frames);
    }
    if ids.is_empty() {
        return Err(DataError::Data(format!(
            "split `{split}` of {} lists no frames",
            data_dir.display()
        )));
    }
    Ok(ids)
}

/// Loads the frames of a split into memory, in the family's derived form.
pub fn load_split<F: DerivedFrame>(
    data_dir: &Path,
    split: &str,
    max_frames: usize,
    with_labels: bool,
) -> Result<InMemoryFrames<F>> {
    let ids = split_ids(data_dir, split, max_frames)?;
    InMemoryFrames::load(&DatasetDir::new(data_dir).training(), &ids, with_labels)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{FrameSource, SensorFrame};

    fn sample_root() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample")
    }

    #[test]
    fn a_sun_rgbd_directory_is_named_as_such() {
        let sun = Path::new(env!("CARGO_MANIFEST_DIR")).join("../sunrgbd/tests/data");
        let err = split_ids(&sun, "val", 0).unwrap_err().to_string();
        assert!(err.contains("SUN RGB-D"), "{err}");
    }

    #[test]
    fn loads_the_listed_frames_in_order() {
        let all = split_ids(&sample_root(), "val", 0).unwrap();
        let two = load_split::<SensorFrame>(&sample_root(), "val", 2, false).unwrap();
        assert_eq!(two.len(), 2);
        assert_eq!(two.frame_id(1), all[1]);
        assert!(two.frame(0).unwrap().objects.is_empty(), "labels not read");
    }

    #[test]
    fn an_empty_or_missing_split_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir_all(dir.path().join("ImageSets")).unwrap();
        std::fs::write(dir.path().join("ImageSets/val.txt"), "").unwrap();
        let err = split_ids(dir.path(), "val", 0).unwrap_err().to_string();
        assert!(err.contains("lists no frames"), "{err}");
        let err = split_ids(dir.path(), "train", 0).unwrap_err().to_string();
        assert!(err.contains("train.txt"), "{err}");
    }
}
