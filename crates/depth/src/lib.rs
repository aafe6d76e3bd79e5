//! Depth completion, DASANet's camera branch: the sparse LiDAR depth projected into the
//! image ([`project_scan`]) made dense ([`complete`], IP-Basic's classical pipeline:
//! Ku, Harakeh, Waslander, CRV 2018), in the KITTI depth-completion format
//! ([`read_depth_png`] / [`write_depth_png`], the format's home is `fusiondet-kitti`:
//! 16-bit PNG, metres × 256, 0 = empty).
//!
//! [`pseudo_points`] back-projects a completed map into a coloured pseudo point cloud.
//! [`DepthCompleter`] is the interface a learned completion can implement later.

pub mod batch;
pub mod holdout;
pub mod image_ops;
pub mod ip_basic;
mod median;
pub mod metrics;
pub mod project;
pub mod pseudo;
mod scratch;

pub use batch::{
    BatchSummary, PseudoSummary, complete_dir, complete_frames, frame_ids, pseudo_frames,
};
pub use fusiondet_kitti::{DepthMap, read_depth_png, write_depth_png};
pub use holdout::{holdout_errors, split_holdout};
pub use ip_basic::{Blur, DepthCompleter, IpBasic, Method, complete};
pub use metrics::{DepthErrors, depth_errors, restrict_to_scan_coverage};
pub use project::project_scan;
pub use pseudo::{PseudoPoint, Thinning, pseudo_points, read_pseudo_points, write_pseudo_points};

/// Errors of depth maps and their files.
#[derive(Debug, thiserror::Error)]
pub enum DepthError {
    #[error(transparent)]
    Format(#[from] fusiondet_kitti::FormatError),
    #[error(transparent)]
    Data(#[from] fusiondet_dataset::DataError),
    /// Two maps that must align do not (the message says which sizes).
    #[error("{0}")]
    Mismatch(String),
}

pub type Result<T> = std::result::Result<T, DepthError>;
