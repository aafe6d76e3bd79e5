//! Why a frame could not be loaded for drawing.

use fusiondet_kitti::FormatError;
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum VizError {
    /// A frame file is missing or malformed (the message names file, line and field).
    #[error(transparent)]
    Format(#[from] FormatError),
    /// The calibration parses but cannot be used (singular extrinsics).
    #[error("{}: {message}", path.display())]
    Calib { path: PathBuf, message: String },
    /// The result directory itself is missing or not a directory.
    #[error("{}: {message}", path.display())]
    ResultDir { path: PathBuf, message: String },
}
