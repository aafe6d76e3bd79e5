//! A frame prepared for frustum extraction: the LiDAR points projected into
//! the image once (rectified camera coordinates and pixels), so that every 2D box of
//! the frame is only a filter over these arrays.

use crate::error::Result;
use fusiondet_dataset::{Class, DerivedFrame, SensorFrame};
use fusiondet_geometry::CameraModel;
use fusiondet_kitti::{Calib, FrameDir, LidarPoint, Object};

pub use fusiondet_dataset::{DEFAULT_IMAGE_SIZE, FrameSource, png_size};

/// Points closer than this (rectified depth, metres) are not projected.
pub const NEAR_DEPTH: f64 = 0.1;

/// The LiDAR points of a frame that project into the image, in front of the camera.
#[derive(Debug, Clone, Default)]
pub struct ProjectedCloud {
    /// Rectified camera coordinates (x right, y down, z forward).
    pub rect: Vec<[f64; 3]>,
    /// Pixel coordinates (u, v) in the P2 image.
    pub uv: Vec<[f64; 2]>,
}

impl ProjectedCloud {
    /// Transforms every point once; keeps those with rectified depth above
    /// [`NEAR_DEPTH`] that project into the `width`×`height` image.
    pub fn new(lidar: &[LidarPoint], camera: &CameraModel, image_size: [f64; 2]) -> Self {
        // Plain arrays: nalgebra's checked indexing in this loop costs more than the maths.
        let t: [[f64; 4]; 3] =
            std::array::from_fn(|r| std::array::from_fn(|c| camera.velo_to_rect[(r, c)]));
        let p: [[f64; 4]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| camera.p2[(r, c)]));
        let (w, h) = (image_size[0], image_size[1]);
        let mut rect = Vec::with_capacity(lidar.len());
        let mut uv = Vec::with_capacity(lidar.len());
        for q in lidar {
            let (x, y, z) = (q[0] as f64, q[1] as f64, q[2] as f64);
            let r = t.map(|row| row[0] * x + row[1] * y + row[2] * z + row[3]);
            if r[2] <= NEAR_DEPTH {
                continue;
            }
            let hom = p.map(|row| row[0] * r[0] + row[1] * r[1] + row[2] * r[2] + row[3]);
            if hom[2] <= 0.0 {
                continue;
            }
            let (u, v) = (hom[0] / hom[2], hom[1] / hom[2]);
            if (0.0..w).contains(&u) && (0.0..h).contains(&v) {
                rect.push(r);
                uv.push([u, v]);
            }
        }
        // A full scan keeps about a sixth of its points: hand the rest back.
        rect.shrink_to_fit();
        uv.shrink_to_fit();
        ProjectedCloud { rect, uv }
    }

    pub fn len(&self) -> usize {
        self.rect.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rect.is_empty()
    }
}

/// A frame ready for frustum extraction: what the frustum family keeps of a
/// [`SensorFrame`] (the points in the image, projected once; no intensity, no image).
#[derive(Debug, Clone)]
pub struct ProjectedFrame {
    pub id: String,
    pub camera: CameraModel,
    /// Image width and height in pixels; 2D boxes are clipped to it.
    pub image_size: [f64; 2],
    pub cloud: ProjectedCloud,
    /// Ground truth (empty for detection-only frames).
    pub objects: Vec<Object>,
    /// The class of each of `objects` (see [`SensorFrame::classes`]).
    pub classes: Vec<Class>,
}

impl ProjectedFrame {
    /// Projects an in-memory scan (tests, simulated frames).
    pub fn new(
        id: &str,
        calib: &Calib,
        lidar: &[LidarPoint],
        image_size: [f64; 2],
        objects: Vec<Object>,
    ) -> Result<ProjectedFrame> {
        let frame = SensorFrame::new(id, calib.clone(), lidar.to_vec(), image_size, objects)?;
        Ok(Self::project(frame))
    }

    /// Reads frame `id` (see [`SensorFrame::load`]) and projects it.
    pub fn load(dir: &FrameDir, id: &str, with_labels: bool) -> Result<ProjectedFrame> {
        Ok(Self::project(SensorFrame::load(dir, id, with_labels)?))
    }

    fn project(frame: SensorFrame) -> ProjectedFrame {
        let cloud = ProjectedCloud::new(&frame.lidar, &frame.camera, frame.image_size);
        ProjectedFrame {
            id: frame.id,
            camera: frame.camera,
            image_size: frame.image_size,
            cloud,
            objects: frame.objects,
            classes: frame.classes,
        }
    }
}

impl DerivedFrame for ProjectedFrame {
    fn derive(frame: SensorFrame) -> fusiondet_dataset::Result<Self> {
        Ok(Self::project(frame))
    }
    fn id(&self) -> &str {
        &self.id
    }
}

/// A source of the frustum family's frames.
pub trait FrustumFrames: FrameSource<Frame = ProjectedFrame> {}
impl<S: FrameSource<Frame = ProjectedFrame>> FrustumFrames for S {}

/// The frustum family's frames held in memory (about 40 bytes per in-image point:
/// ~0.8 MB per KITTI frame, a sixth of the full scan's).
pub type InMemoryFrames = fusiondet_dataset::InMemoryFrames<ProjectedFrame>;

/// The frames of a split (the first `max_frames`; 0 = all) in the frustum family's form.
pub fn load_split(
    data_dir: &std::path::Path,
    split: &str,
    max_frames: usize,
    with_labels: bool,
) -> Result<InMemoryFrames> {
    Ok(fusiondet_dataset::load_split(
        data_dir,
        split,
        max_frames,
        with_labels,
    )?)
}

/// The frustum family's frames read from disk on every request.
pub type DiskFrames = fusiondet_dataset::DiskFrames<ProjectedFrame>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_data::sample_dir;

    #[test]
    fn projection_keeps_only_points_in_the_image() {
        let f = ProjectedFrame::load(&sample_dir(), "000003", true).unwrap();
        assert_eq!(f.image_size, [1242.0, 375.0]);
        assert!(f.cloud.len() > 10_000, "{}", f.cloud.len());
        for (r, uv) in f.cloud.rect.iter().zip(&f.cloud.uv) {
            assert!(r[2] > NEAR_DEPTH);
            assert!((0.0..1242.0).contains(&uv[0]) && (0.0..375.0).contains(&uv[1]));
            let (u, v, _) = f.camera.rect_to_image(*r);
            assert!((u - uv[0]).abs() < 1e-9 && (v - uv[1]).abs() < 1e-9);
        }
        // A point behind the camera and one far outside the image are dropped.
        let calib = fusiondet_kitti::read_calib(&sample_dir().calib("000003")).unwrap();
        let g = ProjectedFrame::new(
            "x",
            &calib,
            &[
                [-10.0, 0.0, 0.0, 0.0],
                [10.0, 30.0, 0.0, 0.0],
                [10.0, 0.0, -1.0, 0.0],
            ],
            [1242.0, 375.0],
            vec![],
        )
        .unwrap();
        assert_eq!(g.cloud.len(), 1);
    }

    #[test]
    fn missing_files_are_errors_naming_the_file() {
        let err = ProjectedFrame::load(&sample_dir(), "999999", true)
            .unwrap_err()
            .to_string();
        assert!(err.contains("999999"), "{err}");
    }
}
