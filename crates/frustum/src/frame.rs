//! One KITTI frame prepared for frustum extraction: the LiDAR points projected into
//! the image once (rectified camera coordinates and pixels), so that every 2D box of
//! the frame is only a filter over these arrays.

use crate::error::{FrustumError, Result};
use fusiondet_geometry::CameraModel;
use fusiondet_kitti::{
    Calib, FrameDir, LidarPoint, Object, read_calib, read_objects, read_velodyne,
};
use std::path::Path;
use std::sync::Arc;

/// KITTI's usual image size, used when a frame has no readable `image_2` PNG.
pub const DEFAULT_IMAGE_SIZE: [f64; 2] = [1242.0, 375.0];

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

/// A frame ready for frustum extraction.
#[derive(Debug, Clone)]
pub struct Frame {
    pub id: String,
    pub camera: CameraModel,
    /// Image width and height in pixels; 2D boxes are clipped to it.
    pub image_size: [f64; 2],
    pub cloud: ProjectedCloud,
    /// Ground truth (empty for detection-only frames).
    pub objects: Vec<Object>,
}

impl Frame {
    pub fn new(
        id: &str,
        calib: &Calib,
        lidar: &[LidarPoint],
        image_size: [f64; 2],
        objects: Vec<Object>,
    ) -> Result<Frame> {
        let camera = CameraModel::from_calib(calib).map_err(|message| FrustumError::Calib {
            frame: id.to_string(),
            message,
        })?;
        let cloud = ProjectedCloud::new(lidar, &camera, image_size);
        Ok(Frame {
            id: id.to_string(),
            camera,
            image_size,
            cloud,
            objects,
        })
    }

    /// Reads `velodyne`, `calib` and, when `with_labels`, `label_2` of frame `id`. The
    /// image size comes from the `image_2` PNG header when the file exists (only its
    /// first 24 bytes are read), else [`DEFAULT_IMAGE_SIZE`].
    pub fn load(dir: &FrameDir, id: &str, with_labels: bool) -> Result<Frame> {
        let calib = read_calib(&dir.calib(id))?;
        let lidar = read_velodyne(&dir.velodyne(id))?;
        let objects = if with_labels {
            read_objects(&dir.label(id))?
        } else {
            Vec::new()
        };
        let image_size = png_size(&dir.image(id)).unwrap_or(DEFAULT_IMAGE_SIZE);
        Frame::new(id, &calib, &lidar, image_size, objects)
    }
}

/// Width and height from a PNG's IHDR chunk, or `None` if the file is missing or not a PNG.
pub fn png_size(path: &Path) -> Option<[f64; 2]> {
    use std::io::Read;
    let mut head = [0u8; 24];
    std::fs::File::open(path).ok()?.read_exact(&mut head).ok()?;
    if head[..8] != *b"\x89PNG\r\n\x1a\n" || head[12..16] != *b"IHDR" {
        return None;
    }
    let w = u32::from_be_bytes([head[16], head[17], head[18], head[19]]);
    let h = u32::from_be_bytes([head[20], head[21], head[22], head[23]]);
    (w > 0 && h > 0).then_some([w as f64, h as f64])
}

/// Where a data set gets its frames from, by index.
pub trait FrameSource: Sync {
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    fn frame_id(&self, index: usize) -> &str;
    fn frame(&self, index: usize) -> Result<Arc<Frame>>;
    /// The index of a frame id, if the source holds it.
    fn index_of(&self, id: &str) -> Option<usize> {
        (0..self.len()).find(|&i| self.frame_id(i) == id)
    }
}

/// All frames held in memory (about 40 bytes per in-image point: ~0.8 MB per KITTI frame).
#[derive(Debug, Clone, Default)]
pub struct InMemoryFrames {
    frames: Vec<Arc<Frame>>,
}

impl InMemoryFrames {
    pub fn new(frames: Vec<Frame>) -> Self {
        InMemoryFrames {
            frames: frames.into_iter().map(Arc::new).collect(),
        }
    }

    /// Loads the frames in parallel; fails on the first unreadable one (in id order).
    pub fn load(dir: &FrameDir, ids: &[String], with_labels: bool) -> Result<Self> {
        use rayon::prelude::*;
        let frames = ids
            .par_iter()
            .map(|id| Frame::load(dir, id, with_labels))
            .collect::<Result<Vec<_>>>()?;
        Ok(InMemoryFrames::new(frames))
    }
}

impl FrameSource for InMemoryFrames {
    fn len(&self) -> usize {
        self.frames.len()
    }
    fn frame_id(&self, index: usize) -> &str {
        &self.frames[index].id
    }
    fn frame(&self, index: usize) -> Result<Arc<Frame>> {
        Ok(self.frames[index].clone())
    }
    fn index_of(&self, id: &str) -> Option<usize> {
        self.frames.iter().position(|f| f.id == id)
    }
}

/// Frames read from disk on every request (nothing held; slower).
#[derive(Debug, Clone)]
pub struct DiskFrames {
    pub dir: FrameDir,
    pub ids: Vec<String>,
    pub with_labels: bool,
}

impl FrameSource for DiskFrames {
    fn len(&self) -> usize {
        self.ids.len()
    }
    fn frame_id(&self, index: usize) -> &str {
        &self.ids[index]
    }
    fn frame(&self, index: usize) -> Result<Arc<Frame>> {
        Frame::load(&self.dir, &self.ids[index], self.with_labels).map(Arc::new)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_data::sample_dir;

    #[test]
    fn projection_keeps_only_points_in_the_image() {
        let f = Frame::load(&sample_dir(), "000003", true).unwrap();
        assert_eq!(f.image_size, [1242.0, 375.0]);
        assert!(f.cloud.len() > 10_000, "{}", f.cloud.len());
        for (r, uv) in f.cloud.rect.iter().zip(&f.cloud.uv) {
            assert!(r[2] > NEAR_DEPTH);
            assert!((0.0..1242.0).contains(&uv[0]) && (0.0..375.0).contains(&uv[1]));
            let (u, v, _) = f.camera.rect_to_image(*r);
            assert!((u - uv[0]).abs() < 1e-9 && (v - uv[1]).abs() < 1e-9);
        }
        // A point behind the camera and one far outside the image are dropped.
        let calib = read_calib(&sample_dir().calib("000003")).unwrap();
        let g = Frame::new(
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
        let err = Frame::load(&sample_dir(), "999999", true)
            .unwrap_err()
            .to_string();
        assert!(err.contains("999999"), "{err}");
    }
}
