//! Shared test fixtures: the bundled real KITTI frames.

use fusiondet_geometry::CameraModel;
use fusiondet_kitti::{FrameDir, read_calib};
use image::{Rgb, RgbImage};

/// `data/kitti-sample/training` of this repository.
pub fn sample_dir() -> FrameDir {
    FrameDir::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../data/kitti-sample/training"
    ))
}

/// The camera of bundled frame 000001.
pub fn camera() -> CameraModel {
    let calib = read_calib(&sample_dir().calib("000001")).unwrap();
    calib.camera_model().unwrap()
}

pub fn count_colour(img: &RgbImage, c: Rgb<u8>) -> usize {
    img.pixels().filter(|&&p| p == c).count()
}
