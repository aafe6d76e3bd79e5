//! DASANet's shape: Voxel R-CNN's (for the LiDAR branch, the BEV network, the anchor
//! head and the heads' widths), the pseudo branch's input, which of the two modules are
//! on — the four rows of the paper's Table 4 — and the sizes the paper leaves open.
//!
//! The open sizes of the published configuration are chosen so that the parameter
//! counts land within 10% of Table 5 (see `Dasanet::param_rows` and docs/dasanet.md): RoI
//! features from C3 and C4 (and P3, P4) at 88 channels each (C = 176, N = 216), and
//! STCA's encoder 6 → 32 → 64 point MLP, 64-channel submanifold convolutions and a
//! 240-channel strided one over a 12³ RoI grid (F^A: 6³ × 480).
//!
//! Table 5's counts are nearly additive (26.2 + 30.8 − 55.2 = 1.8 M shared, about one
//! stage one), which fits a +STCA row whose head reads F^A alone, with no RoI grid
//! pooling; that is how the rows are built here: the head reads F^T with TDIS, F^A with
//! STCA, both concatenated with both.

use super::stca::StcaConfig;
use crate::voxel_rcnn::config::{PoolLevelConfig, VoxelRcnnNetConfig};
use serde::{Deserialize, Serialize};

/// Features of a pseudo voxel: the mean x, y, z and r, g, b (0–1) of its points.
pub const PSEUDO_VOXEL_FEATURES: usize = 6;

/// The four rows of the paper's ablation (Table 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AblationRow {
    /// Voxel R-CNN, LiDAR only.
    Baseline,
    Tdis,
    Stca,
    /// Both modules: DASANet.
    Dasanet,
}

impl AblationRow {
    pub const ALL: [AblationRow; 4] = [
        AblationRow::Baseline,
        AblationRow::Tdis,
        AblationRow::Stca,
        AblationRow::Dasanet,
    ];

    /// The paper's name of the row.
    pub fn label(self) -> &'static str {
        match self {
            AblationRow::Baseline => "baseline",
            AblationRow::Tdis => "+TDIS",
            AblationRow::Stca => "+STCA",
            AblationRow::Dasanet => "+TDIS +STCA",
        }
    }

    /// (TDIS, STCA) on.
    pub fn modules(self) -> (bool, bool) {
        match self {
            AblationRow::Baseline => (false, false),
            AblationRow::Tdis => (true, false),
            AblationRow::Stca => (false, true),
            AblationRow::Dasanet => (true, true),
        }
    }

    /// Table 5: parameters (millions), GFLOPs and frames/s on an RTX 3090.
    pub fn published_cost(self) -> (f64, f64, f64) {
        match self {
            AblationRow::Baseline => (6.9, 22.7, 25.2),
            AblationRow::Tdis => (26.2, 28.0, 14.5),
            AblationRow::Stca => (30.8, 27.9, 12.7),
            AblationRow::Dasanet => (55.2, 30.9, 10.5),
        }
    }
}

/// What DASANet adds to Voxel R-CNN: which modules are on and the sizes the paper leaves
/// open (the `[dasanet.modules]` table of a configuration file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DasanetModules {
    pub tdis: bool,
    pub stca: bool,
    pub stca_shape: StcaConfig,
    /// λ1, λ2 of Eq. 16: the auxiliary heads on F^T and on F^A (present only when both
    /// modules are, whose optimisation they balance).
    pub aux_weights: [f64; 2],
    /// How TDIS's weights start (the paper does not say).
    pub tdis_init: TdisInit,
    /// How TDIS's supplement joins F^S (Eq. 3, 5, 7 add it plainly).
    pub tdis_form: TdisForm,
}

impl Default for DasanetModules {
    fn default() -> Self {
        Self {
            tdis: true,
            stca: true,
            stca_shape: StcaConfig::default(),
            aux_weights: [1.0, 1.0],
            tdis_init: TdisInit::FanIn,
            tdis_form: TdisForm::Plain,
        }
    }
}

/// How TDIS adds its supplement S = A^Ch F^Sp + F^Ch A^Sp + F^Go A to F^S.
///
/// `plain` is Eq. 3, 5 and 7 as printed: F^T = F^S + S. S is three weighted sums over
/// N·C inputs each, and under AdamW every weight moves by about the learning rate a
/// step, so S can outgrow F^S within a few hundred steps whatever the start (issue 34).
/// The paper is silent on S's scale; `gated` fixes it: F^T = F^S + tanh(g) · S ·
/// RMS(F^S) / RMS(S), RMS per RoI over its N·C features and g one learned scalar
/// starting at 0. The supplement is then exactly |tanh g| times F^S's size, so
/// RMS(F^T − F^S) / RMS(F^S) ≤ 1 at every step; TDIS starts as the identity, like
/// `tdis_init = "zero"`, while W^Sp, W^Ch and W^Go start at fan-in values so that S has a
/// direction for g to learn along (hence `gated` refuses zero-started weights). A gate
/// rather than a normalisation alone because a fixed-size disturbance would sit on F^S
/// from the first step whether it helps or not.
///
/// `bypass` is a measurement, not a model: F^T = F^S, with the pseudo branch, the pooling
/// of F^P and everything else of the +TDIS row in place, so a run with it isolates what
/// TDIS itself does to the row.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TdisForm {
    #[default]
    Plain,
    Gated,
    Bypass,
}

/// The starting weights of TDIS's W^Sp, W^Ch and W^Go.
///
/// `fan-in` draws them like a linear layer's (±1/√(N·C)); the three sums then add to
/// every feature a term whose variance is about that of F^D = F^P − F^S, so the head
/// first sees F^S under a disturbance as large as itself. `zero` starts TDIS as the
/// identity (F^T = F^S), as residual branches are often started; W still receives a
/// gradient from the first step, since ∂F^T/∂W is F^D, not W.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TdisInit {
    FanIn,
    Zero,
}

/// The whole network's shape: Voxel R-CNN's (LiDAR branch, BEV network, anchor head, head
/// widths; its `roi.levels` are the levels F^S and F^P pool from) and the modules.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DasanetNetConfig {
    pub voxel_rcnn: VoxelRcnnNetConfig,
    pub modules: DasanetModules,
}

impl Default for DasanetNetConfig {
    fn default() -> Self {
        Self::published(AblationRow::Dasanet)
    }
}

/// Voxel R-CNN's published shape with the RoI grid pooled from C3 and C4 at 88 channels
/// each, as DASANet's published rows use it.
pub fn published_voxel_rcnn() -> VoxelRcnnNetConfig {
    let mut voxel_rcnn = VoxelRcnnNetConfig::default();
    let level = |stage, radius| PoolLevelConfig {
        stage,
        mid_channels: 88,
        out_channels: 88,
        query_range: [4, 4, 4],
        radius,
        samples: 16,
    };
    voxel_rcnn.roi.levels = vec![level(3, 0.8), level(4, 1.6)];
    voxel_rcnn
}

impl DasanetNetConfig {
    /// The published-size network of a row with at least one module (the baseline row is
    /// Voxel R-CNN itself, the `voxel_rcnn` family).
    pub fn published(row: AblationRow) -> Self {
        let (tdis, stca) = row.modules();
        Self {
            voxel_rcnn: published_voxel_rcnn(),
            modules: DasanetModules {
                tdis,
                stca,
                ..DasanetModules::default()
            },
        }
    }

    /// Which ablation row this shape is.
    pub fn row(&self) -> AblationRow {
        match (self.modules.tdis, self.modules.stca) {
            (false, false) => AblationRow::Baseline,
            (true, false) => AblationRow::Tdis,
            (false, true) => AblationRow::Stca,
            (true, true) => AblationRow::Dasanet,
        }
    }

    /// Whether the auxiliary heads exist (both modules on).
    pub fn has_aux_heads(&self) -> bool {
        self.modules.tdis && self.modules.stca
    }

    /// RoI grid locations N.
    pub fn grid_locations(&self) -> usize {
        self.voxel_rcnn.roi.grid_size.pow(3)
    }

    /// RoI feature channels C (the pooling levels' outputs together).
    pub fn roi_channels(&self) -> usize {
        self.voxel_rcnn
            .roi
            .levels
            .iter()
            .map(|l| l.out_channels)
            .sum()
    }

    /// Width of the flattened F^T.
    pub fn grid_width(&self) -> usize {
        self.roi_channels() * self.grid_locations()
    }

    /// Width of the detection head's input: F^T with TDIS, F^A with STCA.
    pub fn head_input(&self) -> usize {
        let on = |b: bool, w: usize| if b { w } else { 0 };
        let m = &self.modules;
        on(m.tdis, self.grid_width()) + on(m.stca, m.stca_shape.flattened_width())
    }

    pub fn validate(&self) -> Result<(), String> {
        self.modules.validate()?;
        self.voxel_rcnn.validate()
    }
}

impl DasanetModules {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.tdis || self.stca) {
            return Err(
                "[dasanet.modules]: neither tdis nor stca is on; the baseline row is Voxel R-CNN \
                 (kind = \"voxel_rcnn\")"
                    .into(),
            );
        }
        if self.tdis_form == TdisForm::Gated && self.tdis_init == TdisInit::Zero {
            return Err(
                "[dasanet.modules]: tdis_form = \"gated\" with tdis_init = \"zero\" never \
                 learns (a zero supplement gives the gate no gradient and a shut gate gives the \
                 weights none); use tdis_init = \"fan-in\""
                    .into(),
            );
        }
        self.stca_shape.validate()?;
        if self
            .aux_weights
            .iter()
            .any(|w| !(w.is_finite() && *w >= 0.0))
        {
            return Err(format!(
                "[dasanet.modules] aux_weights {:?} must be finite and ≥ 0",
                self.aux_weights
            ));
        }
        Ok(())
    }
}
