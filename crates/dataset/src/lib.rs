//! The neutral home of frames: what every detector family, the evaluation and the
//! pictures read a data set through.
//!
//! - [`SensorFrame`]: one frame as the sensors saw it — the full LiDAR scan with
//!   intensity, the camera model, the image (read on demand) and the labels.
//! - [`FrameSource`]: frames by index, held in memory ([`InMemoryFrames`]) or read from
//!   disk on every request ([`DiskFrames`]); a family keeps its own derived form of a
//!   frame ([`DerivedFrame`]: the frustum family keeps only the points in the image).
//! - [`load_split`] / [`split_ids`]: the frames an `ImageSets/<split>.txt` lists.
//! - [`ClassSet`]: a detector's class vocabulary (names in one-hot order, mean sizes).
//! - [`rng`]: the one seeded generator of the project.
//! - [`indoor`]: SUN RGB-D scenes as frames (upright depth → the rectified camera
//!   convention of `geometry::Box3d`, and back).

pub mod classes;
pub mod error;
pub mod frame;
pub mod indoor;
pub mod rng;
pub mod split;

pub use classes::{Class, ClassInfo, ClassSet};
pub use error::{DataError, Result};
pub use frame::{
    DEFAULT_IMAGE_SIZE, DerivedFrame, DiskFrames, FrameSource, InMemoryFrames, SensorFrame,
    png_size, scan_in_rect,
};
pub use split::{load_split, split_ids};

/// The bundled KITTI sample frames, for tests.
#[cfg(test)]
pub(crate) mod test_data {
    use fusiondet_kitti::FrameDir;
    use std::path::Path;

    pub fn sample_dir() -> FrameDir {
        FrameDir::new(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample/training"),
        )
    }
}
