//! The Voxel R-CNN network's shape (OpenPCDet's `voxel_rcnn_car.yaml` by default): channel
//! widths, layer counts, pooling settings. What the data side decides (voxel size, range,
//! anchors) is the voxel crate's config; the network reads the few values it needs of it
//! through [`VoxelGeometry`].

use fusiondet_nn::NormConfig;
use serde::{Deserialize, Serialize};

/// Bounds on the network's sizes, so that a mistyped value is refused with its key instead
/// of exhausting memory (far above the published network: 6³ grid, 16–32 samples, widths
/// up to 256).
pub const MAX_ROI_GRID: usize = 32;
pub const MAX_POOL_SAMPLES: usize = 1024;
pub const MAX_CHANNELS: usize = 4096;

/// OpenPCDet's batch-norm momentum in the sparse backbone and the BEV network.
pub const BACKBONE_NORM_MOMENTUM: f64 = 0.01;

/// The RoI head's norms: PyTorch's defaults (eps 1e-5, momentum 0.1).
pub const HEAD_NORM: NormConfig = NormConfig {
    bias_before_norm: false,
    momentum: 0.1,
    epsilon: 1e-5,
};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VoxelRcnnNetConfig {
    /// Point features per voxel (x, y, z, intensity).
    pub input_channels: usize,
    /// VoxelBackBone8x: widths of conv_input/conv1, conv2, conv3, conv4.
    pub backbone_channels: [usize; 4],
    /// Width of the (3,1,1) output convolution.
    pub backbone_out_channels: usize,
    pub bev: BevConfig,
    /// Anchors per BEV cell and class (rotations × sizes).
    pub anchors_per_location: usize,
    pub num_classes: usize,
    pub num_direction_bins: usize,
    pub roi: RoiHeadConfig,
    /// Batch-norm momentum of the backbones (OpenPCDet: 0.01, running statistics that
    /// settle over thousands of steps; a short run needs a larger one).
    pub norm_momentum: f64,
}

/// BaseBEVBackbone: blocks of 3×3 convolutions, each upsampled by a transposed
/// convolution and concatenated.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BevConfig {
    /// 3×3 convolutions after each block's first (strided) one.
    pub layer_nums: Vec<usize>,
    pub layer_strides: Vec<usize>,
    pub num_filters: Vec<usize>,
    pub upsample_strides: Vec<usize>,
    pub num_upsample_filters: Vec<usize>,
}

/// The voxel RoI pooling levels and the RoI head's fully connected layers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RoiHeadConfig {
    /// Grid points per RoI edge (6 → 216 per RoI).
    pub grid_size: usize,
    pub levels: Vec<PoolLevelConfig>,
    pub shared_fc: Vec<usize>,
    pub cls_fc: Vec<usize>,
    pub reg_fc: Vec<usize>,
    pub dropout: f64,
    /// Box code size of the class-agnostic regression (7).
    pub code_size: usize,
}

/// One backbone level the RoI grid pools from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoolLevelConfig {
    /// Backbone stage, 1–4 (x_conv1 … x_conv4).
    pub stage: usize,
    /// Channels after the feature and position layers (`MLPS[0]`).
    pub mid_channels: usize,
    /// Channels out of the level (`MLPS[1]`).
    pub out_channels: usize,
    /// Half-width of the voxel cube searched around a grid point, per axis (z, y, x).
    pub query_range: [usize; 3],
    /// Ball radius in metres.
    pub radius: f64,
    /// Neighbours kept per grid point (the first found).
    pub samples: usize,
}

impl Default for VoxelRcnnNetConfig {
    fn default() -> Self {
        Self {
            input_channels: 4,
            backbone_channels: [16, 32, 64, 64],
            backbone_out_channels: 128,
            bev: BevConfig::default(),
            anchors_per_location: 2,
            num_classes: 1,
            num_direction_bins: 2,
            roi: RoiHeadConfig::default(),
            norm_momentum: BACKBONE_NORM_MOMENTUM,
        }
    }
}

impl Default for BevConfig {
    fn default() -> Self {
        Self {
            layer_nums: vec![5, 5],
            layer_strides: vec![1, 2],
            num_filters: vec![64, 128],
            upsample_strides: vec![1, 2],
            num_upsample_filters: vec![128, 128],
        }
    }
}

impl Default for RoiHeadConfig {
    fn default() -> Self {
        let level = |stage, radius| PoolLevelConfig {
            stage,
            mid_channels: 32,
            out_channels: 32,
            query_range: [4, 4, 4],
            radius,
            samples: 16,
        };
        Self {
            grid_size: 6,
            levels: vec![level(2, 0.4), level(3, 0.8), level(4, 1.6)],
            shared_fc: vec![256, 256],
            cls_fc: vec![256, 256],
            reg_fc: vec![256, 256],
            dropout: 0.3,
            code_size: 7,
        }
    }
}

impl VoxelRcnnNetConfig {
    /// Every layer of the sparse backbone and the BEV network: no bias, batch norm with
    /// eps 1e-3 and `norm_momentum`.
    pub fn backbone_norm(&self) -> NormConfig {
        NormConfig {
            bias_before_norm: false,
            momentum: self.norm_momentum,
            epsilon: 1e-3,
        }
    }

    /// Channels of backbone stage `stage` (1–4).
    pub fn stage_channels(&self, stage: usize) -> usize {
        self.backbone_channels[stage - 1]
    }

    /// Channels of the BEV map: the output convolution's width times the 2 heights left.
    pub fn bev_input_channels(&self, heights: usize) -> usize {
        self.backbone_out_channels * heights
    }

    /// What is wrong with this shape, if anything.
    pub fn validate(&self) -> Result<(), String> {
        let b = &self.bev;
        let n = b.layer_nums.len();
        if n == 0
            || [
                b.layer_strides.len(),
                b.num_filters.len(),
                b.upsample_strides.len(),
                b.num_upsample_filters.len(),
            ]
            .iter()
            .any(|&l| l != n)
        {
            return Err(format!(
                "[voxel_rcnn.bev]: layer_nums, layer_strides, num_filters, upsample_strides and \
                 num_upsample_filters need one entry per block (got {}, {}, {}, {}, {})",
                n,
                b.layer_strides.len(),
                b.num_filters.len(),
                b.upsample_strides.len(),
                b.num_upsample_filters.len()
            ));
        }
        if b.layer_strides
            .iter()
            .chain(&b.upsample_strides)
            .any(|&s| s == 0)
        {
            return Err("[voxel_rcnn.bev]: strides must be at least 1".into());
        }
        let zero = |v: &[usize]| v.contains(&0);
        if zero(&self.backbone_channels)
            || self.backbone_out_channels == 0
            || self.input_channels == 0
        {
            return Err("[voxel_rcnn]: channel widths must be positive".into());
        }
        let widths = self
            .backbone_channels
            .iter()
            .chain([&self.backbone_out_channels, &self.input_channels])
            .chain(&b.num_filters)
            .chain(&b.num_upsample_filters);
        if let Some(w) = widths.into_iter().find(|&&w| w > MAX_CHANNELS) {
            return Err(format!(
                "[voxel_rcnn]: a channel width of {w} is more than {MAX_CHANNELS}"
            ));
        }
        if b.layer_nums.iter().any(|&l| l > 64)
            || b.layer_strides
                .iter()
                .chain(&b.upsample_strides)
                .any(|&s| s > 16)
        {
            return Err(
                "[voxel_rcnn.bev]: layer_nums must be at most 64 and strides at most 16".into(),
            );
        }
        let r = &self.roi;
        if r.grid_size == 0 || r.levels.is_empty() {
            return Err(
                "[voxel_rcnn.roi]: grid_size and at least one pooling level are needed".into(),
            );
        }
        // The pooled grid is grid_size³ points a RoI: bounded before anything is allocated.
        if r.grid_size > MAX_ROI_GRID {
            return Err(format!(
                "[voxel_rcnn.roi] grid_size {} must be at most {MAX_ROI_GRID} (the paper's is 6)",
                r.grid_size
            ));
        }
        for (i, level) in r.levels.iter().enumerate() {
            if !(1..=4).contains(&level.stage) {
                return Err(format!(
                    "[voxel_rcnn.roi.levels[{i}]] stage {} is not a backbone stage 1–4",
                    level.stage
                ));
            }
            // NaN fails the range test, so it is refused too.
            if level.samples == 0
                || !(level.radius > 0.0 && level.radius <= 100.0)
                || level.mid_channels == 0
                || level.out_channels == 0
            {
                return Err(format!(
                    "[voxel_rcnn.roi.levels[{i}]]: samples, radius (at most 100 m) and channels \
                     must be positive, got samples {}, radius {}",
                    level.samples, level.radius
                ));
            }
            if level.samples > MAX_POOL_SAMPLES
                || level.mid_channels.max(level.out_channels) > MAX_CHANNELS
                || level.query_range.iter().any(|&q| q > 16)
            {
                return Err(format!(
                    "[voxel_rcnn.roi.levels[{i}]]: samples at most {MAX_POOL_SAMPLES}, channels at \
                     most {MAX_CHANNELS}, query_range at most 16 (got samples {}, query_range {:?})",
                    level.samples, level.query_range
                ));
            }
        }
        if r.shared_fc
            .iter()
            .chain(&r.cls_fc)
            .chain(&r.reg_fc)
            .any(|&w| w > MAX_CHANNELS)
        {
            return Err(format!(
                "[voxel_rcnn.roi]: fully connected widths must be at most {MAX_CHANNELS}"
            ));
        }
        if zero(&r.shared_fc) || zero(&r.cls_fc) || zero(&r.reg_fc) || r.shared_fc.is_empty() {
            return Err(
                "[voxel_rcnn.roi]: fully connected widths must be positive (shared_fc non-empty)"
                    .into(),
            );
        }
        if !(self.norm_momentum > 0.0 && self.norm_momentum <= 1.0) {
            return Err(format!(
                "[voxel_rcnn.network] norm_momentum {} must lie in (0, 1]",
                self.norm_momentum
            ));
        }
        if !(0.0..1.0).contains(&r.dropout) {
            return Err(format!(
                "[voxel_rcnn.roi] dropout {} must lie in [0, 1)",
                r.dropout
            ));
        }
        Ok(())
    }
}
