//! FCAM's attention inside the slice PointNets: CBAM (Woo et al., ECCV 2018) and the
//! improved CBAM of Li, Xie & Shin (Signals 2021), on ragged (point, sub-frustum) pairs.
//!
//! The feature map CBAM sees is one frustum's [C, sub-frustums, points] map of a scale
//! (F-ConvNet's PointNet input is [B, C, L, N]):
//! - channel attention `σ(MLP(AvgPool F) + MLP(MaxPool F))`, pools over the frustum's
//!   real pairs, shared MLP C → C/r → C with ReLU (r = 16); the improved form adds a
//!   parallel MLP with tanh (r = 32) and sums all four terms before the sigmoid;
//! - spatial attention `σ(conv7×7([MaxPool_c F; AvgPool_c F]))` over the
//!   (sub-frustum × point) grid, point j of a sub-frustum being its j-th member in index
//!   order and empty cells zero (the padded map the published PointNet pools over).
//!
//! The attended features `M_s ⊙ (M_c ⊙ F)` replace F as the next layer's input.

use crate::config::AttentionConfig;
use crate::inputs::AttentionIndex;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{Linear, LinearConfig, PaddingConfig2d};
use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;
use burn::tensor::activation::{relu, sigmoid, tanh};

/// A channel MLP C → C/r → C without biases (CBAM's shared MLP).
#[derive(Module, Debug)]
pub struct ChannelMlp {
    pub reduce: Linear,
    pub expand: Linear,
    /// tanh instead of ReLU between the two layers (the improved CBAM's second branch).
    #[module(skip)]
    use_tanh: bool,
}

impl ChannelMlp {
    pub fn new(channels: usize, reduction: usize, use_tanh: bool, device: &Device) -> Self {
        let hidden = (channels / reduction.max(1)).max(1);
        Self {
            reduce: LinearConfig::new(channels, hidden)
                .with_bias(false)
                .init(device),
            expand: LinearConfig::new(hidden, channels)
                .with_bias(false)
                .init(device),
            use_tanh,
        }
    }

    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let h = self.reduce.forward(x);
        let h = if self.use_tanh { tanh(h) } else { relu(h) };
        self.expand.forward(h)
    }
}

/// One CBAM block (channel then spatial attention) for C-channel pair features.
#[derive(Module, Debug)]
pub struct Cbam {
    pub channel: ChannelMlp,
    /// The improved CBAM's tanh branch.
    pub channel_tanh: Option<ChannelMlp>,
    /// 2 → 1 channels, k × k, no bias.
    pub spatial: Conv2d,
}

impl Cbam {
    pub fn new(channels: usize, improved: bool, config: &AttentionConfig, device: &Device) -> Self {
        let k = config.spatial_kernel;
        Self {
            channel: ChannelMlp::new(channels, config.channel_reduction, false, device),
            channel_tanh: improved
                .then(|| ChannelMlp::new(channels, config.tanh_reduction, true, device)),
            spatial: Conv2dConfig::new([2, 1], [k, k])
                .with_padding(PaddingConfig2d::Explicit(k / 2, k / 2, k / 2, k / 2))
                .with_bias(false)
                .init(device),
        }
    }

    /// `x`: pair features [pairs, C] (non-negative: they follow a ReLU) → attended features.
    pub fn forward(&self, x: Tensor<2>, index: &AttentionIndex) -> Tensor<2> {
        let x = x.clone() * self.channel_weights(x, index);
        let s = self.spatial_weights(x.clone(), index);
        x * s
    }

    /// M_c per pair, [pairs, C].
    fn channel_weights(&self, x: Tensor<2>, index: &AttentionIndex) -> Tensor<2> {
        let [_, c] = x.dims();
        let device = x.device();
        let sum = Tensor::<2>::zeros([index.frustums, c], &device).select_assign(
            0,
            index.pair_frustum.clone(),
            x.clone(),
            IndexingUpdateOp::Add,
        );
        let avg = sum / index.frustum_counts.clone();
        let max = index.frustum_pool.max_pool(x);
        let mut logits = self.channel.forward(avg.clone()) + self.channel.forward(max.clone());
        if let Some(t) = &self.channel_tanh {
            logits = logits + t.forward(avg) + t.forward(max);
        }
        sigmoid(logits).select(0, index.pair_frustum.clone())
    }

    /// M_s per pair, [pairs, 1].
    fn spatial_weights(&self, x: Tensor<2>, index: &AttentionIndex) -> Tensor<2> {
        let device = x.device();
        let maps = Tensor::cat(vec![x.clone().max_dim(1), x.mean_dim(1)], 1); // [P, 2]
        let (b, l, n) = (index.frustums, index.slices_per_frustum, index.cap);
        let grid = Tensor::cat(vec![maps, Tensor::zeros([1, 2], &device)], 0)
            .select(0, index.grid_cell_pair.clone())
            .reshape([b, l, n, 2])
            .permute([0, 3, 1, 2]);
        let att = self.spatial.forward(grid).reshape([b * l * n, 1]);
        sigmoid(att.select(0, index.pair_grid_cell.clone()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{ModelConfig, SliceEncoderKind};
    use crate::inputs::BatchInputs;
    use crate::synthetic::{SyntheticSpec, synthetic_batch};

    fn host(t: Tensor<2>) -> Vec<f32> {
        t.try_into_vec_as::<f32>().unwrap()
    }

    /// y = x · W for a bias-free `Linear` (burn stores W as [in, out]).
    fn linear(x: &[f32], layer: &Linear) -> Vec<f32> {
        let [d_in, d_out] = layer.weight.val().dims();
        let w = layer.weight.val().try_into_vec_as::<f32>().unwrap();
        (0..d_out)
            .map(|o| (0..d_in).map(|i| x[i] * w[i * d_out + o]).sum())
            .collect()
    }

    fn mlp(x: &[f32], m: &ChannelMlp) -> Vec<f32> {
        let h: Vec<f32> = linear(x, &m.reduce)
            .into_iter()
            .map(|v| if m.use_tanh { v.tanh() } else { v.max(0.0) })
            .collect();
        linear(&h, &m.expand)
    }

    fn sig(v: f32) -> f32 {
        1.0 / (1.0 + (-v).exp())
    }

    /// CBAM computed loop by loop on the host: per-frustum channel pooling over the real
    /// pairs, then a k × k cross-correlation over each frustum's (slice × member) grid.
    fn reference(
        x: &[f32],
        c: usize,
        cbam: &Cbam,
        slice_start: &[usize],
        l: usize,
        cap: usize,
    ) -> Vec<f32> {
        let frustums = (slice_start.len() - 1) / l;
        let mut out = x.to_vec();
        for f in 0..frustums {
            let (a, b) = (slice_start[f * l], slice_start[(f + 1) * l]);
            let n = (b - a).max(1) as f32;
            let mut avg = vec![0f32; c];
            let mut max = vec![0f32; c];
            for p in a..b {
                for ch in 0..c {
                    avg[ch] += x[p * c + ch] / n;
                    max[ch] = max[ch].max(x[p * c + ch]);
                }
            }
            let mut logit: Vec<f32> = mlp(&avg, &cbam.channel)
                .iter()
                .zip(mlp(&max, &cbam.channel))
                .map(|(u, v)| u + v)
                .collect();
            if let Some(t) = &cbam.channel_tanh {
                for (ch, (u, v)) in mlp(&avg, t).iter().zip(mlp(&max, t)).enumerate() {
                    logit[ch] += u + v;
                }
            }
            for p in a..b {
                for ch in 0..c {
                    out[p * c + ch] *= sig(logit[ch]);
                }
            }
        }
        // Spatial attention over [frustum][2][slice][member].
        let w = cbam.spatial.weight.val().try_into_vec_as::<f32>().unwrap();
        let k = cbam.spatial.weight.val().dims()[2];
        let r = (k / 2) as isize;
        let mut maps = vec![0f32; frustums * 2 * l * cap];
        let mut cell_of = vec![0usize; *slice_start.last().unwrap()];
        for sl in 0..frustums * l {
            let (f, s) = (sl / l, sl % l);
            for (j, p) in (slice_start[sl]..slice_start[sl + 1]).enumerate() {
                let row = &out[p * c..(p + 1) * c];
                maps[((f * 2) * l + s) * cap + j] = row.iter().cloned().fold(f32::MIN, f32::max);
                maps[((f * 2 + 1) * l + s) * cap + j] = row.iter().sum::<f32>() / c as f32;
                cell_of[p] = sl * cap + j;
            }
        }
        for (p, &cell) in cell_of.iter().enumerate() {
            let (f, s, j) = (cell / (l * cap), (cell / cap) % l, cell % cap);
            let mut acc = 0f32;
            for ch in 0..2 {
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (y, xx) = (s as isize + dy, j as isize + dx);
                        if y < 0 || xx < 0 || y >= l as isize || xx >= cap as isize {
                            continue;
                        }
                        let v = maps[((f * 2 + ch) * l + y as usize) * cap + xx as usize];
                        acc += v * w[(ch * k + (dy + r) as usize) * k + (dx + r) as usize];
                    }
                }
            }
            for ch in 0..c {
                out[p * c + ch] *= sig(acc);
            }
        }
        out
    }

    #[test]
    fn ragged_cbam_matches_a_loop_by_loop_reference() {
        for kind in [SliceEncoderKind::Cbam, SliceEncoderKind::ImprovedCbam] {
            let config = ModelConfig {
                slice_encoder: kind,
                ..ModelConfig::tiny()
            };
            let device = Device::flex();
            let batch = synthetic_batch(&SyntheticSpec::tiny(3), 7);
            let inputs = BatchInputs::new(&batch, &config, &device).unwrap();
            let scale = &inputs.scales[1];
            let index = scale.attention.as_ref().expect("attention index");
            let c = 16;
            device.seed(3);
            let cbam = Cbam::new(
                c,
                kind == SliceEncoderKind::ImprovedCbam,
                &config.attention,
                &device,
            );
            let x = Tensor::<2>::random(
                [scale.num_pairs, c],
                burn::tensor::Distribution::Uniform(0.0, 2.0),
                &device,
            );
            let got = host(cbam.forward(x.clone(), index));
            let slice_start = scale.slice_start();
            let want = reference(
                &host(x),
                c,
                &cbam,
                slice_start,
                scale.slices_per_frustum,
                scale.cap,
            );
            assert_eq!(got.len(), want.len());
            let worst = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            assert!(worst < 1e-5, "{kind:?}: largest difference {worst}");
        }
    }
}
