//! The voxel family's data (Voxel R-CNN, and DASANet on top of it): what the networks of
//! `models::voxel_rcnn` are fed and trained against, following OpenPCDet's published
//! KITTI Car configuration (`voxel_rcnn_car.yaml`). No networks here.
//!
//! - [`boxes`]: [`LidarBox`] (centre, dx/dy/dz, heading in the LiDAR frame) and its
//!   conversion from and to KITTI's camera-frame `Box3d`; rotated BEV and 3D IoU, the
//!   anchor assignment's nearest-BEV IoU, points in boxes.
//! - [`config`]: the voxel grid, anchors, RoI sampling and augmentation settings (serde
//!   tables whose defaults are the published values).
//! - [`scene`]: a frame in the LiDAR frame (points with intensity, labelled boxes).
//! - [`voxelize`]: the camera field-of-view filter and points → voxels with their mean
//!   features (the `MeanVFE`), capped and, in training, seeded-shuffled.
//! - [`anchors`], [`coder`], [`targets`]: the anchor head's anchors, the residual box
//!   coder and direction bins, and the anchor targets.
//! - [`roi_targets`]: the second stage's RoI sampling and targets.
//! - [`gt_database`], [`augment`]: the ground-truth database and the training
//!   augmentation (ground-truth sampling, flip, rotation, scaling).
//!
//! Geometry is f64; only what feeds a network (voxel features, regression and
//! classification targets) is f32. Every random choice draws from a
//! `fusiondet_dataset::rng::Sampler` the caller seeds.

pub mod anchors;
pub mod augment;
pub mod boxes;
pub mod coder;
pub mod config;
pub mod error;
pub mod gt_database;
pub mod roi_targets;
pub mod scene;
pub mod targets;
pub mod voxelize;

pub use anchors::Anchors;
pub use augment::{AugmentReport, GtSampler, augment};
pub use boxes::{BevRect, GtBox, LidarBox, iou_3d, iou_bev, limit_period, nearest_bev_iou};
pub use coder::{CODE_SIZE, DirectionBins, decode, encode};
pub use config::{
    AnchorClass, AnchorConfig, AugmentConfig, RoiTargetConfig, SampleGroup, VoxelConfig,
};
pub use error::{Result, VoxelError};
pub use gt_database::{DbObject, GtDatabase, kitti_difficulty};
pub use roi_targets::{
    Proposal, RoiTargets, canonical_gt, decode_roi, roi_reg_target, sample_rois,
};
pub use scene::{PseudoPoint, Scene};
pub use targets::{AnchorAssigner, AnchorTargets};
pub use voxelize::{Voxelizer, Voxels, fov_mask, points_in_fov};
