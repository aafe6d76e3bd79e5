//! Voxel R-CNN (Deng et al., AAAI 2021) in burn, as OpenPCDet's `voxel_rcnn_car.yaml`
//! builds it: mean voxel features → sparse 3D backbone ([`backbone3d`]) → height
//! compression and BEV backbone ([`bev`]) → anchor head ([`anchor_head`]) → proposals
//! (decoded and suppressed on the CPU by the caller) → voxel RoI pooling ([`roi_pool`]) →
//! RoI head ([`roi_head`]).
//!
//! The forward pass is split where the CPU takes over (proposal decoding and NMS, the
//! RoI grid query), so the pipeline can time and batch each stage.

pub mod anchor_head;
pub mod backbone3d;
pub mod bev;
pub mod checkpoint;
pub mod config;
pub mod loss;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub mod proposals_device;
pub mod roi_head;
pub mod roi_pool;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub mod roi_query_device;
pub mod synthetic;

pub use anchor_head::{AnchorHead, AnchorPredictions};
pub use backbone3d::{BackboneOutput, BackbonePlan, SparseMap, VoxelBackbone};
pub use bev::{BevBackbone, height_compression};
pub use checkpoint::{VoxelRcnnShape, load_voxel_rcnn, read_voxel_rcnn_shape, save_voxel_rcnn};
pub use config::{BevConfig, PoolLevelConfig, RoiHeadConfig, VoxelRcnnNetConfig};
pub use loss::{
    AnchorLossTargets, RoiLossTargets, VoxelRcnnLoss, VoxelRcnnLossConfig, anchor_loss, roi_loss,
};
pub use roi_head::{RoiHead, RoiPredictions};
pub use roi_pool::{RoiBox, RoiGridIndex, RoiGridPool, VoxelGeometry, roi_grid_points};

use crate::info::trainable_params;
use burn::prelude::*;

/// Heights left after the output convolution for a grid of `z` voxels.
pub fn bev_heights(grid_z: usize) -> usize {
    let conv = |n: usize, g: fusiondet_nn::sparse::ConvGeometry| g.output_shape([n, 1, 1])[0];
    let mut z = grid_z;
    for stage in 2..=4 {
        z = conv(
            z,
            backbone3d::stage_geometry(stage).expect("stages 2–4 downsample"),
        );
    }
    conv(z, backbone3d::output_geometry())
}

/// The backbone maps the RoI grid pools from, one per pooling level.
pub fn pooled_maps<'a>(
    backbone: &'a BackboneOutput,
    levels: &[PoolLevelConfig],
) -> Vec<&'a SparseMap> {
    levels
        .iter()
        .map(|l| &backbone.stages[l.stage - 1])
        .collect()
}

#[derive(Module, Debug)]
pub struct VoxelRcnn {
    pub backbone: VoxelBackbone,
    pub bev: BevBackbone,
    pub anchor_head: AnchorHead,
    pub roi_pool: RoiGridPool,
    pub roi_head: RoiHead,
}

/// Stage one's outputs: the sparse maps (kept for RoI pooling) and anchor predictions.
#[derive(Debug, Clone)]
pub struct StageOneOutput {
    pub backbone: BackboneOutput,
    pub anchors: AnchorPredictions,
}

impl VoxelRcnn {
    /// The network for a voxel grid with `grid_z` heights (41 in the published config).
    pub fn new(
        config: &VoxelRcnnNetConfig,
        grid_z: usize,
        device: &Device,
    ) -> Result<Self, String> {
        config.validate()?;
        let bev_in = config.bev_input_channels(bev_heights(grid_z));
        let bev_out = BevBackbone::output_channels(&config.bev);
        let level_channels: Vec<usize> = config
            .roi
            .levels
            .iter()
            .map(|l| config.stage_channels(l.stage))
            .collect();
        let pooled: usize = config
            .roi
            .levels
            .iter()
            .map(|l| l.out_channels)
            .sum::<usize>()
            * config.roi.grid_size.pow(3);
        Ok(Self {
            backbone: VoxelBackbone::new(config, device),
            bev: BevBackbone::new(&config.bev, bev_in, &config.backbone_norm(), device),
            anchor_head: AnchorHead::new(
                bev_out,
                config.anchors_per_location,
                config.num_classes,
                config.num_direction_bins,
                device,
            ),
            roi_pool: RoiGridPool::new(&config.roi, &level_channels, device),
            roi_head: RoiHead::new(&config.roi, pooled, device),
        })
    }

    /// Voxel features [voxels, 4] on the plan's input sites → maps and anchor predictions.
    pub fn stage_one(&self, voxel_features: Tensor<2>, plan: &BackbonePlan) -> StageOneOutput {
        let backbone = self.backbone.forward(voxel_features, plan);
        let bev = self.bev.forward(height_compression(&backbone.output));
        StageOneOutput {
            anchors: self.anchor_head.forward(bev),
            backbone,
        }
    }

    /// Trainable parameters per module, in data-flow order.
    pub fn param_rows(&self) -> Vec<(String, usize)> {
        vec![
            (
                "3D backbone (VoxelBackBone8x)".into(),
                trainable_params(&self.backbone),
            ),
            ("BEV backbone".into(), trainable_params(&self.bev)),
            ("anchor head".into(), trainable_params(&self.anchor_head)),
            ("RoI grid pooling".into(), trainable_params(&self.roi_pool)),
            ("RoI head FCs".into(), trainable_params(&self.roi_head)),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn published_configuration_counts_openpcdets_parameters() {
        let device = Device::flex();
        let config = VoxelRcnnNetConfig::default();
        assert_eq!(bev_heights(41), 2);
        let model = VoxelRcnn::new(&config, 41, &device).unwrap();
        let rows = model.param_rows();
        let count: Vec<usize> = rows.iter().map(|r| r.1).collect();
        // OpenPCDet's module counts: backbone 711,872; BEV 1,219,328; anchor head 5,140;
        // RoI head 5,650,280 (pooling 9,056 + FCs 5,641,224); total 7,586,620.
        assert_eq!(count, vec![711_872, 1_219_328, 5_140, 9_056, 5_641_224]);
        assert_eq!(count.iter().sum::<usize>(), 7_586_620);
        assert_eq!(trainable_params(&model), 7_586_620);
    }
}
