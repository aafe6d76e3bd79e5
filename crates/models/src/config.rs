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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum SliceEncoderKind {
    /// F-ConvNet: shared MLP (Linear + BatchNorm + ReLU per layer), max-pooled per slice.
    #[default]
    PointNet,
    /// FCAM with CBAM: the PointNet with channel + spatial attention after the hidden
    /// layers listed in `[model.attention]`.
    Cbam,
    /// FCAM: the improved CBAM (parallel ReLU and tanh channel MLPs).
    ImprovedCbam,
}

impl SliceEncoderKind {
    pub fn uses_attention(self) -> bool {
        !matches!(self, Self::PointNet)
    }
}

/// FCAM's attention blocks (used by the `cbam` and `improved_cbam` encoders).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AttentionConfig {
    /// Reduction of the ReLU channel MLP (CBAM: 16).
    pub channel_reduction: usize,
    /// Reduction of the improved CBAM's tanh channel MLP (32).
    pub tanh_reduction: usize,
    /// Side of the spatial attention's square kernel (7).
    pub spatial_kernel: usize,
    /// PointNet layers (0-based) whose outputs are attended. The default, one block after
    /// the first layer, is the placement whose parameter count matches FCAM's published
    /// +11,264 over F-ConvNet (the channel MLPs of 64/64/128/256-channel maps).
    pub after_layers: Vec<usize>,
}

impl Default for AttentionConfig {
    fn default() -> Self {
        Self {
            channel_reduction: 16,
            tanh_reduction: 32,
            spatial_kernel: 7,
            after_layers: vec![0],
        }
    }
}

/// SAF's local feature aggregation (`[model.lfa]`; absent = off). See [`crate::lfa`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LfaConfig {
    /// K nearest neighbours per point.
    pub neighbours: usize,
    /// One entry per random halving.
    pub stages: Vec<LfaStageConfig>,
    /// Metres that divide the centroid-relative positions p_k and p_i of the local encoding
    /// and the point MLP's input (1 = the paper's raw metres). With raw metres a point's
    /// position (metres from the centroid) dwarfs its neighbour offsets (decimetres), so
    /// the first layer learns mostly where a point is; see docs/frustum.md.
    pub position_scale_m: f64,
    /// Metres that divide the neighbour offsets p_i − p_k and their length (1 = raw).
    pub offset_scale_m: f64,
    /// How LFA's features reach the PointNets (`none` = the paper's concatenation).
    pub feature_gate: LfaFeatureGate,
    /// How the PointNets' first layers draw the weights of the 3 pair coordinates.
    pub coordinate_init: CoordinateInit,
}

/// The starting weights of the pair coordinates' rows in each PointNet's first layer.
///
/// With LFA that layer has 3 + C inputs (C = 512 at the paper's size), and a linear layer
/// draws its weights at ±1/√fan-in, so `shared` (the default; the paper is silent) starts
/// the coordinate rows 13 times smaller than F-ConvNet's, whose layer has 3 inputs. A
/// batch norm follows, so the size itself does not change the function, but Adam moves
/// every weight by about the learning rate a step whatever its size, and the coordinates'
/// weights then turn over 13 times faster relative to their size than in F-ConvNet. `own`
/// draws those rows at their own fan-in (3), as F-ConvNet does, and the feature rows at
/// the layer's as before; with `feature_gate = "zero"` the network then starts as
/// F-ConvNet does, in distribution.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CoordinateInit {
    #[default]
    Shared,
    Own,
}

/// What stands between LFA's features f and the slice PointNets' first layers.
///
/// `none` is the paper (Eq. 10's output concatenated to each pair's coordinates as it
/// is). With LFA's 512 channels beside the 3 coordinates, a freshly initialised first
/// layer draws almost all of its input from f, and the full-size LFA row lost 10–12
/// points of 3D AP to F-ConvNet with a higher training loss (docs/frustum.md). `zero`
/// multiplies f by a learned per-channel scale started at 0 (as LayerScale and ReZero
/// start residual branches): the network starts as F-ConvNet on the same points, and
/// LFA's weights receive gradient as soon as a scale moves off zero. Not in the paper.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LfaFeatureGate {
    #[default]
    None,
    Zero,
}

/// The MLP widths of one LFA stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LfaStageConfig {
    /// MLP over each neighbour's relative-position encoding, max-pooled over the K.
    pub local: Vec<usize>,
    /// MLP over the point itself.
    pub point: Vec<usize>,
}

impl LfaStageConfig {
    pub fn out_channels(&self) -> usize {
        self.local.last().copied().unwrap_or(0) + self.point.last().copied().unwrap_or(0)
    }
}

impl Default for LfaConfig {
    /// Two halvings (4096 → 2048 → 1024 points), K = 16, 64 feature channels per point:
    /// the paper gives no widths; these keep LFA near a tenth of a training step here
    /// (3,355,113 parameters with the published F-ConvNet, 9.9% under the paper's; the SAF
    /// shipped until 2026-11-28 had them). [`LfaConfig::paper`] is the paper's size.
    fn default() -> Self {
        Self {
            neighbours: 16,
            stages: vec![
                LfaStageConfig {
                    local: vec![16, 32],
                    point: vec![32],
                },
                LfaStageConfig {
                    local: vec![32],
                    point: vec![32],
                },
            ],
            position_scale_m: 1.0,
            offset_scale_m: 1.0,
            feature_gate: LfaFeatureGate::None,
            coordinate_init: CoordinateInit::Shared,
        }
    }
}

impl LfaConfig {
    /// The widths the published configurations use (`configs/saf-*.toml`): SAF's network
    /// at the paper's size. The paper (He et al., Sensors 2022) gives LFA's structure
    /// (Eq. 9–10, two random halvings 4,096 → 1,024, K nearest neighbours) but no widths;
    /// its only constraint on them is the parameter count, 3,724,013 for Car, Pedestrian
    /// and Cyclist alike (Tables 4–6), 407,236 over F-ConvNet's 3,316,777. Nearly all of
    /// that has to be LFA's output width, because every LFA channel widens the first layer
    /// of the four PointNets it feeds (64 + 64 + 128 + 256 = 512 weights a channel).
    /// What we chose where the paper is silent: each MLP of Eq. 9–10 one shared layer, as
    /// RandLA-Net's position encoding (the module's model), and the width doubling from
    /// the first halving to the second as RandLA-Net's encoder does: 128 then 256, so
    /// every point carries 512 channels, the width of the PointNets' widest output.
    /// Car network: 3,716,521 parameters, −0.20% from the paper's (`fusiondet info`;
    /// docs/frustum.md has the other widths tried and why none can match exactly).
    /// `Default` keeps the CPU-sized widths the shipped SAF was trained with.
    pub fn paper() -> Self {
        Self {
            stages: vec![
                LfaStageConfig {
                    local: vec![128],
                    point: vec![128],
                },
                LfaStageConfig {
                    local: vec![256],
                    point: vec![256],
                },
            ],
            ..Self::default()
        }
    }

    /// Feature channels each surviving point carries into the PointNets.
    pub fn out_channels(&self) -> usize {
        self.stages.last().map_or(0, LfaStageConfig::out_channels)
    }
}

/// The architecture. Everything here determines the weights' shapes or their meaning.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModelConfig {
    /// Length of the class one-hot appended to every slice feature (Car, Pedestrian, Cyclist).
    pub num_classes: usize,
    /// Per-slice encoder.
    pub slice_encoder: SliceEncoderKind,
    /// FCAM's attention blocks (ignored by the plain PointNet).
    pub attention: AttentionConfig,
    /// SAF's local feature aggregation before the PointNets; `None` (no `[model.lfa]`)
    /// for F-ConvNet.
    pub lfa: Option<LfaConfig>,
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
    /// Car, Pedestrian, Cyclist): the box coder's, which the experiment configuration
    /// checks them against.
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
    /// SAF's joint 3D–2D projection loss weight μ (0 = off; SAF uses 0.1): smooth-L1 on the
    /// 2D box of the projected predicted box against the projected ground truth.
    pub projection_weight: f32,
}

/// The most channels a layer may have in a configuration.
pub const MAX_CHANNELS: usize = 4096;
/// The widest spatial-attention kernel (CBAM uses 7).
pub const MAX_SPATIAL_KERNEL: usize = 31;

impl LossConfig {
    /// Every weight and shape within what a loss can use: a focal γ of 1e19 overflows.
    pub fn validate(&self) -> Result<(), String> {
        let bad = |msg: String| Err(msg);
        let in_range = |v: f32, lo: f32, hi: f32| v.is_finite() && (lo..=hi).contains(&v);
        if !in_range(self.focal_alpha, 0.0, 1.0) {
            return bad(format!(
                "focal_alpha must be in [0, 1], not {}",
                self.focal_alpha
            ));
        }
        if !in_range(self.focal_gamma, 0.0, 10.0) {
            return bad(format!(
                "focal_gamma must be in [0, 10], not {}",
                self.focal_gamma
            ));
        }
        for (name, v) in [
            ("box_weight", self.box_weight),
            ("heading_residual_weight", self.heading_residual_weight),
            ("size_residual_weight", self.size_residual_weight),
            ("corner_weight", self.corner_weight),
            ("projection_weight", self.projection_weight),
        ] {
            if !in_range(v, 0.0, 1000.0) {
                return bad(format!("{name} must be in [0, 1000], not {v}"));
            }
        }
        for (name, v) in [
            ("center_delta", self.center_delta),
            ("residual_delta", self.residual_delta),
            ("corner_delta", self.corner_delta),
        ] {
            if !(in_range(v, 0.0, 100.0) && v > 0.0) {
                return bad(format!("{name} must be in (0, 100], not {v}"));
            }
        }
        Ok(())
    }
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
            projection_weight: 0.0,
        }
    }
}

/// F-ConvNet's KITTI size clusters as its reference implementation writes them for the
/// network (`dataset_info.py`, Car, Pedestrian, Cyclist), which every shipped checkpoint
/// stores: the KITTI class set's mean sizes to f32 precision (the Cyclist length is
/// 1.762824 here, 1.76282397 in the box coder).
#[allow(clippy::excessive_precision)]
pub const KITTI_SIZE_CLUSTERS: [[f32; 3]; 3] = [
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
            attention: AttentionConfig::default(),
            lfa: None,
            pointnet_widths: vec![
                vec![64, 64, 128],
                vec![64, 64, 128],
                vec![128, 128, 256],
                vec![256, 256, 512],
            ],
            fcn_channels: vec![128, 128, 256, 512],
            deconv_channels: 256,
            num_heading_bins: 12,
            size_clusters: KITTI_SIZE_CLUSTERS.to_vec(),
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

    /// The settings of every layer followed by batch norm.
    pub fn norm(&self) -> fusiondet_nn::NormConfig {
        fusiondet_nn::NormConfig {
            bias_before_norm: self.bias_before_norm,
            momentum: self.batch_norm_momentum,
            epsilon: self.batch_norm_epsilon,
        }
    }

    /// Input channels of the slice PointNets: relative coordinates plus LFA features.
    pub fn pointnet_input_channels(&self) -> usize {
        3 + self.lfa.as_ref().map_or(0, LfaConfig::out_channels)
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

    /// Checks the structural constraints the network relies on, and that every size is one
    /// a real network could use (a width of 100,000 would abort on allocation).
    pub fn validate(&self) -> Result<(), ModelError> {
        let bad = |msg: String| Err(ModelError::InvalidConfig(msg));
        let widths: [(&str, Vec<usize>); 3] = [
            ("pointnet_widths", self.pointnet_widths.concat()),
            ("fcn_channels", self.fcn_channels.clone()),
            ("deconv_channels", vec![self.deconv_channels]),
        ];
        for (name, values) in widths {
            if let Some(w) = values.into_iter().find(|&w| w > MAX_CHANNELS) {
                return bad(format!(
                    "{name}: at most {MAX_CHANNELS} channels a layer, not {w}"
                ));
            }
        }
        if self.num_heading_bins > 360 {
            return bad(format!(
                "num_heading_bins must be at most 360, not {}",
                self.num_heading_bins
            ));
        }
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
        if self.slice_encoder.uses_attention() {
            let a = &self.attention;
            if a.channel_reduction == 0
                || a.tanh_reduction == 0
                || a.spatial_kernel.is_multiple_of(2)
                || a.spatial_kernel > MAX_SPATIAL_KERNEL
            {
                return bad(format!(
                    "attention: reductions must be positive and spatial_kernel odd and at most \
                     {MAX_SPATIAL_KERNEL}"
                ));
            }
            if let Some(l) = a
                .after_layers
                .iter()
                .find(|&&l| self.pointnet_widths.iter().any(|w| l + 1 >= w.len()))
            {
                return bad(format!(
                    "attention.after_layers: layer {l} is not a hidden layer of every PointNet \
                     (attention goes after a hidden layer, before the last)"
                ));
            }
        }
        if let Some(lfa) = &self.lfa
            && (lfa.neighbours == 0
                || lfa.stages.is_empty()
                || lfa.stages.iter().any(|s| {
                    s.local.is_empty()
                        || s.point.is_empty()
                        || s.local.contains(&0)
                        || s.point.contains(&0)
                }))
        {
            return bad(
                "lfa: neighbours must be positive and every stage needs non-empty, positive \
                 `local` and `point` widths"
                    .into(),
            );
        }
        if let Some(lfa) = &self.lfa {
            for (key, v) in [
                ("position_scale_m", lfa.position_scale_m),
                ("offset_scale_m", lfa.offset_scale_m),
            ] {
                if !(v.is_finite() && v > 0.0) {
                    return bad(format!(
                        "lfa.{key} = {v}: must be a positive number of metres (1 = raw metres)"
                    ));
                }
            }
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
