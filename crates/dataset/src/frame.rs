//! One frame as the sensors saw it, and where frames come from.

use crate::classes::Class;
use crate::error::{DataError, Result};
use fusiondet_geometry::CameraModel;
use fusiondet_kitti::{
    Calib, FrameDir, LidarPoint, Object, read_calib, read_objects, read_velodyne,
};
use std::marker::PhantomData;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// KITTI's usual image size, used when a frame has no readable `image_2` PNG.
pub const DEFAULT_IMAGE_SIZE: [f64; 2] = [1242.0, 375.0];

/// One frame: the full LiDAR scan (x, y, z, intensity in the LiDAR frame, every point
/// of the sweep), the camera model, the image (its size always; its pixels on demand)
/// and the ground truth.
#[derive(Debug, Clone)]
pub struct SensorFrame {
    pub id: String,
    pub calib: Calib,
    pub camera: CameraModel,
    pub lidar: Vec<LidarPoint>,
    /// Image width and height in pixels.
    pub image_size: [f64; 2],
    /// Where the image's pixels are, when the frame came from disk.
    pub image_path: Option<PathBuf>,
    /// Ground truth (empty for detection-only frames).
    pub objects: Vec<Object>,
    /// The class of each of `objects`, as its format spells it: KITTI's own for KITTI
    /// frames; for SUN RGB-D frames (whose `objects` are KITTI lines with class `Misc`,
    /// which KITTI's code does not evaluate) the SUN RGB-D class.
    pub classes: Vec<Class>,
}

impl SensorFrame {
    /// A frame from in-memory parts (simulated or converted data).
    pub fn new(
        id: &str,
        calib: Calib,
        lidar: Vec<LidarPoint>,
        image_size: [f64; 2],
        objects: Vec<Object>,
    ) -> Result<SensorFrame> {
        let camera = calib.camera_model().map_err(|message| DataError::Calib {
            frame: id.to_string(),
            message,
        })?;
        Ok(SensorFrame {
            id: id.to_string(),
            calib,
            camera,
            lidar,
            image_size,
            image_path: None,
            classes: objects.iter().map(|o| Class::Kitti(o.class)).collect(),
            objects,
        })
    }

    /// Reads `velodyne`, `calib` and, when `with_labels`, `label_2` of frame `id`. The
    /// image size comes from the `image_2` PNG header when the file exists (only its
    /// first 24 bytes are read), else [`DEFAULT_IMAGE_SIZE`].
    pub fn load(dir: &FrameDir, id: &str, with_labels: bool) -> Result<SensorFrame> {
        let calib = read_calib(&dir.calib(id))?;
        let lidar = read_velodyne(&dir.velodyne(id))?;
        let objects = if with_labels {
            read_objects(&dir.label(id))?
        } else {
            Vec::new()
        };
        let image = dir.image(id);
        let image_size = present_png_size(&image)?.unwrap_or(DEFAULT_IMAGE_SIZE);
        let mut frame = SensorFrame::new(id, calib, lidar, image_size, objects)?;
        frame.image_path = image.is_file().then_some(image);
        Ok(frame)
    }

    /// The camera image, read now (frames keep only its path).
    pub fn image(&self) -> Result<image::RgbImage> {
        let path = self.image_path.as_ref().ok_or_else(|| {
            DataError::Data(format!(
                "frame {}: no image_2 PNG was found for it (it was read without one, or \
                 built in memory)",
                self.id
            ))
        })?;
        Ok(fusiondet_kitti::image::read_image(path)?)
    }
}

/// The points of one LiDAR scan (`velodyne` .bin) in the rectified camera frame of its
/// calibration (`calib`): what counting points in labelled boxes needs, for scans and
/// calibrations kept in directories of their own.
pub fn scan_in_rect(velodyne: &Path, calib: &Path) -> Result<Vec<[f64; 3]>> {
    let camera = read_calib(calib)?
        .camera_model()
        .map_err(|message| DataError::Calib {
            frame: calib.display().to_string(),
            message,
        })?;
    Ok(read_velodyne(velodyne)?
        .iter()
        .map(|p| camera.velo_to_rect([p[0] as f64, p[1] as f64, p[2] as f64]))
        .collect())
}

/// Width and height from a PNG's IHDR chunk, or `None` if the file is missing, cannot be
/// read (a pipe or device in its place is passed over, never waited on) or is not a PNG.
pub fn png_size(path: &Path) -> Option<[f64; 2]> {
    present_png_size(path).ok().flatten()
}

/// [`png_size`] for a frame, which may come without its image: `None` where it is missing
/// or not a PNG, but an error where it is there and is a pipe, a device or a folder.
fn present_png_size(path: &Path) -> Result<Option<[f64; 2]>> {
    use std::io::Read;
    if std::fs::symlink_metadata(path).is_err() {
        return Ok(None);
    }
    let (mut file, _) =
        fusiondet_kitti::error::open_regular(path, fusiondet_kitti::error::MAX_IMAGE_BYTES)?;
    let mut head = [0u8; 24];
    if file.read_exact(&mut head).is_err()
        || head[..8] != *b"\x89PNG\r\n\x1a\n"
        || head[12..16] != *b"IHDR"
    {
        return Ok(None);
    }
    let w = u32::from_be_bytes([head[16], head[17], head[18], head[19]]);
    let h = u32::from_be_bytes([head[20], head[21], head[22], head[23]]);
    Ok((w > 0 && h > 0).then_some([w as f64, h as f64]))
}

/// What a detector family keeps of a [`SensorFrame`]: the frustum family keeps only
/// the points that project into the image; a voxel family may keep the whole frame.
pub trait DerivedFrame: Sized + Send + Sync {
    fn derive(frame: SensorFrame) -> Result<Self>;
    fn id(&self) -> &str;
}

impl DerivedFrame for SensorFrame {
    fn derive(frame: SensorFrame) -> Result<Self> {
        Ok(frame)
    }
    fn id(&self) -> &str {
        &self.id
    }
}

/// Where a data set gets its frames from, by index.
pub trait FrameSource: Sync {
    type Frame: DerivedFrame;
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    fn frame_id(&self, index: usize) -> &str;
    fn frame(&self, index: usize) -> Result<Arc<Self::Frame>>;
    /// The index of a frame id, if the source holds it.
    fn index_of(&self, id: &str) -> Option<usize> {
        (0..self.len()).find(|&i| self.frame_id(i) == id)
    }
}

/// All frames held in memory, in the family's derived form.
#[derive(Debug)]
pub struct InMemoryFrames<F> {
    frames: Vec<Arc<F>>,
}

impl<F> Clone for InMemoryFrames<F> {
    fn clone(&self) -> Self {
        InMemoryFrames {
            frames: self.frames.clone(),
        }
    }
}

impl<F> Default for InMemoryFrames<F> {
    fn default() -> Self {
        InMemoryFrames { frames: Vec::new() }
    }
}

impl<F: DerivedFrame> InMemoryFrames<F> {
    pub fn new(frames: Vec<F>) -> Self {
        InMemoryFrames {
            frames: frames.into_iter().map(Arc::new).collect(),
        }
    }

    /// Loads the frames in parallel; fails on the first unreadable one (in id order).
    pub fn load(dir: &FrameDir, ids: &[String], with_labels: bool) -> Result<Self> {
        use rayon::prelude::*;
        let frames = ids
            .par_iter()
            .map(|id| F::derive(SensorFrame::load(dir, id, with_labels)?))
            .collect::<Result<Vec<_>>>()?;
        Ok(InMemoryFrames::new(frames))
    }
}

impl<F: DerivedFrame> FrameSource for InMemoryFrames<F> {
    type Frame = F;
    fn len(&self) -> usize {
        self.frames.len()
    }
    fn frame_id(&self, index: usize) -> &str {
        self.frames[index].id()
    }
    fn frame(&self, index: usize) -> Result<Arc<F>> {
        Ok(self.frames[index].clone())
    }
    fn index_of(&self, id: &str) -> Option<usize> {
        self.frames.iter().position(|f| f.id() == id)
    }
}

/// Frames read from disk on every request (nothing held; slower).
#[derive(Debug)]
pub struct DiskFrames<F> {
    pub dir: FrameDir,
    pub ids: Vec<String>,
    pub with_labels: bool,
    derived: PhantomData<fn() -> F>,
}

impl<F> Clone for DiskFrames<F> {
    fn clone(&self) -> Self {
        DiskFrames {
            dir: self.dir.clone(),
            ids: self.ids.clone(),
            with_labels: self.with_labels,
            derived: PhantomData,
        }
    }
}

impl<F> DiskFrames<F> {
    pub fn new(dir: FrameDir, ids: Vec<String>, with_labels: bool) -> Self {
        DiskFrames {
            dir,
            ids,
            with_labels,
            derived: PhantomData,
        }
    }
}

impl<F: DerivedFrame> FrameSource for DiskFrames<F> {
    type Frame = F;
    fn len(&self) -> usize {
        self.ids.len()
    }
    fn frame_id(&self, index: usize) -> &str {
        &self.ids[index]
    }
    fn frame(&self, index: usize) -> Result<Arc<F>> {
        let frame = SensorFrame::load(&self.dir, &self.ids[index], self.with_labels)?;
        F::derive(frame).map(Arc::new)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_data::sample_dir;

    #[test]
    fn a_frame_keeps_the_whole_scan_with_intensity() {
        let f = SensorFrame::load(&sample_dir(), "000003", true).unwrap();
        assert_eq!(f.image_size, [1242.0, 375.0]);
        let raw = read_velodyne(&sample_dir().velodyne("000003")).unwrap();
        assert_eq!(f.lidar, raw);
        assert!(f.lidar.iter().any(|p| p[3] > 0.0), "intensity is kept");
        assert!(!f.objects.is_empty());
        assert_eq!(f.image().unwrap().dimensions(), (1242, 375));
    }

    #[test]
    fn missing_files_are_errors_naming_the_file() {
        let err = SensorFrame::load(&sample_dir(), "999999", true)
            .unwrap_err()
            .to_string();
        assert!(err.contains("999999"), "{err}");
    }

    #[test]
    fn memory_and_disk_sources_agree() {
        let ids = vec!["000001".to_string(), "000003".to_string()];
        let memory = InMemoryFrames::<SensorFrame>::load(&sample_dir(), &ids, true).unwrap();
        let disk = DiskFrames::<SensorFrame>::new(sample_dir(), ids, true);
        assert_eq!(memory.len(), 2);
        assert_eq!(memory.index_of("000003"), Some(1));
        assert_eq!(disk.index_of("000003"), Some(1));
        for i in 0..2 {
            let (a, b) = (memory.frame(i).unwrap(), disk.frame(i).unwrap());
            assert_eq!(a.id, b.id);
            assert_eq!(a.lidar, b.lidar);
            assert_eq!(a.objects, b.objects);
        }
    }
}
