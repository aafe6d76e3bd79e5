//! Network and loss configuration: serde structs that read from TOML, with F-ConvNet's
//! published Car configuration as the default and a `tiny` variant for fast tests.
//!
//! A TOML file holds a `[model]` table (architecture; stored in checkpoints and compared on
//! load) and a `[loss]` table; every key is optional and defaults to the Car value. Unknown
//! top-level tables (for example a trainer's `[train]`) are ignored, unknown keys inside
//! `[model]` / `[loss]` are an error.

use crate::error::ModelError;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The whole configuration: architecture plus loss.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default)]
pub struct FConvNetConfig {
    pub model: ModelConfig,
    pub loss: LossConfig,
}

/// Which per-slice encoder runs on the (point, sub-frustum) pairs of each scale.
///
/// Only the plain PointNet exists today; SAF's local feature aggregation and FCAM's
/// CBAM-style attention are meant to be added here as further variants.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum SliceEncoderKind {
    /// Shared MLP (Linear + BatchNorm + ReLU per layer) and a max-pool over the slice.
    #[default]
    PointNet,
}

/// The architecture. Everything here determines the weights' shapes or their meaning.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModelConfig {
    /// Length of the class one-hot appended to every slice feature (Car, Pedestrian, Cyclist).
    pub num_classes: usize,
    /// Per-slice encoder.
    pub slice_encoder: SliceEncoderKind,
    /// PointNet layer widths per scale, finest scale first (four scales).
    pub pointnet_widths: Vec<Vec<usize>>,
    /// Output channels of FCN blocks 1–4 (each block's convolutions and its merge conv).
    pub fcn_channels: Vec<usize>,
    /// Output channels of each of the three transposed convolutions (blocks 2, 3, 4);
    /// the heads see three times this many channels.
    pub deconv_channels: usize,
    /// Heading bins over 2π; bin k is centred on k · 2π / bins.
    pub num_heading_bins: usize,
    /// Mean (l, w, h) of each size cluster, in metres (F-ConvNet: the KITTI class means of
    /// Car, Pedestrian, Cyclist). Must match the frustum dataset's size-residual encoding.
    pub size_clusters: Vec<[f32; 3]>,
    /// Whether layers followed by batch norm carry a bias. The published implementation
    /// has none (the bias is redundant before batch norm); `true` adds 5,632 parameters to Car.
    pub bias_before_norm: bool,
    pub batch_norm_momentum: f64,
    pub batch_norm_epsilon: f64,
}

/// Loss weights and shapes (F-ConvNet's `cfg.LOSS` and its `huber_loss` deltas).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LossConfig {
    pub focal_alpha: f32,
    pub focal_gamma: f32,
    /// Weight of the whole box term (centre + heading + size + corners).
    pub box_weight: f32,
    pub heading_residual_weight: f32,
    pub size_residual_weight: f32,
    pub corner_weight: f32,
    /// Huber delta on the centre distance.
    pub center_delta: f32,
    /// Huber delta on the heading and size residuals.
    pub residual_delta: f32,
    /// Huber delta on the mean corner distance.
    pub corner_delta: f32,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self::car()
    }
}

impl Default for LossConfig {
    fn default() -> Self {
        Self {
            focal_alpha: 0.25,
            focal_gamma: 2.0,
            box_weight: 1.0,
            heading_residual_weight: 20.0,
            size_residual_weight: 20.0,
            corner_weight: 10.0,
            center_delta: 3.0,
            residual_delta: 1.0,
            corner_delta: 1.0,
        }
    }
}

/// F-ConvNet's KITTI class mean sizes (l, w, h) for Car, Pedestrian, Cyclist
/// (`datasets/dataset_info.py` of the reference implementation, rounded to f32).
#[allow(clippy::excessive_precision)]
pub const KITTI_MEAN_SIZES: [[f32; 3]; 3] = [
    [3.883_116_4, 1.628_567_4, 1.525_631_9],
    [0.844_225_24, 0.660_686_2, 1.762_551_2],
    [1.762_824, 0.597_063_67, 1.736_981_3],
];

impl ModelConfig {
    /// The published Car configuration.
    pub fn car() -> Self {
        Self {
            num_classes: 3,
            slice_encoder: SliceEncoderKind::PointNet,
            pointnet_widths: vec![
                vec![64, 64, 128],
                vec![64, 64, 128],
                vec![128, 128, 256],
                vec![256, 256, 512],
            ],
            fcn_channels: vec![128, 128, 256, 512],
            deconv_channels: 256,
            num_heading_bins: 12,
            size_clusters: KITTI_MEAN_SIZES.to_vec(),
            bias_before_norm: false,
            batch_norm_momentum: 0.1,
            batch_norm_epsilon: 1e-5,
        }
    }

    /// Small widths, same structure: trains in milliseconds per step, for tests.
    pub fn tiny() -> Self {
        Self {
            pointnet_widths: vec![
                vec![16, 16, 32],
                vec![16, 16, 32],
                vec![16, 32],
                vec![32, 64],
            ],
            fcn_channels: vec![32, 32, 48, 64],
            deconv_channels: 32,
            ..Self::car()
        }
    }

    /// Channels of one scale's slice features after the one-hot is appended.
    pub fn scale_feature_channels(&self, scale: usize) -> usize {
        self.pointnet_widths[scale].last().copied().unwrap_or(3) + self.num_classes
    }

    /// Regression outputs per position: 3 centre offsets, bins heading scores and bins
    /// normalised residuals, clusters size scores and clusters × 3 normalised size residuals.
    pub fn regression_channels(&self) -> usize {
        3 + 2 * self.num_heading_bins + 4 * self.size_clusters.len()
    }

    /// Channels the heads see (three deconvolved blocks, concatenated).
    pub fn head_channels(&self) -> usize {
        3 * self.deconv_channels
    }

    /// The width of one heading bin in radians.
    pub fn heading_bin_width(&self) -> f32 {
        std::f32::consts::TAU / self.num_heading_bins as f32
    }

    /// Checks the structural constraints the network relies on.
    pub fn validate(&self) -> Result<(), ModelError> {
        let bad = |msg: String| Err(ModelError::InvalidConfig(msg));
        if self.pointnet_widths.len() != 4 {
            return bad(format!(
                "pointnet_widths must list 4 scales, got {}",
                self.pointnet_widths.len()
            ));
        }
        if let Some(i) = self
            .pointnet_widths
            .iter()
            .position(|w| w.is_empty() || w.contains(&0))
        {
            return bad(format!(
                "pointnet_widths[{i}] must be non-empty and positive"
            ));
        }
        if self.fcn_channels.len() != 4 || self.fcn_channels.contains(&0) {
            return bad(format!(
                "fcn_channels must list 4 positive channel counts, got {:?}",
                self.fcn_channels
            ));
        }
        if self.deconv_channels == 0 || self.num_heading_bins == 0 || self.num_classes == 0 {
            return bad(
                "deconv_channels, num_heading_bins and num_classes must be positive".into(),
            );
        }
        if self.size_clusters.is_empty() {
            return bad("size_clusters must not be empty".into());
        }
        if self
            .size_clusters
            .iter()
            .flatten()
            .any(|s| !(s.is_finite() && *s > 0.0))
        {
            return bad("size cluster mean sizes must be finite and positive".into());
        }
        if !(self.batch_norm_epsilon > 0.0 && (0.0..=1.0).contains(&self.batch_norm_momentum)) {
            return bad("batch norm epsilon must be > 0 and momentum in [0, 1]".into());
        }
        Ok(())
    }
}

impl FConvNetConfig {
    /// The published Car configuration.
    pub fn car() -> Self {
        Self::default()
    }

    /// The tiny test configuration (Car loss).
    pub fn tiny() -> Self {
        Self {
            model: ModelConfig::tiny(),
            loss: LossConfig::default(),
        }
    }

    pub fn from_toml_str(text: &str) -> Result<Self, ModelError> {
        let config: Self =
            toml::from_str(text).map_err(|e| ModelError::ConfigParse(e.to_string()))?;
        config.model.validate()?;
        Ok(config)
    }

    pub fn from_toml_file(path: &Path) -> Result<Self, ModelError> {
        let text = std::fs::read_to_string(path).map_err(|e| ModelError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        Self::from_toml_str(&text).map_err(|e| match e {
            ModelError::ConfigParse(msg) => {
                ModelError::ConfigParse(format!("{}: {msg}", path.display()))
            }
            other => other,
        })
    }

    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).expect("the configuration serialises to TOML")
    }
}
