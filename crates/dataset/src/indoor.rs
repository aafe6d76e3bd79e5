//! SUN RGB-D scenes as [`SensorFrame`]s, so that the frustum family runs on them
//! unchanged.
//!
//! A scene's points are upright depth (x right, y forward, z up; the camera at the
//! origin, gravity along −z). They become the frame's "LiDAR" points, and its camera
//! frame is the gravity-aligned camera: x_c = x, y_c = −z, z_c = y (the rotation
//! `fusiondet_sunrgbd::calib::DEPTH_TO_CAMERA`, F). The scene's depth-to-image matrix M
//! becomes P2 = [M·Fᵀ | 0] with R0_rect = I and Tr_velo_to_cam = [F | 0], so that
//! P2 · F · p = M · p projects exactly as the scene's calibration does. Since y_c points
//! down along gravity, a KITTI camera box's rotation about y is a rotation about the
//! vertical, as in KITTI.
//!
//! Boxes ([`camera_box`], [`upright_box`]): `Box3d`'s l runs along its heading (camera x
//! at ry = 0), w along camera z, h vertical, and (x, y, z) is the bottom face's centre;
//! an `UprightBox`'s dx runs along (cos yaw, sin yaw). Camera x at ry rotates to
//! (cos ry, −sin ry) in (x_c, z_c) = (x, y), so l = dx, w = dy, h = dz and ry = −yaw.

use crate::classes::Class;
use crate::error::{DataError, Result};
use crate::frame::{DerivedFrame, InMemoryFrames, SensorFrame};
use fusiondet_geometry::{Box3d, alpha_from_ry, normalize_angle};
use fusiondet_kitti::{Calib, LidarPoint, Object, ObjectClass};
use fusiondet_sunrgbd::calib::DEPTH_TO_CAMERA;
use fusiondet_sunrgbd::{SunRgbdDir, UprightBox};
use std::path::Path;

/// The image size of a scene without a readable `image/<id>.jpg` (SUN RGB-D's Kinect v2
/// and RealSense frames are 730×530 after its own cropping).
pub const DEFAULT_INDOOR_IMAGE_SIZE: [f64; 2] = [730.0, 530.0];

/// Upright depth → camera (x right, y down, z forward).
pub fn upright_to_camera(p: [f64; 3]) -> [f64; 3] {
    [p[0], -p[2], p[1]]
}

/// Camera → upright depth (the inverse of [`upright_to_camera`]).
pub fn camera_to_upright(q: [f64; 3]) -> [f64; 3] {
    [q[0], q[2], -q[1]]
}

/// An upright-depth box in `Box3d`'s camera convention (module documentation).
pub fn camera_box(b: &UprightBox) -> Box3d {
    let [cx, cy, cz] = b.centre;
    let [dx, dy, dz] = b.size;
    Box3d {
        l: dx,
        w: dy,
        h: dz,
        x: cx,
        // The bottom face (z = cz − dz/2) at camera y = −z.
        y: -(cz - 0.5 * dz),
        z: cy,
        ry: normalize_angle(-b.yaw),
    }
}

/// A camera box in upright depth (the inverse of [`camera_box`], yaw in (−π, π]).
pub fn upright_box(b: &Box3d) -> UprightBox {
    UprightBox {
        centre: [b.x, b.z, -b.y + 0.5 * b.h],
        size: [b.l, b.w, b.h],
        yaw: normalize_angle(-b.ry),
    }
}

/// The KITTI calibration that projects as the scene's depth-to-image matrix does, with
/// upright depth as its "LiDAR" frame (module documentation).
pub fn kitti_calib(calib: &fusiondet_sunrgbd::Calib) -> Calib {
    let m = &calib.depth_to_image;
    let f = &DEPTH_TO_CAMERA;
    // M · Fᵀ (F is a rotation: Fᵀ = F⁻¹).
    let p2: [[f64; 4]; 3] = std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            if j == 3 {
                0.0
            } else {
                (0..3).map(|k| m[i][k] * f[j][k]).sum()
            }
        })
    });
    let tr: [[f64; 4]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| if j == 3 { 0.0 } else { f[i][j] }));
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    Calib {
        p: [p2; 4],
        r0_rect: identity,
        tr_velo_to_cam: tr,
        tr_imu_to_velo: std::array::from_fn(|i| {
            std::array::from_fn(|j| if i == j { 1.0 } else { 0.0 })
        }),
    }
}

/// A ground-truth line as the frustum family reads it: a KITTI object of class `Misc`
/// (KITTI's code never evaluates it) with the box in camera coordinates; the SUN RGB-D
/// class goes beside it in [`SensorFrame::classes`].
fn camera_object(o: &fusiondet_sunrgbd::Object) -> Object {
    let box3d = camera_box(&o.box3d);
    Object {
        class: ObjectClass::Misc,
        truncation: 0.0,
        occlusion: 0,
        alpha: alpha_from_ry(box3d.ry, box3d.x, box3d.z),
        bbox: o.bbox,
        box3d,
        score: None,
    }
}

/// Width and height from an image file's header (JPEG or PNG); `None` where the scene has
/// no image. One that is there but cannot be read (a pipe or a device in its place, a file
/// that is no image) is an error, never waited on or passed over.
fn image_size(path: &Path) -> Result<Option<[f64; 2]>> {
    if std::fs::symlink_metadata(path).is_err() {
        return Ok(None);
    }
    let (w, h) = fusiondet_kitti::image::image_size(path)?;
    Ok((w > 0 && h > 0).then_some([w as f64, h as f64]))
}

/// Reads scene `id` of a prepared SUN RGB-D directory as a frame: its points (colour as
/// the "intensity", the mean of r, g, b), calibration, image size (the JPEG header, else
/// [`DEFAULT_INDOOR_IMAGE_SIZE`]) and, when `with_labels`, the objects of the ten
/// evaluated classes (SUN RGB-D annotates many more; no detector learns them).
pub fn load_scene(dir: &SunRgbdDir, id: &str, with_labels: bool) -> Result<SensorFrame> {
    let points = fusiondet_sunrgbd::read_points(&dir.points(id))?;
    let calib = kitti_calib(&fusiondet_sunrgbd::read_calib(&dir.calib(id))?);
    let lidar: Vec<LidarPoint> = points
        .iter()
        .map(|p| [p[0], p[1], p[2], (p[3] + p[4] + p[5]) / 3.0])
        .collect();
    let (objects, classes): (Vec<Object>, Vec<Class>) = if with_labels {
        fusiondet_sunrgbd::read_labels(&dir.label(id))?
            .iter()
            .filter_map(|o| Some((camera_object(o), Class::SunRgbd(o.sun_class()?))))
            .unzip()
    } else {
        (Vec::new(), Vec::new())
    };
    let image = dir.image(id);
    let size = image_size(&image)?.unwrap_or(DEFAULT_INDOOR_IMAGE_SIZE);
    let mut frame = SensorFrame::new(id, calib, lidar, size, objects)?;
    frame.classes = classes;
    frame.image_path = image.is_file().then_some(image);
    Ok(frame)
}

/// The ids of a SUN RGB-D split (`splits/<split>.txt`; the first `max_frames`, 0 = all).
pub fn scene_ids(root: &Path, split: &str, max_frames: usize) -> Result<Vec<String>> {
    let dir = SunRgbdDir::new(root);
    if !dir.root.join("splits").is_dir() {
        let hint = if root.join("training").is_dir() || root.join("ImageSets").is_dir() {
            " (it looks like a KITTI directory: this model was configured for SUN RGB-D, \
             `[dataset] format = \"sun_rgbd\"`)"
        } else {
            ""
        };
        return Err(DataError::Data(format!(
            "{} is no prepared SUN RGB-D directory: it has no splits/ folder{hint}",
            root.display()
        )));
    }
    let mut ids = dir.split_ids(split)?;
    if max_frames > 0 {
        ids.truncate(max_frames);
    }
    if ids.is_empty() {
        return Err(DataError::Data(format!(
            "split `{split}` of {} lists no scenes",
            root.display()
        )));
    }
    Ok(ids)
}

/// Loads scenes into memory in parallel, in the family's derived form; fails on the
/// first unreadable one (in id order).
pub fn load_scenes<F: DerivedFrame>(
    root: &Path,
    ids: &[String],
    with_labels: bool,
) -> Result<InMemoryFrames<F>> {
    use rayon::prelude::*;
    let dir = SunRgbdDir::new(root);
    let frames = ids
        .par_iter()
        .map(|id| F::derive(load_scene(&dir, id, with_labels)?))
        .collect::<Result<Vec<_>>>()?;
    Ok(InMemoryFrames::new(frames))
}

/// The scenes of a split in memory (see [`scene_ids`], [`load_scenes`]).
pub fn load_scene_split<F: DerivedFrame>(
    root: &Path,
    split: &str,
    max_frames: usize,
    with_labels: bool,
) -> Result<InMemoryFrames<F>> {
    load_scenes(root, &scene_ids(root, split, max_frames)?, with_labels)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Sampler;
    use fusiondet_geometry::count_points_in_box;
    use fusiondet_sunrgbd::SunClass;
    use std::f64::consts::PI;

    fn fixture() -> SunRgbdDir {
        SunRgbdDir::new(Path::new(env!("CARGO_MANIFEST_DIR")).join("../sunrgbd/tests/data"))
    }

    fn random_box(rng: &mut Sampler) -> UprightBox {
        UprightBox {
            centre: [
                rng.range(-3.0, 3.0),
                rng.range(0.5, 8.0),
                rng.range(-1.5, 1.0),
            ],
            size: [
                rng.range(0.2, 2.5),
                rng.range(0.2, 2.5),
                rng.range(0.2, 2.0),
            ],
            yaw: rng.range(-PI, PI),
        }
    }

    #[test]
    fn boxes_round_trip_and_keep_their_corners() {
        let mut rng = Sampler::new(11);
        for _ in 0..500 {
            let b = random_box(&mut rng);
            let c = camera_box(&b);
            let back = upright_box(&c);
            for k in 0..3 {
                assert!((back.centre[k] - b.centre[k]).abs() < 1e-12);
                assert_eq!(back.size[k], b.size[k]);
            }
            assert!(normalize_angle(back.yaw - b.yaw).abs() < 1e-12);
            // The same eight corners, whichever way they are numbered.
            let up: Vec<[f64; 3]> = b.corners().iter().map(|&p| upright_to_camera(p)).collect();
            for q in fusiondet_geometry::corners(&c) {
                assert!(
                    up.iter()
                        .any(|p| (0..3).all(|k| (p[k] - q[k]).abs() < 1e-9)),
                    "{q:?} is no corner of {b:?}"
                );
            }
            // And l runs along the heading: the +l face centre is the +dx face centre.
            let (s, co) = b.yaw.sin_cos();
            let face = [
                b.centre[0] + 0.5 * b.size[0] * co,
                b.centre[1] + 0.5 * b.size[0] * s,
                b.centre[2],
            ];
            let cam_face = [
                c.x + 0.5 * c.l * libm::cos(c.ry),
                c.y - 0.5 * c.h,
                c.z - 0.5 * c.l * libm::sin(c.ry),
            ];
            let f = upright_to_camera(face);
            assert!((0..3).all(|k| (f[k] - cam_face[k]).abs() < 1e-9));
        }
    }

    #[test]
    fn points_in_a_box_stay_in_it() {
        let mut rng = Sampler::new(5);
        for _ in 0..100 {
            let b = random_box(&mut rng);
            let c = camera_box(&b);
            let pts: Vec<[f64; 3]> = (0..200)
                .map(|_| {
                    [
                        b.centre[0] + rng.range(-1.5, 1.5),
                        b.centre[1] + rng.range(-1.5, 1.5),
                        b.centre[2] + rng.range(-1.2, 1.2),
                    ]
                })
                .collect();
            let inside = pts.iter().filter(|&&p| b.contains(p)).count();
            let cam: Vec<[f64; 3]> = pts.iter().map(|&p| upright_to_camera(p)).collect();
            assert_eq!(count_points_in_box(&c, &cam), inside);
            for p in &pts {
                let q = camera_to_upright(upright_to_camera(*p));
                assert_eq!(q, *p);
            }
        }
    }

    #[test]
    fn the_camera_projects_as_the_scene_calibration() {
        let sun = fusiondet_sunrgbd::read_calib(&fixture().calib("000017")).unwrap();
        let camera = kitti_calib(&sun).camera_model().unwrap();
        let points = fusiondet_sunrgbd::read_points(&fixture().points("000017")).unwrap();
        for p in points.iter().step_by(97) {
            let p = [p[0] as f64, p[1] as f64, p[2] as f64];
            let [u, v] = sun.project(p).unwrap();
            let r = camera.velo_to_rect(p);
            assert_eq!(r, upright_to_camera(p));
            let (cu, cv, _) = camera.rect_to_image(r);
            assert!((cu - u).abs() < 1e-9 && (cv - v).abs() < 1e-9);
        }
    }

    /// A scene whose image is a link to `/dev/zero` is an error naming the image: it was read
    /// for gigabytes and then passed over, with a default size.
    #[cfg(unix)]
    #[test]
    fn a_device_in_the_images_place_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let from = fixture().root;
        for sub in ["calib", "label", "points", "splits"] {
            std::fs::create_dir_all(dir.path().join(sub)).unwrap();
            for entry in std::fs::read_dir(from.join(sub)).unwrap() {
                let path = entry.unwrap().path();
                std::fs::copy(&path, dir.path().join(sub).join(path.file_name().unwrap())).unwrap();
            }
        }
        std::fs::create_dir_all(dir.path().join("image")).unwrap();
        std::os::unix::fs::symlink("/dev/zero", dir.path().join("image/000017.jpg")).unwrap();
        let err = load_scene(&SunRgbdDir::new(dir.path()), "000017", true)
            .unwrap_err()
            .to_string();
        assert!(err.contains("000017.jpg: not a regular file"), "{err}");
    }

    #[test]
    fn the_real_scene_is_a_frame_with_its_bed_and_night_stand() {
        let f = load_scene(&fixture(), "000017", true).unwrap();
        assert_eq!(f.image_size, [730.0, 530.0]);
        assert_eq!(f.lidar.len(), 5000);
        assert_eq!(
            f.classes,
            [
                Class::SunRgbd(SunClass::NightStand),
                Class::SunRgbd(SunClass::Bed)
            ]
        );
        let labels = fusiondet_sunrgbd::read_labels(&fixture().label("000017")).unwrap();
        let rect: Vec<[f64; 3]> = f
            .lidar
            .iter()
            .map(|p| {
                f.camera
                    .velo_to_rect([p[0] as f64, p[1] as f64, p[2] as f64])
            })
            .collect();
        for (o, l) in f.objects.iter().zip(&labels) {
            assert_eq!(o.bbox, l.bbox);
            let up: Vec<[f64; 3]> = f
                .lidar
                .iter()
                .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
                .collect();
            let n = up.iter().filter(|&&p| l.box3d.contains(p)).count();
            assert_eq!(count_points_in_box(&o.box3d, &rect), n);
            assert!(n > 20, "{} has {n} points", l.class);
        }
        let unlabelled = load_scene(&fixture(), "000017", false).unwrap();
        assert!(unlabelled.objects.is_empty() && unlabelled.classes.is_empty());
    }

    #[test]
    fn a_kitti_directory_is_named_as_such() {
        let kitti = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample");
        let err = scene_ids(&kitti, "val", 0).unwrap_err().to_string();
        assert!(err.contains("KITTI"), "{err}");
        assert_eq!(
            scene_ids(&fixture().root, "val", 0).unwrap(),
            ["000017".to_string()]
        );
    }
}
