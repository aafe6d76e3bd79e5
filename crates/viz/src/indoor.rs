//! Pictures of SUN RGB-D scenes (the prepared layout of `fusiondet_sunrgbd`): a scene is
//! read as the frustum family reads it, a [`fusiondet_dataset::SensorFrame`] whose
//! "LiDAR" frame is upright depth and whose boxes are camera boxes
//! (`fusiondet_dataset::indoor`), so the street renderer draws it unchanged: the image
//! with the projected 3D boxes (P2 = M·Fᵀ projects as `sunrgbd::Calib::project` does)
//! above a top view of the room (upright x across, y ahead), the points in their camera
//! colour and the boxes labelled with their SUN RGB-D classes.

use crate::bev::BevRange;
use crate::error::VizError;
use crate::frame::{ClassNames, FrameView, RenderOptions};
use crate::load::result_file;
use fusiondet_dataset::DataError;
use fusiondet_dataset::indoor::{camera_box, load_scene};
use fusiondet_geometry::alpha_from_ry;
use fusiondet_kitti::{Object, ObjectClass};
use fusiondet_sunrgbd::SunRgbdDir;
use image::Rgb;
use std::path::Path;

/// Whether `dir` is a prepared SUN RGB-D directory (`splits/` and `points/`), as the
/// other commands tell it from a KITTI one.
pub fn is_sun_rgbd_dir(dir: &Path) -> bool {
    dir.join("splits").is_dir() && dir.join("points").is_dir()
}

/// Options suited to rooms: 0–8 m ahead (the indoor frustums' depth range) × ±5 m,
/// a 1 m grid, points two pixels wide.
pub fn indoor_render_options() -> RenderOptions {
    RenderOptions {
        bev_range: BevRange {
            forward: (0.0, 8.0),
            lateral: (-5.0, 5.0),
        },
        grid_step: 1.0,
        dont_care: false,
        ..RenderOptions::default()
    }
}

/// An upright-depth line (label or result) as the KITTI object the renderer draws.
fn drawn_object(o: &fusiondet_sunrgbd::Object) -> Object {
    let box3d = camera_box(&o.box3d);
    Object {
        class: ObjectClass::Misc,
        truncation: 0.0,
        occlusion: 0,
        alpha: alpha_from_ry(box3d.ry, box3d.x, box3d.z),
        bbox: o.bbox,
        box3d,
        score: o.score,
    }
}

/// Loads scene `id` of the prepared SUN RGB-D directory `root`: image, points (with
/// their colours), calibration and the labels of the ten evaluated classes (a directory
/// without `label/` gives no ground truth and a note). With `result_dir`, the scene's
/// result lines are the detections (every class written; a missing file gives a note).
pub fn load_indoor_scene(
    root: &Path,
    id: &str,
    result_dir: Option<&Path>,
) -> Result<FrameView, VizError> {
    let dir = SunRgbdDir::new(root);
    let image = fusiondet_sunrgbd::read_image(&dir.image(id))?;
    let mut notes = Vec::new();
    let has_labels = dir.label_dir().is_dir();
    if !has_labels {
        notes.push(format!("no label/ in {}: no ground truth", root.display()));
    }
    let frame = load_scene(&dir, id, has_labels).map_err(|e| match e {
        DataError::Format(e) => VizError::Format(e),
        DataError::Calib { message, .. } => VizError::Calib {
            path: dir.calib(id),
            message,
        },
        DataError::Data(message) => VizError::ResultDir {
            path: root.to_path_buf(),
            message,
        },
    })?;
    // The frame keeps each point's mean colour only; the picture wants all three.
    let point_colours: Vec<Rgb<u8>> = fusiondet_sunrgbd::read_points(&dir.points(id))?
        .iter()
        .map(|p| Rgb([p[3], p[4], p[5]].map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8)))
        .collect();
    let mut names = ClassNames {
        ground_truth: frame
            .classes
            .iter()
            .map(|c| c.as_str().to_string())
            .collect(),
        detections: Vec::new(),
    };
    let detections = match result_dir {
        None => None,
        Some(results) => {
            if !results.is_dir() {
                return Err(VizError::ResultDir {
                    path: results.to_path_buf(),
                    message: "result directory does not exist or is not a directory".into(),
                });
            }
            match result_file(results, id) {
                Some(path) => {
                    let lines = fusiondet_sunrgbd::read_results(&path)?;
                    names.detections = lines.iter().map(|o| o.class.clone()).collect();
                    Some(lines.iter().map(drawn_object).collect())
                }
                None => {
                    notes.push(format!(
                        "no result file for {id} in {}: ground truth only",
                        results.display()
                    ));
                    None
                }
            }
        }
    };
    Ok(FrameView {
        title: format!("scene {id}"),
        image,
        camera: frame.camera,
        points: frame.lidar,
        ground_truth: frame.objects,
        detections,
        notes,
        pseudo_points: None,
        depth: None,
        point_colours: Some(point_colours),
        class_names: Some(names),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::render_frame_with;
    use crate::style::{DETECTION, GT};
    use crate::testutil::count_colour;
    use std::path::PathBuf;

    fn fixture() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../sunrgbd/tests/data")
    }

    #[test]
    fn the_real_scene_is_drawn_with_its_boxes_and_coloured_points() {
        let view = load_indoor_scene(&fixture(), "000017", None).unwrap();
        assert_eq!(view.points.len(), 5000);
        assert_eq!(view.point_colours.as_ref().unwrap().len(), 5000);
        let names = &view.class_names.as_ref().unwrap().ground_truth;
        assert!(names.iter().any(|n| n == "bed"), "{names:?}");
        assert_eq!(
            view.label(crate::style::Source::GroundTruth, &view.ground_truth[0]),
            names[0]
        );
        let picture = render_frame_with(&view, &indoor_render_options());
        assert_eq!(picture.width(), view.image.width());
        // Image, legend and an 8 m × 10 m top view at the image's width.
        let bev_height = (view.image.width() as f64 * 0.8).round() as u32;
        assert!(picture.height() >= view.image.height() + bev_height);
        assert!(count_colour(&picture, GT) > 500);
        assert_eq!(count_colour(&picture, DETECTION), 0);
    }

    #[test]
    fn detections_are_read_from_result_lines_and_labelled_with_their_class() {
        let tmp = tempfile::tempdir().unwrap();
        let labels = fusiondet_sunrgbd::read_labels(&fixture().join("label/000017.txt")).unwrap();
        let results: Vec<_> = labels
            .into_iter()
            .filter(|o| o.class == "bed")
            .map(|mut o| {
                o.score = Some(0.75);
                o.box3d.centre[0] += 0.3;
                o
            })
            .collect();
        assert_eq!(results.len(), 1);
        fusiondet_sunrgbd::write_objects(&tmp.path().join("000017.txt"), &results).unwrap();
        let view = load_indoor_scene(&fixture(), "000017", Some(tmp.path())).unwrap();
        let detections = view.detections.as_ref().unwrap();
        assert_eq!(detections.len(), 1);
        assert_eq!(detections[0].score, Some(0.75));
        assert_eq!(
            view.label(crate::style::Source::Detection, &detections[0]),
            "bed 0.75"
        );
        let picture = render_frame_with(&view, &indoor_render_options());
        assert!(count_colour(&picture, DETECTION) > 200);

        let empty = tempfile::tempdir().unwrap();
        let view = load_indoor_scene(&fixture(), "000017", Some(empty.path())).unwrap();
        assert!(view.detections.is_none());
        assert!(view.notes[0].contains("no result file"), "{:?}", view.notes);
    }

    #[test]
    fn a_kitti_directory_is_not_a_sun_rgbd_one() {
        assert!(!is_sun_rgbd_dir(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample")
        ));
        assert!(is_sun_rgbd_dir(&fixture()));
    }
}
