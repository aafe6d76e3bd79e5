//! `[voxel_rcnn]`: everything a Voxel R-CNN configuration sets beyond the shared
//! sections — the voxel grid, anchors, network shape, losses, RoI sampling,
//! augmentation, proposal and final NMS — each a sub-table whose every key defaults to
//! OpenPCDet's `voxel_rcnn_car.yaml`.

use fusiondet_models::voxel_rcnn::{VoxelRcnnLossConfig, VoxelRcnnNetConfig, VoxelRcnnShape};
use fusiondet_voxel::{AnchorConfig, AugmentConfig, RoiTargetConfig, VoxelConfig};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VoxelRcnnSection {
    pub voxels: VoxelConfig,
    pub anchors: AnchorConfig,
    pub network: VoxelRcnnNetConfig,
    pub loss: VoxelRcnnLossConfig,
    pub roi_targets: RoiTargetConfig,
    pub augment: AugmentConfig,
    pub proposals: ProposalConfig,
    pub post: PostConfig,
}

/// Stage one's boxes handed to the RoI head: the top `pre_max` by score, NMS at `iou`
/// in the bird's-eye view, at most `post_max` kept.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NmsConfig {
    pub pre_max: usize,
    pub post_max: usize,
    pub iou: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProposalConfig {
    pub train: NmsConfig,
    pub test: NmsConfig,
}

impl Default for ProposalConfig {
    fn default() -> Self {
        Self {
            train: NmsConfig {
                pre_max: 9000,
                post_max: 512,
                iou: 0.8,
            },
            test: NmsConfig {
                pre_max: 2048,
                post_max: 100,
                iou: 0.7,
            },
        }
    }
}

/// The final boxes: refined scores of at least `score_threshold`, NMS at `nms`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PostConfig {
    pub score_threshold: f64,
    pub nms: NmsConfig,
}

impl Default for PostConfig {
    fn default() -> Self {
        Self {
            score_threshold: 0.3,
            nms: NmsConfig {
                pre_max: 4096,
                post_max: 500,
                iou: 0.1,
            },
        }
    }
}

impl VoxelRcnnSection {
    /// What fixes the network's tensors (stored in checkpoints).
    pub fn shape(&self) -> VoxelRcnnShape {
        VoxelRcnnShape {
            network: self.network.clone(),
            grid_z: self.voxels.sparse_shape()[0],
        }
    }

    /// Every cross-section constraint; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        self.voxels
            .validate()
            .map_err(|e| format!("[voxel_rcnn.voxels] {e}"))?;
        self.anchors
            .validate(&self.voxels)
            .map_err(|e| format!("[voxel_rcnn.anchors] {e}"))?;
        self.network.validate()?;
        self.roi_targets
            .validate()
            .map_err(|e| format!("[voxel_rcnn.roi_targets] {e}"))?;
        self.augment
            .validate()
            .map_err(|e| format!("[voxel_rcnn.augment] {e}"))?;
        if self.network.anchors_per_location != self.anchors.per_location() {
            return Err(format!(
                "[voxel_rcnn.network] anchors_per_location is {}, but [voxel_rcnn.anchors] \
                 puts {} anchors in each cell; remove the key or make it {}",
                self.network.anchors_per_location,
                self.anchors.per_location(),
                self.anchors.per_location()
            ));
        }
        if self.network.num_classes != self.anchors.classes.len() {
            return Err(format!(
                "[voxel_rcnn.network] num_classes is {}, but [voxel_rcnn.anchors] has {} classes",
                self.network.num_classes,
                self.anchors.classes.len()
            ));
        }
        if self.network.num_direction_bins != self.anchors.num_dir_bins {
            return Err(format!(
                "[voxel_rcnn.network] num_direction_bins ({}) differs from \
                 [voxel_rcnn.anchors] num_dir_bins ({})",
                self.network.num_direction_bins, self.anchors.num_dir_bins
            ));
        }
        // The anchor grid is the BEV map: the voxel grid over the backbone's stride 8.
        let [nx, ny, _] = self.voxels.grid_size();
        let first_stride = self.network.bev.layer_strides[0];
        let up = self.network.bev.upsample_strides[0];
        if self.anchors.feature_map_stride != 8 * first_stride / up.max(1) {
            return Err(format!(
                "[voxel_rcnn.anchors] feature_map_stride {} does not match the network, whose \
                 BEV output has stride {} (8 from the sparse backbone, × layer_strides[0] / \
                 upsample_strides[0])",
                self.anchors.feature_map_stride,
                8 * first_stride / up.max(1)
            ));
        }
        if nx % 8 != 0 || ny % 8 != 0 {
            return Err(format!(
                "[voxel_rcnn.voxels]: the grid ({nx} × {ny} voxels in x and y) must be a \
                 multiple of 8, the sparse backbone's stride"
            ));
        }
        for (name, n) in [
            ("proposals.train", &self.proposals.train),
            ("proposals.test", &self.proposals.test),
            ("post.nms", &self.post.nms),
        ] {
            if n.pre_max == 0 || n.post_max == 0 || !(0.0..=1.0).contains(&n.iou) {
                return Err(format!(
                    "[voxel_rcnn.{name}]: pre_max and post_max must be at least 1 and iou in [0, 1]"
                ));
            }
        }
        if !(0.0..=1.0).contains(&self.post.score_threshold) {
            return Err("[voxel_rcnn.post] score_threshold must lie in [0, 1]".into());
        }
        Ok(())
    }
}
