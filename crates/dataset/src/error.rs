//! Errors of reading frames and splits.

use fusiondet_kitti::FormatError;

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error(transparent)]
    Format(#[from] FormatError),
    /// The calibration of a frame cannot be used.
    #[error("frame {frame}: {message}")]
    Calib { frame: String, message: String },
    /// A split or data set that cannot be used as asked (the message says what to do).
    #[error("{0}")]
    Data(String),
}

pub type Result<T> = std::result::Result<T, DataError>;
