//! The voxel family (Voxel R-CNN) plugged into the generic pipeline: its configuration
//! section, its frames as voxels and batches ([`data`]), proposals and NMS
//! ([`proposals`]), its training task and its detector.

pub mod config;
pub mod data;
pub(crate) mod detector;
pub mod info;
pub mod proposals;
pub(crate) mod task;

pub use config::{NmsConfig, PostConfig, ProposalConfig, VoxelRcnnSection};
pub use detector::{
    STAGE_BACKBONE, STAGE_BEV, STAGE_HEAD, STAGE_NMS, STAGE_PROPOSALS, STAGE_ROI_POOL,
    STAGE_ROI_QUERY, STAGE_RULEBOOKS, STAGE_VOXELIZE, VoxelRcnnDetector,
};
pub use task::{
    GT_DATABASE_DIR, VoxelRcnnTask, build_gt_database, data_gt_database_dir, seeded_network, train,
    trained_parameters,
};
