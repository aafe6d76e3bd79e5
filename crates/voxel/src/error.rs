//! Errors of the voxel family's data.

use fusiondet_kitti::FormatError;

#[derive(Debug, thiserror::Error)]
pub enum VoxelError {
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error(transparent)]
    Data(#[from] fusiondet_dataset::DataError),
    /// The configuration is inconsistent; the message names the field and says why.
    #[error("voxel config: {0}")]
    Config(String),
    /// An input that cannot be used as given (the message says which and why).
    #[error("{0}")]
    Input(String),
    /// A ground-truth database that cannot be read or written.
    #[error("ground-truth database {path}: {message}")]
    Database { path: String, message: String },
}

pub type Result<T> = std::result::Result<T, VoxelError>;
