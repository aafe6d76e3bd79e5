//! `[dasanet]`: what a DASANet configuration sets beyond Voxel R-CNN's `[voxel_rcnn]`
//! sections (which configure its LiDAR branch, BEV network, anchors, heads and data):
//! the modules of its ablation row, the GIoU weight and the pseudo point cloud.

use fusiondet_models::dasanet::{DasanetModules, DasanetNetConfig, DasanetShape};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DasanetSection {
    pub modules: DasanetModules,
    /// Weight of the detection head's 3D GIoU term (the paper gives none: 1).
    pub giou_weight: f64,
    pub pseudo: PseudoCloudConfig,
}

impl Default for DasanetSection {
    fn default() -> Self {
        Self {
            modules: DasanetModules::default(),
            giou_weight: 1.0,
            pseudo: PseudoCloudConfig::default(),
        }
    }
}

/// How a frame's pseudo point cloud is made and voxelized: IP-Basic's fast pipeline
/// (Gaussian blur, no extrapolation, so no depth is invented above the scan), every
/// completed pixel back-projected, optionally thinned.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PseudoCloudConfig {
    /// Pseudo points averaged per voxel (the paper: 15).
    pub max_points_per_voxel: usize,
    /// Pseudo voxels kept per training / detection frame (the paper: LiDAR's caps).
    pub max_voxels_train: usize,
    pub max_voxels_test: usize,
    /// SFD's near-range thinning (below 13 m only pixels with odd u and v).
    pub thinning: bool,
    /// Keep every `pixel_stride`-th pixel along u and v (1: all): a CPU knob that cuts
    /// the cloud by its square.
    pub pixel_stride: usize,
}

impl Default for PseudoCloudConfig {
    fn default() -> Self {
        Self {
            max_points_per_voxel: 15,
            max_voxels_train: 16_000,
            max_voxels_test: 40_000,
            thinning: false,
            pixel_stride: 1,
        }
    }
}

impl PseudoCloudConfig {
    pub fn max_voxels(&self, training: bool) -> usize {
        if training {
            self.max_voxels_train
        } else {
            self.max_voxels_test
        }
    }
}

impl DasanetSection {
    /// The network's shape on the Voxel R-CNN shape and grid of `[voxel_rcnn]`.
    pub fn shape(&self, voxel_rcnn: &crate::voxel_rcnn::VoxelRcnnSection) -> DasanetShape {
        DasanetShape {
            network: DasanetNetConfig {
                voxel_rcnn: voxel_rcnn.network.clone(),
                modules: self.modules.clone(),
            },
            grid_z: voxel_rcnn.voxels.sparse_shape()[0],
            inference_only: false,
        }
    }

    pub fn validate(&self) -> Result<(), String> {
        self.modules.validate()?;
        let p = &self.pseudo;
        if p.max_points_per_voxel == 0 || p.max_voxels_train == 0 || p.max_voxels_test == 0 {
            return Err(
                "[dasanet.pseudo]: max_points_per_voxel, max_voxels_train and max_voxels_test \
                 must be at least 1"
                    .into(),
            );
        }
        if p.max_points_per_voxel > fusiondet_voxel::config::MAX_POINTS_PER_VOXEL
            || p.max_voxels_train.max(p.max_voxels_test) > fusiondet_voxel::config::MAX_VOXELS
        {
            return Err(format!(
                "[dasanet.pseudo]: max_points_per_voxel must be at most {}, max_voxels_train and \
                 max_voxels_test at most {}",
                fusiondet_voxel::config::MAX_POINTS_PER_VOXEL,
                fusiondet_voxel::config::MAX_VOXELS
            ));
        }
        if !(1..=64).contains(&p.pixel_stride) {
            return Err(format!(
                "[dasanet.pseudo] pixel_stride {} must be in 1..=64",
                p.pixel_stride
            ));
        }
        if !(self.giou_weight.is_finite() && self.giou_weight >= 0.0) {
            return Err(format!(
                "[dasanet] giou_weight {} must be finite and ≥ 0",
                self.giou_weight
            ));
        }
        Ok(())
    }
}
