//! DASANet plugged into the generic pipeline: its `[dasanet]` section, the pseudo cloud
//! of a frame ([`pseudo`]), frames as two-branch samples and batches ([`data`]), its
//! detector and training task. Voxel R-CNN's data side, proposals and box decoding are
//! reused as they are.

pub mod config;
pub mod data;
pub mod detector;
pub mod info;
pub mod pseudo;
mod task;

pub use config::{DasanetSection, PseudoCloudConfig};
pub use detector::DasanetDetector;
pub use task::{
    DasanetTask, PSEUDO_GT_DATABASE_DIR, build_pseudo_gt_database, data_pseudo_gt_database_dir,
    detection_data, seeded_network, train, trained_parameters,
};
