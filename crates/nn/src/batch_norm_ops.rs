//! Training batch norm as custom operations on the flex CPU device, in two layouts: over the
//! rows of [rows, C] point features ([`NormLayout::Rows`]: PointNets, sparse convolutions, the
//! RoI pool) and over every axis but the second of channels-first maps ([`NormLayout::Maps`]:
//! [B, C, H, W] BEV maps, the frustum FCN's [B, C, L]).
//!
//! Why: burn 0.22's generic training batch norm swaps the batch and channel axes and reshapes
//! to [C, B·…] twice forward (mean, then the centred squares) and twice backward (the output
//! gradient, and its product with the normalised input) — for point features a transpose of
//! the whole [rows, C] tensor each time, for maps with a batch of more than one a full copy —
//! on top of about eight element-wise passes each way. Here the statistics are read where they
//! lie in two passes, the output written in one, and the backward reads once for its two sums
//! and writes once. Sums are f64 and reduced in a fixed order (row blocks in block order;
//! channels each on their own), so the result does not depend on the number of threads.
//!
//! The same `#[backend_extension]` route as [`crate::ragged`]; [`crate::norm::norm_rows`] and
//! [`crate::norm::norm_maps`] pick this path (training on the flex device) or
//! `BatchNorm::forward`.

use crate::buffers::par_chunks_filled;
use crate::ragged::{dims2, flex_tensor, values};
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, Flex, backend_extension};
use burn::prelude::*;
use rayon::prelude::*;
use std::sync::Arc;

/// Which axes a batch norm's statistics run over.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NormLayout {
    /// [rows, C]: over the rows.
    Rows,
    /// [B, C, …]: over the batch and every axis after the channels.
    Maps,
}

/// The custom operation (see the module's documentation).
#[backend_extension(Flex, Autodiff)]
pub trait BatchNormOps: Backend {
    /// Training batch norm of `x` in `layout`, followed by a ReLU when `relu`: the output,
    /// and the batch's per-channel mean and biased variance ([C] each, constants).
    fn batch_norm_train_fused(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
        layout: NormLayout,
        relu: bool,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

/// [`BatchNormOps::batch_norm_train_fused`] on tensors on the flex device: (output, batch
/// mean, batch variance).
pub fn batch_norm_train<const D: usize>(
    x: Tensor<D>,
    gamma: Tensor<1>,
    beta: Tensor<1>,
    epsilon: f64,
    layout: NormLayout,
    relu: bool,
) -> (Tensor<D>, Tensor<1>, Tensor<1>) {
    let (out, mean, variance) = <Dispatch as BatchNormOps>::batch_norm_train_fused(
        x.into_dispatch(),
        gamma.into_dispatch(),
        beta.into_dispatch(),
        epsilon,
        layout,
        relu,
    );
    (
        Tensor::from_dispatch(out),
        Tensor::from_dispatch(mean),
        Tensor::from_dispatch(variance),
    )
}

/// (output, batch mean, batch variance) in `layout`, the output through a ReLU when `relu`.
fn forward(
    x: &FlexTensor,
    gamma: &FlexTensor,
    beta: &FlexTensor,
    epsilon: f64,
    layout: NormLayout,
    relu: bool,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    let activation = if relu { flex_relu } else { identity };
    match layout {
        NormLayout::Rows => rows_forward(x, gamma, beta, epsilon, activation),
        NormLayout::Maps => maps_forward(x, gamma, beta, epsilon, activation),
    }
}

fn identity(v: f32) -> f32 {
    v
}

/// flex's ReLU to the bit: NaN passes, zero and below give +0.
fn flex_relu(v: f32) -> f32 {
    if v.is_nan() || v > 0.0 { v } else { 0.0 }
}

/// The output gradient through the ReLU of a fused norm + ReLU (flex's `relu_backward`:
/// kept where the ReLU's output is positive or NaN), from that output recomputed as the
/// forward pass computed it, `(x − mean)·scale + β`; without a ReLU the gradient itself.
#[derive(Clone, Copy)]
struct ReluGate<'a> {
    /// (scale = γ/σ, β) per channel, when the norm is followed by a ReLU.
    affine: Option<(&'a [f32], &'a [f32])>,
    mean: &'a [f32],
}

impl ReluGate<'_> {
    #[inline]
    fn gate(&self, ch: usize, x: f32, g: f32) -> f32 {
        match self.affine {
            None => g,
            Some((scale, beta)) => {
                let out = (x - self.mean[ch]) * scale[ch] + beta[ch];
                if out.is_nan() || out > 0.0 { g } else { 0.0 }
            }
        }
    }
}

/// The gradients (x, γ, β) from the output's: with x̂ the normalised input, β' = Σ g,
/// γ' = Σ g·x̂ and x' = γ/σ · (g − mean(g) − x̂·mean(g·x̂)).
/// With a ReLU after the norm (`relu_beta` = β), the output gradient first goes through the
/// ReLU's gate.
fn backward(
    x: &FlexTensor,
    (gamma, mean, variance): (&[f32], &[f32], &[f32]),
    epsilon: f64,
    layout: NormLayout,
    grad: &FlexTensor,
    relu_beta: Option<&[f32]>,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    // The forward pass's scale, by the same function (so the same bits); only the gate uses it.
    let scale = relu_beta.map(|_| output_scale(variance, gamma, epsilon));
    let gate = ReluGate {
        affine: scale.as_deref().zip(relu_beta),
        mean,
    };
    match layout {
        NormLayout::Rows => rows_backward(x, gamma, mean, variance, epsilon, grad, gate),
        NormLayout::Maps => maps_backward(x, gamma, mean, variance, epsilon, grad, gate),
    }
}

/// Rows per block of the column reductions: blocks are reduced in parallel and their sums
/// added in block order, so the result does not depend on the number of threads.
const ROWS_PER_BLOCK: usize = 256;

/// Per-column sums over the rows of a [rows, C] computation, `add(r, acc)` adding row r's
/// terms into `acc` (f64, so long columns keep their precision).
fn column_sums(rows: usize, c: usize, add: impl Fn(usize, &mut [f64]) + Sync) -> Vec<f64> {
    let blocks = rows.div_ceil(ROWS_PER_BLOCK);
    let partial: Vec<Vec<f64>> = (0..blocks)
        .into_par_iter()
        .map(|b| {
            let mut acc = vec![0f64; c];
            for r in b * ROWS_PER_BLOCK..((b + 1) * ROWS_PER_BLOCK).min(rows) {
                add(r, &mut acc);
            }
            acc
        })
        .collect();
    let mut total = vec![0f64; c];
    for block in &partial {
        for (t, &v) in total.iter_mut().zip(block) {
            *t += v;
        }
    }
    total
}

/// Training batch norm of [rows, C]: (output, mean, biased variance). Two reading passes
/// for the statistics (mean, then the centred squares) and one writing the output, where
/// burn's generic form transposes the rows twice and makes about eight passes.
fn rows_forward(
    x: &FlexTensor,
    gamma: &FlexTensor,
    beta: &FlexTensor,
    epsilon: f64,
    activation: fn(f32) -> f32,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    let [rows, c] = dims2(x);
    let data = values(x);
    let (gamma, beta) = (values(gamma), values(beta));
    assert_eq!((gamma.len(), beta.len()), (c, c), "γ and β per channel");
    let n = rows.max(1) as f64;
    let mean: Vec<f32> = column_sums(rows, c, |r, acc| {
        for (a, &v) in acc.iter_mut().zip(&data[r * c..(r + 1) * c]) {
            *a += v as f64;
        }
    })
    .into_iter()
    .map(|s| (s / n) as f32)
    .collect();
    let variance: Vec<f32> = column_sums(rows, c, |r, acc| {
        for ((a, &v), &m) in acc.iter_mut().zip(&data[r * c..(r + 1) * c]).zip(&mean) {
            let d = (v - m) as f64;
            *a += d * d;
        }
    })
    .into_iter()
    .map(|s| (s / n) as f32)
    .collect();
    let scale = output_scale(&variance, &gamma, epsilon);
    let block = ROWS_PER_BLOCK * c;
    let out = par_chunks_filled(rows * c, block, |b, dst| {
        let src = &data[b * block..][..dst.len()];
        for (d_row, s_row) in dst.chunks_exact_mut(c).zip(src.chunks_exact(c)) {
            for ((((o, &v), &m), &k), &b) in d_row
                .iter_mut()
                .zip(s_row)
                .zip(&mean)
                .zip(&scale)
                .zip(beta.iter())
            {
                *o = activation((v - m) * k + b);
            }
        }
    });
    let vector = |v: Vec<f32>| FlexTensor::from_data(TensorData::new(v, [c]));
    (flex_tensor(out, [rows, c]), vector(mean), vector(variance))
}

/// The row layout's gradients ([`backward`]): one reading pass for the sums, one writing x'.
fn rows_backward(
    x: &FlexTensor,
    gamma: &[f32],
    mean: &[f32],
    variance: &[f32],
    epsilon: f64,
    grad: &FlexTensor,
    gate: ReluGate,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    let [rows, c] = dims2(x);
    assert_eq!(dims2(grad), [rows, c], "a gradient per output");
    let (data, g) = (values(x), values(grad));
    let inv_std = inverse_std(variance, epsilon);
    // Σ g and Σ g·x̂ per channel, side by side in one accumulator of 2C.
    let sums = column_sums(rows, 2 * c, |r, acc| {
        let (sum_g, sum_gx) = acc.split_at_mut(c);
        let (x_row, g_row) = (&data[r * c..(r + 1) * c], &g[r * c..(r + 1) * c]);
        for ch in 0..c {
            let x_hat = (x_row[ch] - mean[ch]) * inv_std[ch];
            let g = gate.gate(ch, x_row[ch], g_row[ch]);
            sum_g[ch] += g as f64;
            sum_gx[ch] += (g * x_hat) as f64;
        }
    });
    let n = rows.max(1) as f64;
    let mean_g: Vec<f32> = sums[..c].iter().map(|&s| (s / n) as f32).collect();
    let mean_gx: Vec<f32> = sums[c..].iter().map(|&s| (s / n) as f32).collect();
    let scale: Vec<f32> = gamma.iter().zip(&inv_std).map(|(&g, &s)| g * s).collect();
    let dx = par_chunks_filled(rows * c, ROWS_PER_BLOCK * c, |b, dst| {
        let first = b * ROWS_PER_BLOCK;
        for (i, d_row) in dst.chunks_exact_mut(c).enumerate() {
            let r = first + i;
            let (x_row, g_row) = (&data[r * c..(r + 1) * c], &g[r * c..(r + 1) * c]);
            for ch in 0..c {
                let x_hat = (x_row[ch] - mean[ch]) * inv_std[ch];
                let g = gate.gate(ch, x_row[ch], g_row[ch]);
                d_row[ch] = scale[ch] * ((g - mean_g[ch]) - x_hat * mean_gx[ch]);
            }
        }
    });
    let vector = |v: Vec<f32>| FlexTensor::from_data(TensorData::new(v, [c]));
    (
        flex_tensor(dx, [rows, c]),
        vector(sums[c..].iter().map(|&s| s as f32).collect()),
        vector(sums[..c].iter().map(|&s| s as f32).collect()),
    )
}

/// [B, C, S]: the batch, the channels and the values of one channel's map in one frame.
fn extents(x: &FlexTensor) -> [usize; 3] {
    let shape = x.layout().shape();
    assert!(shape.num_dims() >= 2, "a [B, C, …] tensor");
    let spatial = (2..shape.num_dims()).map(|d| shape[d]).product();
    [shape[0], shape[1], spatial]
}

/// `per_channel(ch, runs)` for every channel, in parallel, where `runs` yields the channel's
/// B runs of S values (frame by frame) as offsets into the [B, C, S] data.
fn per_channel<T: Send>(
    [batch, channels, spatial]: [usize; 3],
    reduce: impl Fn(usize, &mut dyn Iterator<Item = std::ops::Range<usize>>) -> T + Sync,
) -> Vec<T> {
    (0..channels)
        .into_par_iter()
        .map(|ch| {
            let mut runs = (0..batch).map(|b| {
                let start = (b * channels + ch) * spatial;
                start..start + spatial
            });
            reduce(ch, &mut runs)
        })
        .collect()
}

/// A [B, C, S] output written by `write(ch, run_offset, out_run)` for every (frame, channel)
/// run, in parallel over blocks of whole runs.
fn per_run_filled(
    [batch, channels, spatial]: [usize; 3],
    write: impl Fn(usize, usize, &mut [f32]) + Sync,
) -> Vec<f32> {
    // Enough runs a task that small maps (the FCN's 35-long slices) are not one task each.
    let runs_per_task = (4096 / spatial.max(1)).max(1);
    let len = batch * channels * spatial;
    par_chunks_filled(len, runs_per_task * spatial, |task, block| {
        for (i, run) in block.chunks_exact_mut(spatial.max(1)).enumerate() {
            let index = task * runs_per_task + i;
            write(index % channels, index * spatial, run);
        }
    })
}

/// `1 / √(σ² + ε)` per channel.
fn inverse_std(variance: &[f32], epsilon: f64) -> Vec<f32> {
    variance
        .iter()
        .map(|&v| 1.0 / (v + epsilon as f32).sqrt())
        .collect()
}

/// γ / √(σ² + ε) per channel: what the forward pass multiplies the centred input by (and
/// the fused ReLU's backward recomputes the output with, to the bit).
fn output_scale(variance: &[f32], gamma: &[f32], epsilon: f64) -> Vec<f32> {
    inverse_std(variance, epsilon)
        .iter()
        .zip(gamma)
        .map(|(&s, &g)| s * g)
        .collect()
}

/// Training batch norm of [B, C, …]: (output, mean, biased variance). Per channel, one
/// reading pass for the mean and one for the centred squares (f64 sums); one pass writes
/// the output.
fn maps_forward(
    x: &FlexTensor,
    gamma: &FlexTensor,
    beta: &FlexTensor,
    epsilon: f64,
    activation: fn(f32) -> f32,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    let dims @ [batch, c, spatial] = extents(x);
    let data = values(x);
    let (gamma, beta) = (values(gamma), values(beta));
    assert_eq!((gamma.len(), beta.len()), (c, c), "γ and β per channel");
    let n = (batch * spatial).max(1) as f64;
    let stats: Vec<(f32, f32)> = per_channel(dims, |_, runs| {
        let runs: Vec<_> = runs.collect();
        let sum: f64 = runs
            .iter()
            .map(|r| data[r.clone()].iter().map(|&v| v as f64).sum::<f64>())
            .sum();
        let mean = (sum / n) as f32;
        let squares: f64 = runs
            .iter()
            .map(|r| {
                data[r.clone()]
                    .iter()
                    .map(|&v| {
                        let d = (v - mean) as f64;
                        d * d
                    })
                    .sum::<f64>()
            })
            .sum();
        (mean, (squares / n) as f32)
    });
    let (mean, variance): (Vec<f32>, Vec<f32>) = stats.into_iter().unzip();
    let scale = output_scale(&variance, &gamma, epsilon);
    let out = per_run_filled(dims, |ch, offset, run| {
        let (m, k, b) = (mean[ch], scale[ch], beta[ch]);
        for (o, &v) in run.iter_mut().zip(&data[offset..offset + spatial]) {
            *o = activation((v - m) * k + b);
        }
    });
    let shape = x.layout().shape().clone();
    let vector = |v: Vec<f32>| FlexTensor::from_data(TensorData::new(v, [c]));
    (
        FlexTensor::from_data(TensorData::new(out, shape)),
        vector(mean),
        vector(variance),
    )
}

/// The map layout's gradients ([`backward`]): one reading pass per channel for both sums,
/// one pass writing x'.
fn maps_backward(
    x: &FlexTensor,
    gamma: &[f32],
    mean: &[f32],
    variance: &[f32],
    epsilon: f64,
    grad: &FlexTensor,
    gate: ReluGate,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    let dims @ [batch, c, spatial] = extents(x);
    assert_eq!(
        x.layout().shape(),
        grad.layout().shape(),
        "a gradient per output"
    );
    let (data, g) = (values(x), values(grad));
    let inv_std = inverse_std(variance, epsilon);
    let sums: Vec<(f64, f64)> = per_channel(dims, |ch, runs| {
        let (m, s) = (mean[ch], inv_std[ch]);
        let (mut sum_g, mut sum_gx) = (0f64, 0f64);
        for r in runs {
            for (&v, &gv) in data[r.clone()].iter().zip(&g[r]) {
                let gv = gate.gate(ch, v, gv);
                sum_g += gv as f64;
                sum_gx += (gv * ((v - m) * s)) as f64;
            }
        }
        (sum_g, sum_gx)
    });
    let n = (batch * spatial).max(1) as f64;
    let mean_g: Vec<f32> = sums.iter().map(|&(s, _)| (s / n) as f32).collect();
    let mean_gx: Vec<f32> = sums.iter().map(|&(_, s)| (s / n) as f32).collect();
    let dx = per_run_filled(dims, |ch, offset, run| {
        let (m, s, k) = (mean[ch], inv_std[ch], gamma[ch] * inv_std[ch]);
        let (mg, mgx) = (mean_g[ch], mean_gx[ch]);
        let src = data[offset..offset + spatial].iter().zip(&g[offset..]);
        for (d, (&v, &gv)) in run.iter_mut().zip(src) {
            let gv = gate.gate(ch, v, gv);
            *d = k * ((gv - mg) - (v - m) * s * mgx);
        }
    });
    let shape = x.layout().shape().clone();
    let vector = |v: Vec<f32>| FlexTensor::from_data(TensorData::new(v, [c]));
    (
        FlexTensor::from_data(TensorData::new(dx, shape)),
        vector(sums.iter().map(|&(_, s)| s as f32).collect()),
        vector(sums.iter().map(|&(s, _)| s as f32).collect()),
    )
}

impl BatchNormOps for Flex {
    fn batch_norm_train_fused(
        x: FlexTensor,
        gamma: FlexTensor,
        beta: FlexTensor,
        epsilon: f64,
        layout: NormLayout,
        relu: bool,
    ) -> (FlexTensor, FlexTensor, FlexTensor) {
        forward(&x, &gamma, &beta, epsilon, layout, relu)
    }
}

/// The backward step of [`BatchNormOps::batch_norm_train_fused`].
#[derive(Debug)]
struct BatchNormBackward;

/// The input, γ, the batch mean and variance, ε, the layout, and β when a ReLU follows.
type BatchNormState = (
    FlexTensor,
    Arc<Vec<f32>>,
    Arc<Vec<f32>>,
    Arc<Vec<f32>>,
    f64,
    NormLayout,
    Option<Arc<Vec<f32>>>,
);

impl Backward<Flex, 3> for BatchNormBackward {
    type State = BatchNormState;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (x, gamma, mean, variance, epsilon, layout, relu_beta) = ops.state;
        let grad = grads.consume::<Flex>(&ops.node);
        let statistics = (gamma.as_slice(), mean.as_slice(), variance.as_slice());
        let relu_beta = relu_beta.as_deref().map(Vec::as_slice);
        let (dx, dgamma, dbeta) = backward(&x, statistics, epsilon, layout, &grad, relu_beta);
        let [node_x, node_gamma, node_beta] = ops.parents;
        for (node, g) in [(node_x, dx), (node_gamma, dgamma), (node_beta, dbeta)] {
            if let Some(node) = node {
                grads.register::<Flex>(node.id, g);
            }
        }
    }
}

impl<C: CheckpointStrategy> BatchNormOps for Autodiff<Flex, C> {
    fn batch_norm_train_fused(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
        layout: NormLayout,
        relu: bool,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let (x, a) = x.into_parts();
        let (gamma, b) = gamma.into_parts();
        let (beta, c) = beta.into_parts();
        let (out, mean, variance) = forward(&x, &gamma, &beta, epsilon, layout, relu);
        let out = match BatchNormBackward
            .prepare::<C>([a, b, c])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let host = |t: &FlexTensor| Arc::new(values(t).into_owned());
                let state = (
                    x,
                    host(&gamma),
                    host(&mean),
                    host(&variance),
                    epsilon,
                    layout,
                    relu.then(|| host(&beta)),
                );
                prep.finish(state, out)
            }
            OpsKind::UnTracked(prep) => prep.finish(out),
        };
        // The statistics are constants (the running statistics' update detaches them).
        (out, Self::from_inner(mean), Self::from_inner(variance))
    }
}
