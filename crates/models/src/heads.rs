//! Per-position heads: two-way classification and the box regression, as `Linear` layers on
//! [B · positions, channels].
//!
//! Regression layout per position (see [`RegressionLayout`]), F-ConvNet's order:
//! 3 centre offsets (metres, added to the position's slice centre) · NH heading-bin scores ·
//! NH heading residuals normalised by half the bin width (π / NH), so ±1 spans a bin ·
//! NS size-cluster scores · NS × 3 size residuals (l, w, h) normalised by the cluster's
//! mean size (size = mean · (1 + residual)), as in `BatchTargets`.

use crate::config::ModelConfig;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

/// Offsets of the regression channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RegressionLayout {
    pub heading_bins: usize,
    pub size_clusters: usize,
}

impl RegressionLayout {
    pub fn new(config: &ModelConfig) -> Self {
        Self {
            heading_bins: config.num_heading_bins,
            size_clusters: config.size_clusters.len(),
        }
    }
    pub fn center(&self) -> std::ops::Range<usize> {
        0..3
    }
    pub fn heading_scores(&self) -> std::ops::Range<usize> {
        3..3 + self.heading_bins
    }
    pub fn heading_residuals(&self) -> std::ops::Range<usize> {
        3 + self.heading_bins..3 + 2 * self.heading_bins
    }
    pub fn size_scores(&self) -> std::ops::Range<usize> {
        let s = 3 + 2 * self.heading_bins;
        s..s + self.size_clusters
    }
    /// Cluster c's (l, w, h) residuals are at `start + 3c ..start + 3c + 3`.
    pub fn size_residuals(&self) -> std::ops::Range<usize> {
        let s = 3 + 2 * self.heading_bins + self.size_clusters;
        s..s + 3 * self.size_clusters
    }
    pub fn len(&self) -> usize {
        3 + 2 * self.heading_bins + 4 * self.size_clusters
    }
    pub fn is_empty(&self) -> bool {
        false
    }
}

#[derive(Module, Debug)]
pub struct Heads {
    pub cls: Linear,
    pub reg: Linear,
}

impl Heads {
    pub fn new(config: &ModelConfig, device: &Device) -> Self {
        let c = config.head_channels();
        Self {
            cls: LinearConfig::new(c, 2).init(device),
            reg: LinearConfig::new(c, config.regression_channels()).init(device),
        }
    }

    /// [B, C, P] → (classification logits [B, P, 2], regression [B, P, R]).
    pub fn forward(&self, x: Tensor<3>) -> (Tensor<3>, Tensor<3>) {
        let [b, c, p] = x.dims();
        let x = x.swap_dims(1, 2).reshape([b * p, c]);
        let cls = fusiondet_nn::linear::linear(&self.cls, x.clone());
        let reg = fusiondet_nn::linear::linear(&self.reg, x);
        let r = reg.dims()[1];
        (cls.reshape([b, p, 2]), reg.reshape([b, p, r]))
    }
}
