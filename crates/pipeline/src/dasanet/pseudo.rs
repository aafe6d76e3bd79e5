//! A frame's pseudo point cloud as DASANet's pseudo branch reads it (Algorithm A1, steps
//! 1–2): its LiDAR scan projected into image_2 and completed (IP-Basic, or the frame's
//! completed map from a depth directory when one is given), every completed pixel
//! back-projected into the LiDAR frame with its colour, kept where it lies in the point
//! range.

use super::config::PseudoCloudConfig;
use crate::error::{PipelineError, Result};
use fusiondet_dataset::SensorFrame;
use fusiondet_depth::{
    DepthCompleter, IpBasic, Thinning, project_scan, pseudo_points, read_depth_png,
};
use fusiondet_voxel::PseudoPoint;
use std::path::Path;

/// Makes the pseudo cloud of frames.
#[derive(Debug, Clone)]
pub struct PseudoCloudMaker {
    pub config: PseudoCloudConfig,
    pub completer: IpBasic,
    /// The point range [x0, y0, z0, x1, y1, z1] the voxels cover.
    pub point_range: [f64; 6],
}

fn frame_err(frame: &SensorFrame, message: impl std::fmt::Display) -> PipelineError {
    PipelineError::Invalid(format!("frame {}: {message}", frame.id))
}

impl PseudoCloudMaker {
    pub fn new(config: &PseudoCloudConfig, point_range: [f64; 6]) -> Self {
        Self {
            config: config.clone(),
            completer: IpBasic::default(),
            point_range,
        }
    }

    /// The frame's pseudo points, x, y, z (LiDAR frame) and r, g, b in 0–1, from its
    /// completed map in `depth_dir` (`<id>.png`, KITTI depth format) when given, else
    /// completed here. Refuses a frame without an image, an image of another size than
    /// the frame's, or a camera whose principal point lies outside the image.
    pub fn cloud(&self, frame: &SensorFrame, depth_dir: Option<&Path>) -> Result<Vec<PseudoPoint>> {
        let image = frame.image().map_err(|e| {
            frame_err(
                frame,
                format!("DASANet needs the camera image for its pseudo points: {e}"),
            )
        })?;
        let [w, h] = frame.image_size;
        if (image.width() as f64, image.height() as f64) != (w, h) {
            return Err(frame_err(
                frame,
                format!(
                    "image_2 is {}×{} but the frame was read as {w}×{h}",
                    image.width(),
                    image.height()
                ),
            ));
        }
        let (cx, cy) = (frame.camera.p2[(0, 2)], frame.camera.p2[(1, 2)]);
        if !(cx > 0.0 && cx < w && cy > 0.0 && cy < h) {
            return Err(frame_err(
                frame,
                format!(
                    "the calibration's principal point ({cx:.1}, {cy:.1}) lies outside its \
                     {w}×{h} image: the image does not belong to this calibration"
                ),
            ));
        }
        let depth = match depth_dir {
            Some(dir) => {
                let path = dir.join(format!("{}.png", frame.id));
                read_depth_png(&path).map_err(|e| frame_err(frame, e))?
            }
            None => self.completer.complete(&project_scan(frame)),
        };
        let thinning = self.config.thinning.then(Thinning::default);
        let points = pseudo_points(&depth, &image, &frame.camera, thinning)
            .map_err(|e| frame_err(frame, e))?;
        let r = &self.point_range;
        let stride = self.config.pixel_stride as f32;
        Ok(points
            .iter()
            .filter(|p| stride <= 1.0 || (p.uv[0] % stride == 0.0 && p.uv[1] % stride == 0.0))
            .filter(|p| (0..3).all(|a| (p.xyz[a] as f64) >= r[a] && (p.xyz[a] as f64) < r[a + 3]))
            .map(|p| {
                let [x, y, z] = p.xyz;
                let [red, green, blue] = p.rgb.map(|c| c / 255.0);
                [x, y, z, red, green, blue]
            })
            .collect())
    }
}
