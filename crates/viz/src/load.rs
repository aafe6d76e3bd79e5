//! Reading one frame (a [`SensorFrame`] and its image) from a KITTI `training/` (or
//! `testing/`) directory and, optionally, a directory of result files into a [`FrameView`].

use crate::error::VizError;
use crate::frame::FrameView;
use fusiondet_dataset::{DataError, SensorFrame};
use fusiondet_kitti::image::read_image;
use fusiondet_kitti::{FrameDir, read_objects};
use std::path::{Path, PathBuf};

/// The result file of frame `id`: `DIR/ID.txt`, or the KITTI devkit's `DIR/data/ID.txt`.
pub fn result_file(dir: &Path, id: &str) -> Option<PathBuf> {
    [
        dir.join(format!("{id}.txt")),
        dir.join("data").join(format!("{id}.txt")),
    ]
    .into_iter()
    .find(|p| p.is_file())
}

/// Loads frame `id`. Image, calibration and point cloud are required. Labels are too,
/// unless the frame directory has no `label_2/` at all (KITTI's `testing/`), which
/// yields no ground truth and a note. With `result_dir`, the frame's detections are
/// read; a result directory lacking this frame yields `detections: None` and a note
/// (the caller decides whether to print it), so the picture still shows ground truth.
pub fn load_frame(
    frames: &FrameDir,
    id: &str,
    result_dir: Option<&Path>,
) -> Result<FrameView, VizError> {
    // The image first: a frame without its picture cannot be drawn at all.
    let image = read_image(&frames.image(id))?;
    let mut notes = Vec::new();
    let has_labels = frames.label(id).parent().is_none_or(|dir| dir.is_dir());
    if !has_labels {
        notes.push(format!(
            "no label_2/ in {}: no ground truth",
            frames.root.display()
        ));
    }
    let frame = SensorFrame::load(frames, id, has_labels).map_err(|e| match e {
        DataError::Format(e) => VizError::Format(e),
        DataError::Calib { message, .. } => VizError::Calib {
            path: frames.calib(id),
            message,
        },
        DataError::Data(message) => VizError::ResultDir {
            path: frames.root.clone(),
            message,
        },
    })?;

    let detections = match result_dir {
        None => None,
        Some(dir) => {
            if !dir.is_dir() {
                return Err(VizError::ResultDir {
                    path: dir.to_path_buf(),
                    message: "result directory does not exist or is not a directory".into(),
                });
            }
            match result_file(dir, id) {
                Some(path) => Some(read_objects(&path)?),
                None => {
                    notes.push(format!(
                        "no result file for {id} in {}: ground truth only",
                        dir.display()
                    ));
                    None
                }
            }
        }
    };

    Ok(FrameView {
        title: format!("frame {id}"),
        image,
        camera: frame.camera,
        points: frame.lidar,
        ground_truth: frame.objects,
        detections,
        notes,
        pseudo_points: None,
        depth: None,
        point_colours: None,
        class_names: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::sample_dir;

    #[test]
    fn loads_a_bundled_frame() {
        let view = load_frame(&sample_dir(), "000001", None).unwrap();
        assert_eq!(view.image.dimensions(), (1242, 375));
        assert_eq!(view.ground_truth.len(), 7);
        assert!(view.points.len() > 1000);
        assert!(view.detections.is_none() && view.notes.is_empty());
    }

    #[test]
    fn result_dir_without_the_frame_gives_a_note_not_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let view = load_frame(&sample_dir(), "000001", Some(dir.path())).unwrap();
        assert!(view.detections.is_none());
        assert!(
            view.notes[0].contains("no result file for 000001"),
            "{:?}",
            view.notes
        );
    }

    #[test]
    fn results_are_found_directly_or_under_data() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("data")).unwrap();
        let line = "Car -1 -1 1.85 387.63 181.54 423.81 203.12 1.67 1.87 3.69 -16.53 2.39 58.49 1.57 0.9\n";
        std::fs::write(dir.path().join("data/000001.txt"), line).unwrap();
        let view = load_frame(&sample_dir(), "000001", Some(dir.path())).unwrap();
        assert_eq!(view.detections.unwrap()[0].score, Some(0.9));
    }

    #[test]
    fn missing_frame_or_result_dir_is_an_error_naming_the_path() {
        let err = load_frame(&sample_dir(), "999999", None)
            .unwrap_err()
            .to_string();
        assert!(err.contains("image_2/999999.png"), "{err}");
        let err = load_frame(&sample_dir(), "000001", Some(Path::new("/no/such/results")))
            .unwrap_err()
            .to_string();
        assert!(err.contains("/no/such/results"), "{err}");
    }
}
