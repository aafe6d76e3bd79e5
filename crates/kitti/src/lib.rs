//! KITTI object-benchmark file formats: strict readers (every error names file,
//! line and field) and atomic writers.

pub mod atomic;
pub mod calib;
pub mod depth;
pub mod detections2d;
pub mod error;
pub mod image;
pub mod label;
pub mod layout;
pub mod paths;
pub mod results;
pub mod shard;
pub mod split;
pub mod velodyne;

pub use atomic::write_atomic;
pub use calib::{Calib, Mat33, Mat34, read_calib, write_calib};
pub use depth::{DepthMap, read_depth_png, write_depth_png};
pub use detections2d::{Detection2d, read_detections2d, write_detections2d};
pub use error::{FormatError, Result};
pub use label::{Box2d, Box3d, Object, ObjectClass, read_objects, write_objects};
pub use layout::{
    DatasetDir, FrameDir, frame_id, parse_frame_id, split_file, split_is_file, split_name,
};
pub use results::{ResultsManifest, read_manifest, write_manifest};
pub use shard::Shard;
pub use split::{read_split, write_split};
pub use velodyne::{LidarPoint, read_velodyne, write_velodyne};
