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
use burn::tensor::activation::{relu, sigmoid, tanh};
use fusiondet_nn::host_max::{flex_max, host_path};
use rayon::prelude::*;

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
        if host_path(&x) {
            self.forward_on_host(x, index)
        } else {
            self.forward_by_tensors(x, index)
        }
    }

    /// The spatial attention's k × k cross-correlation (2 → 1 channels, zero padding
    /// k / 2) of the [B, 2, L, N] grid, row by row: burn-flex lowers a convolution to an
    /// im2col matrix of [B · L · N, 2 · k²] (28 MB for FCAM's finest scale and 8
    /// frustums) written and read again for a product with one output column.
    fn spatial_logits_on_host(&self, grid: &[f32], b: usize, l: usize, n: usize) -> Vec<f32> {
        let weight = self.spatial.weight.val();
        let [_, channels, k, _] = weight.dims();
        let w = weight
            .into_data()
            .try_into_vec::<f32>()
            .expect("f32 convolution weights");
        let bias = self.spatial.bias.as_ref().map_or(0.0, |bias| {
            bias.val()
                .into_data()
                .try_into_vec::<f32>()
                .expect("f32 bias")[0]
        });
        let r = (k / 2) as isize;
        let mut out = vec![bias; b * l * n];
        out.par_chunks_mut(n).enumerate().for_each(|(row, dst)| {
            let (f, s) = (row / l, (row % l) as isize);
            for ch in 0..channels {
                for dy in 0..k {
                    let y = s + dy as isize - r;
                    if y < 0 || y >= l as isize {
                        continue;
                    }
                    let src = &grid[((f * channels + ch) * l + y as usize) * n..][..n];
                    for dx in 0..k {
                        let wv = w[(ch * k + dy) * k + dx];
                        let shift = dx as isize - r;
                        let (j0, j1) = (
                            (-shift).max(0) as usize,
                            (n as isize - shift).min(n as isize) as usize,
                        );
                        for (d, &v) in dst[j0..j1]
                            .iter_mut()
                            .zip(&src[(j0 as isize + shift) as usize..])
                        {
                            *d += wv * v;
                        }
                    }
                }
            }
        });
        out
    }

    /// Burn's operations: differentiable, on any backend.
    fn forward_by_tensors(&self, x: Tensor<2>, index: &AttentionIndex) -> Tensor<2> {
        let x = x.clone() * self.channel_weights(x, index);
        let s = self.spatial_weights(x.clone(), index);
        x * s
    }

    /// Inference on the flex CPU device, the same maps computed in three passes over the
    /// pair rows, in place: the frustums' sums and maxima; the channel weights applied
    /// with each row's max and mean taken; the spatial weights applied. The tensor path
    /// gathers [pairs, C] weight maps, scatter-adds and reduces in separate passes, and
    /// FCAM spent about a sixth of its forward pass there. The two MLPs still run as burn
    /// operations on their small inputs; the 7 × 7 convolution runs on the host too
    /// (`spatial_logits_on_host`). Rounding differs from the tensor path in the order of
    /// the row sums and of the convolution's products.
    fn forward_on_host(&self, x: Tensor<2>, index: &AttentionIndex) -> Tensor<2> {
        let [_, c] = x.dims();
        let device = x.device();
        let (b, l, n) = (index.frustums, index.slices_per_frustum, index.cap);
        let pool = &index.frustum_pool;
        let mut data = x.into_data();
        let rows = data
            .as_mut_slice::<f32>()
            .expect("an f32 tensor on the flex device");
        // Channel attention: per frustum, the mean and max over its pairs.
        let mut avg = vec![0f32; b * c];
        let mut max = vec![0f32; b * c];
        avg.par_chunks_mut(c)
            .zip(max.par_chunks_mut(c))
            .enumerate()
            .for_each(|(f, (sum, top))| {
                let (start, count) = (pool.starts[f], pool.counts[f]);
                if count == 0 {
                    return;
                }
                let frustum = &rows[start * c..(start + count) * c];
                top.copy_from_slice(&frustum[..c]);
                for row in frustum.chunks_exact(c) {
                    for ((s, t), &v) in sum.iter_mut().zip(top.iter_mut()).zip(row) {
                        *s += v;
                        *t = flex_max(*t, v);
                    }
                }
                let divisor = count as f32;
                sum.iter_mut().for_each(|s| *s /= divisor);
            });
        let host_tensor = |v: Vec<f32>, shape: [usize; 2]| {
            Tensor::<2>::from_data(TensorData::new(v, shape), &device)
        };
        let (avg, max) = (host_tensor(avg, [b, c]), host_tensor(max, [b, c]));
        let mut logits = self.channel.forward(avg.clone()) + self.channel.forward(max.clone());
        if let Some(t) = &self.channel_tanh {
            logits = logits + t.forward(avg) + t.forward(max);
        }
        let weights = sigmoid(logits)
            .into_data()
            .try_into_vec::<f32>()
            .expect("f32 channel weights");
        // Apply them, taking each row's max and mean over channels for the spatial grid
        // [B, 2, L, N] (empty cells stay zero).
        let mut frustum_of_row = Vec::with_capacity(rows.len() / c.max(1));
        for (f, &count) in pool.counts.iter().enumerate() {
            frustum_of_row.extend(std::iter::repeat_n(f, count));
        }
        assert_eq!(
            frustum_of_row.len() * c,
            rows.len(),
            "the frustums' pairs are contiguous and cover every row"
        );
        let mut maps = vec![[0f32; 2]; frustum_of_row.len()];
        rows.par_chunks_mut(c)
            .zip(maps.par_iter_mut())
            .zip(frustum_of_row.par_iter())
            .for_each(|((row, map), &f)| {
                row.iter_mut()
                    .zip(&weights[f * c..(f + 1) * c])
                    .for_each(|(v, w)| *v *= w);
                *map = [lanes_max(row), lanes_sum(row) / c as f32];
            });
        let mut grid = vec![0f32; b * 2 * l * n];
        for (map, &cell) in maps.iter().zip(&index.pair_grid_cell_host) {
            let (slice, j) = (cell as usize / n, cell as usize % n);
            let (f, s) = (slice / l, slice % l);
            grid[((f * 2) * l + s) * n + j] = map[0];
            grid[((f * 2 + 1) * l + s) * n + j] = map[1];
        }
        let spatial = self.spatial_logits_on_host(&grid, b, l, n);
        rows.par_chunks_mut(c)
            .zip(index.pair_grid_cell_host.par_iter())
            .for_each(|(row, &cell)| {
                let s = 1.0 / (1.0 + (-spatial[cell as usize]).exp());
                row.iter_mut().for_each(|v| *v *= s);
            });
        Tensor::from_data(data, &device)
    }

    /// M_c per pair, [pairs, C].
    fn channel_weights(&self, x: Tensor<2>, index: &AttentionIndex) -> Tensor<2> {
        let sum = index.pair_frustum.sum_by_source(x.clone());
        let avg = sum / index.frustum_counts.clone();
        let max = index.frustum_pool.max_pool(x);
        let mut logits = self.channel.forward(avg.clone()) + self.channel.forward(max.clone());
        if let Some(t) = &self.channel_tanh {
            logits = logits + t.forward(avg) + t.forward(max);
        }
        index.pair_frustum.gather(sigmoid(logits))
    }

    /// M_s per pair, [pairs, 1].
    fn spatial_weights(&self, x: Tensor<2>, index: &AttentionIndex) -> Tensor<2> {
        let maps = Tensor::cat(vec![x.clone().max_dim(1), x.mean_dim(1)], 1); // [P, 2]
        let (b, l, n) = (index.frustums, index.slices_per_frustum, index.cap);
        // Empty cells read the gather's zero row.
        let grid = index
            .grid_cell_pair
            .gather(maps)
            .reshape([b, l, n, 2])
            .permute([0, 3, 1, 2]);
        let att = self.spatial.forward(grid).reshape([b * l * n, 1]);
        sigmoid(index.pair_grid_cell.gather(att))
    }
}

/// Max of a row in eight lanes (so that it vectorises); NaN-free rows only, as CBAM's
/// inputs follow a ReLU.
fn lanes_max(row: &[f32]) -> f32 {
    let mut lanes = [f32::NEG_INFINITY; 8];
    let chunks = row.chunks_exact(8);
    let tail = chunks.remainder();
    for chunk in chunks {
        for (m, &v) in lanes.iter_mut().zip(chunk) {
            *m = if v > *m { v } else { *m };
        }
    }
    lanes
        .into_iter()
        .chain(tail.iter().copied())
        .fold(f32::NEG_INFINITY, f32::max)
}

/// Sum of a row in eight lanes (so that it vectorises).
fn lanes_sum(row: &[f32]) -> f32 {
    let mut lanes = [0f32; 8];
    let chunks = row.chunks_exact(8);
    let tail = chunks.remainder();
    for chunk in chunks {
        for (s, &v) in lanes.iter_mut().zip(chunk) {
            *s += v;
        }
    }
    lanes.iter().sum::<f32>() + tail.iter().sum::<f32>()
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
            assert!(host_path(&x), "the test runs the host path");
            let on_host = host(cbam.forward(x.clone(), index));
            let by_tensors = host(cbam.forward_by_tensors(x.clone(), index));
            let slice_start = scale.slice_start();
            let want = reference(
                &host(x),
                c,
                &cbam,
                slice_start,
                scale.slices_per_frustum,
                scale.cap,
            );
            for (path, got) in [("host", on_host), ("tensors", by_tensors)] {
                assert_eq!(got.len(), want.len());
                let worst = got
                    .iter()
                    .zip(&want)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0f32, f32::max);
                assert!(
                    worst < 1e-5,
                    "{kind:?} by {path}: largest difference {worst}"
                );
            }
        }
    }
    /// In training on a GPU CBAM's gathers differentiate by their readers (`RowGather`):
    /// the improved CBAM's output and the gradients of its input and spatial kernel on wgpu
    /// are the CPU's within rounding.
    #[cfg(feature = "wgpu")]
    #[test]
    fn training_gradients_on_wgpu_match_the_cpu() {
        use crate::device_test_support::{assert_close, upstream};
        let Some(gpu) = fusiondet_nn::cube::working_wgpu_device("CBAM's gathers on a GPU") else {
            return;
        };
        let config = ModelConfig {
            slice_encoder: SliceEncoderKind::ImprovedCbam,
            ..ModelConfig::tiny()
        };
        let batch = synthetic_batch(&SyntheticSpec::tiny(3), 7);
        let c = 16;
        let cpu = Device::flex().autodiff();
        let cbam = Cbam::new(c, true, &config.attention, &cpu);
        let run = |device: &Device| {
            let inputs = BatchInputs::new(&batch, &config, device).unwrap();
            let scale = &inputs.scales[1];
            let index = scale.attention.as_ref().expect("attention index");
            let cbam = cbam.clone().fork(device);
            let values: Vec<f32> = (0..scale.num_pairs * c)
                .map(|v| ((v * 37) % 101) as f32 / 50.0)
                .collect();
            let x = Tensor::<2>::from_data(TensorData::new(values, [scale.num_pairs, c]), device)
                .require_grad();
            let y = cbam.forward(x.clone(), index);
            let grads = (y.clone() * upstream(y.dims(), device)).sum().backward();
            [
                y.try_into_vec_as::<f32>().unwrap(),
                x.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap(),
                cbam.spatial
                    .weight
                    .grad(&grads)
                    .unwrap()
                    .try_into_vec_as::<f32>()
                    .unwrap(),
            ]
        };
        let want = run(&cpu);
        assert!(
            want[1].iter().any(|&g| g != 0.0),
            "a gradient reaches the input"
        );
        let got = run(&gpu.autodiff());
        for (what, (got, want)) in ["output", "input gradient", "spatial kernel gradient"]
            .iter()
            .zip(got.iter().zip(&want))
        {
            assert_close(got, want, 1e-3, what);
        }
    }
}
