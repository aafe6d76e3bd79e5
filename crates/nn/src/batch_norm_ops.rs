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

use crate::buffers::par_chunks_written;
use crate::ragged::{dims2, flex_tensor, values};
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, AutodiffBackend, Backend, Dispatch, Flex, backend_extension};
use burn::prelude::*;
use multiversion::multiversion;
use rayon::prelude::*;
use std::mem::MaybeUninit;
use std::sync::Arc;

/// Which axes a batch norm's statistics run over.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NormLayout {
    /// [rows, C]: over the rows.
    Rows,
    /// [B, C, …]: over the batch and every axis after the channels.
    Maps,
}

/// The custom operation (see the module's documentation; on a CubeCL device,
/// [`crate::batch_norm_device`]'s kernels).
#[backend_extension(Flex, Cube: cfg(any(feature = "wgpu", feature = "cuda")), Autodiff)]
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

/// [`BatchNormOps::batch_norm_train_fused`] on tensors on the flex device or a CubeCL one:
/// (output, batch mean, batch variance).
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
    // Each kernel is monomorphised for its activation (and, backward, its gate), so the
    // per-element loops carry no call or branch on the variant and vectorise.
    match (layout, relu) {
        (NormLayout::Rows, true) => rows_forward(x, gamma, beta, epsilon, flex_relu),
        (NormLayout::Rows, false) => rows_forward(x, gamma, beta, epsilon, identity),
        (NormLayout::Maps, true) => maps_forward(x, gamma, beta, epsilon, flex_relu),
        (NormLayout::Maps, false) => maps_forward(x, gamma, beta, epsilon, identity),
    }
}

#[inline(always)]
fn identity(v: f32) -> f32 {
    v
}

/// flex's ReLU to the bit: NaN passes, zero and below give +0.
#[inline(always)]
fn flex_relu(v: f32) -> f32 {
    if v.is_nan() || v > 0.0 { v } else { 0.0 }
}

/// What the output gradient passes through before the norm's own backward: nothing
/// ([`Ungated`]) or the fused ReLU's gate ([`ReluGate`]).
trait Gate: Copy + Sync {
    /// This gate with its per-channel slices cut to `c` channels, so that loops over
    /// `0..c` index them without bounds checks.
    fn channels(self, c: usize) -> Self;
    /// Channel `ch`'s output gradient `g` at input `x`, through the gate.
    fn gate(&self, ch: usize, x: f32, g: f32) -> f32;
}

/// A norm without a ReLU: the gradient itself.
#[derive(Clone, Copy)]
struct Ungated;

impl Gate for Ungated {
    fn channels(self, _: usize) -> Self {
        self
    }

    #[inline(always)]
    fn gate(&self, _: usize, _: f32, g: f32) -> f32 {
        g
    }
}

/// The output gradient through the ReLU of a fused norm + ReLU (flex's `relu_backward`:
/// kept where the ReLU's output is positive or NaN), from that output recomputed as the
/// forward pass computed it, `(x − mean)·scale + β`.
#[derive(Clone, Copy)]
struct ReluGate<'a> {
    /// γ/σ per channel.
    scale: &'a [f32],
    beta: &'a [f32],
    mean: &'a [f32],
}

impl Gate for ReluGate<'_> {
    fn channels(self, c: usize) -> Self {
        ReluGate {
            scale: &self.scale[..c],
            beta: &self.beta[..c],
            mean: &self.mean[..c],
        }
    }

    #[inline(always)]
    fn gate(&self, ch: usize, x: f32, g: f32) -> f32 {
        let out = (x - self.mean[ch]) * self.scale[ch] + self.beta[ch];
        if out.is_nan() || out > 0.0 { g } else { 0.0 }
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
    let statistics = (gamma, mean, variance, epsilon);
    let Some(beta) = relu_beta else {
        return match layout {
            NormLayout::Rows => rows_backward(x, statistics, grad, Ungated),
            NormLayout::Maps => maps_backward(x, statistics, grad, Ungated),
        };
    };
    // The forward pass's scale, by the same function (so the same bits).
    let scale = output_scale(variance, gamma, epsilon);
    let gate = ReluGate {
        scale: &scale,
        beta,
        mean,
    };
    match layout {
        NormLayout::Rows => rows_backward(x, statistics, grad, gate),
        NormLayout::Maps => maps_backward(x, statistics, grad, gate),
    }
}

/// A norm's γ, batch mean and variance, and ε: what its backward pass reads besides the
/// input and the output gradient.
type Statistics<'a> = (&'a [f32], &'a [f32], &'a [f32], f64);

/// Rows per block of the column reductions: blocks are reduced in parallel and their sums
/// added in block order, so the result does not depend on the number of threads.
const ROWS_PER_BLOCK: usize = 256;

/// Per-column sums over the rows of a [rows, C] computation, `add(block, acc)` adding the
/// terms of the rows in `block` into `acc` in row order (f64, so long columns keep their
/// precision).
fn column_sums(
    rows: usize,
    c: usize,
    add: impl Fn(std::ops::Range<usize>, &mut [f64]) + Sync,
) -> Vec<f64> {
    let blocks = rows.div_ceil(ROWS_PER_BLOCK);
    let partial: Vec<Vec<f64>> = (0..blocks)
        .into_par_iter()
        .map(|b| {
            let mut acc = vec![0f64; c];
            add(
                b * ROWS_PER_BLOCK..((b + 1) * ROWS_PER_BLOCK).min(rows),
                &mut acc,
            );
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

// The row layout's per-block kernels. Each takes its rows and per-channel values as slice
// arguments (which the compiler knows do not overlap the output) and cuts every
// per-channel slice to exactly C, so the loops over a row's C channels run without bounds
// checks or reloads and vectorise across channels; every value is still the same
// operations in the same order as one scalar loop. Each is compiled per instruction set
// (`multiversion`: SSE2 to AVX-512) and picks the CPU's best at run time; vectorised across
// channels, never inside a sum, and without fused multiply-adds (Rust contracts none), the
// values are those of the baseline build to the bit.

/// Rows `rows` of the [_, c] matrix `t`.
fn row_block(t: &[f32], c: usize, rows: std::ops::Range<usize>) -> &[f32] {
    &t[rows.start * c..rows.end * c]
}

/// acc[ch] += x[r, ch] for the rows of `x` in order.
#[multiversion(targets = "simd")]
fn add_columns(acc: &mut [f64], x: &[f32]) {
    let c = acc.len();
    for row in x.chunks_exact(c) {
        for (a, &v) in acc.iter_mut().zip(row) {
            *a += v as f64;
        }
    }
}

/// acc[ch] += (x[r, ch] − mean[ch])² for the rows of `x` in order.
#[multiversion(targets = "simd")]
fn add_centred_squares(acc: &mut [f64], x: &[f32], mean: &[f32]) {
    let c = acc.len();
    let mean = &mean[..c];
    for row in x.chunks_exact(c) {
        for ((a, &v), &m) in acc.iter_mut().zip(row).zip(mean) {
            let d = (v - m) as f64;
            *a += d * d;
        }
    }
}

/// out[r, ch] = activation((x[r, ch] − mean[ch])·scale[ch] + β[ch]).
#[multiversion(targets = "simd")]
fn normalise_rows(
    out: &mut [MaybeUninit<f32>],
    x: &[f32],
    [mean, scale, beta]: [&[f32]; 3],
    activation: impl Fn(f32) -> f32,
) {
    let c = mean.len();
    let (scale, beta) = (&scale[..c], &beta[..c]);
    for (o_row, x_row) in out.chunks_exact_mut(c).zip(x.chunks_exact(c)) {
        let (o_row, x_row) = (&mut o_row[..c], &x_row[..c]);
        for ch in 0..c {
            o_row[ch].write(activation((x_row[ch] - mean[ch]) * scale[ch] + beta[ch]));
        }
    }
}

/// Σ g and Σ g·x̂ per channel (g through `gate`, x̂ = (x − mean)·inv_std) over the rows
/// of `x` and `g` in order.
#[multiversion(targets = "simd")]
fn add_gradient_sums(
    (sum_g, sum_gx): (&mut [f64], &mut [f64]),
    x: &[f32],
    g: &[f32],
    [mean, inv_std]: [&[f32]; 2],
    gate: impl Gate,
) {
    let c = mean.len();
    let (sum_g, sum_gx, inv_std) = (&mut sum_g[..c], &mut sum_gx[..c], &inv_std[..c]);
    let gate = gate.channels(c);
    for (x_row, g_row) in x.chunks_exact(c).zip(g.chunks_exact(c)) {
        let (x_row, g_row) = (&x_row[..c], &g_row[..c]);
        for ch in 0..c {
            let x_hat = (x_row[ch] - mean[ch]) * inv_std[ch];
            let g = gate.gate(ch, x_row[ch], g_row[ch]);
            sum_g[ch] += g as f64;
            sum_gx[ch] += (g * x_hat) as f64;
        }
    }
}

/// dx[r, ch] = scale[ch]·((g − mean(g)[ch]) − x̂·mean(g·x̂)[ch]) for the rows of `x` and `g`
/// (g through `gate`).
#[multiversion(targets = "simd")]
fn input_gradient_rows(
    dx: &mut [MaybeUninit<f32>],
    (x, g): (&[f32], &[f32]),
    [mean, inv_std, scale, mean_g, mean_gx]: [&[f32]; 5],
    gate: impl Gate,
) {
    let c = mean.len();
    let (inv_std, scale) = (&inv_std[..c], &scale[..c]);
    let (mean_g, mean_gx) = (&mean_g[..c], &mean_gx[..c]);
    let gate = gate.channels(c);
    let rows = x.chunks_exact(c).zip(g.chunks_exact(c));
    for (d_row, (x_row, g_row)) in dx.chunks_exact_mut(c).zip(rows) {
        let (d_row, x_row, g_row) = (&mut d_row[..c], &x_row[..c], &g_row[..c]);
        for ch in 0..c {
            let x_hat = (x_row[ch] - mean[ch]) * inv_std[ch];
            let g = gate.gate(ch, x_row[ch], g_row[ch]);
            d_row[ch].write(scale[ch] * ((g - mean_g[ch]) - x_hat * mean_gx[ch]));
        }
    }
}

/// Training batch norm of [rows, C]: (output, mean, biased variance). Two reading passes
/// for the statistics (mean, then the centred squares) and one writing the output, where
/// burn's generic form transposes the rows twice and makes about eight passes.
fn rows_forward(
    x: &FlexTensor,
    gamma: &FlexTensor,
    beta: &FlexTensor,
    epsilon: f64,
    activation: impl Fn(f32) -> f32 + Copy + Sync,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    let [rows, c] = dims2(x);
    let data = values(x);
    let (gamma, beta) = (values(gamma), values(beta));
    assert_eq!((gamma.len(), beta.len()), (c, c), "γ and β per channel");
    let n = rows.max(1) as f64;
    let mean: Vec<f32> = column_sums(rows, c, |rows, acc| {
        add_columns(acc, row_block(&data, c, rows))
    })
    .into_iter()
    .map(|s| (s / n) as f32)
    .collect();
    let variance: Vec<f32> = column_sums(rows, c, |rows, acc| {
        add_centred_squares(acc, row_block(&data, c, rows), &mean)
    })
    .into_iter()
    .map(|s| (s / n) as f32)
    .collect();
    let scale = output_scale(&variance, &gamma, epsilon);
    let block = ROWS_PER_BLOCK * c;
    let out = par_chunks_written(rows * c, block, |b, dst| {
        let src = &data[b * block..][..dst.len()];
        normalise_rows(dst, src, [&mean, &scale, &beta], activation);
    });
    let vector = |v: Vec<f32>| FlexTensor::from_data(TensorData::new(v, [c]));
    (flex_tensor(out, [rows, c]), vector(mean), vector(variance))
}

/// The row layout's gradients ([`backward`]): one reading pass for the sums, one writing x'.
fn rows_backward(
    x: &FlexTensor,
    (gamma, mean, variance, epsilon): Statistics,
    grad: &FlexTensor,
    gate: impl Gate,
) -> (FlexTensor, FlexTensor, FlexTensor) {
    let [rows, c] = dims2(x);
    assert_eq!(dims2(grad), [rows, c], "a gradient per output");
    let (data, g) = (values(x), values(grad));
    let inv_std = inverse_std(variance, epsilon);
    // Σ g and Σ g·x̂ per channel, side by side in one accumulator of 2C.
    let sums = column_sums(rows, 2 * c, |rows, acc| {
        let (x, g) = (row_block(&data, c, rows.clone()), row_block(&g, c, rows));
        add_gradient_sums(acc.split_at_mut(c), x, g, [mean, &inv_std], gate);
    });
    let n = rows.max(1) as f64;
    let mean_g: Vec<f32> = sums[..c].iter().map(|&s| (s / n) as f32).collect();
    let mean_gx: Vec<f32> = sums[c..].iter().map(|&s| (s / n) as f32).collect();
    let scale: Vec<f32> = gamma.iter().zip(&inv_std).map(|(&g, &s)| g * s).collect();
    let per_channel = [mean, &inv_std, &scale, &mean_g, &mean_gx];
    let dx = par_chunks_written(rows * c, ROWS_PER_BLOCK * c, |b, dst| {
        let first = b * ROWS_PER_BLOCK;
        let rows = first..first + dst.len() / c.max(1);
        let (x, g) = (row_block(&data, c, rows.clone()), row_block(&g, c, rows));
        input_gradient_rows(dst, (x, g), per_channel, gate);
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
/// run, in parallel over blocks of whole runs; `write` writes every value of its run.
fn per_run_written(
    [batch, channels, spatial]: [usize; 3],
    write: impl Fn(usize, usize, &mut [MaybeUninit<f32>]) + Sync,
) -> Vec<f32> {
    // Enough runs a task that small maps (the FCN's 35-long slices) are not one task each.
    let runs_per_task = (4096 / spatial.max(1)).max(1);
    let len = batch * channels * spatial;
    par_chunks_written(len, runs_per_task * spatial, |task, block| {
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

/// out[i] = activation((x[i] − m)·k + b) over one channel's run of a map (the map layout's
/// [`normalise_rows`]).
#[multiversion(targets = "simd")]
fn normalise_run(
    out: &mut [MaybeUninit<f32>],
    x: &[f32],
    [m, k, b]: [f32; 3],
    activation: impl Fn(f32) -> f32,
) {
    for (o, &v) in out.iter_mut().zip(x) {
        o.write(activation((v - m) * k + b));
    }
}

/// dx[i] = k·((g − mean(g)) − (x − m)·s·mean(g·x̂)) over channel `ch`'s run (g through
/// `gate`; the map layout's [`input_gradient_rows`]).
#[multiversion(targets = "simd")]
fn input_gradient_run(
    dx: &mut [MaybeUninit<f32>],
    (x, g): (&[f32], &[f32]),
    [m, s, k, mean_g, mean_gx]: [f32; 5],
    (gate, ch): (impl Gate, usize),
) {
    for (d, (&v, &gv)) in dx.iter_mut().zip(x.iter().zip(g)) {
        let gv = gate.gate(ch, v, gv);
        d.write(k * ((gv - mean_g) - (v - m) * s * mean_gx));
    }
}

/// Training batch norm of [B, C, …]: (output, mean, biased variance). Per channel, one
/// reading pass for the mean and one for the centred squares (f64 sums); one pass writes
/// the output.
fn maps_forward(
    x: &FlexTensor,
    gamma: &FlexTensor,
    beta: &FlexTensor,
    epsilon: f64,
    activation: impl Fn(f32) -> f32 + Copy + Sync,
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
    let out = per_run_written(dims, |ch, offset, run| {
        let affine = [mean[ch], scale[ch], beta[ch]];
        normalise_run(run, &data[offset..offset + spatial], affine, activation);
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
    (gamma, mean, variance, epsilon): Statistics,
    grad: &FlexTensor,
    gate: impl Gate,
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
    let dx = per_run_written(dims, |ch, offset, run| {
        let (m, s, k) = (mean[ch], inv_std[ch], gamma[ch] * inv_std[ch]);
        let src = (
            &data[offset..offset + spatial],
            &g[offset..offset + spatial],
        );
        let per_channel = [m, s, k, mean_g[ch], mean_gx[ch]];
        input_gradient_run(run, src, per_channel, (gate, ch));
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The row layout as plain scalar loops: per channel, f64 sums over blocks of
    /// `ROWS_PER_BLOCK` rows in row order, the blocks added in order; then the output or the
    /// input gradient element by element. (output, mean, variance, dx, dγ, dβ).
    fn scalar_rows(
        x: &[f32],
        [rows, c]: [usize; 2],
        (gamma, beta, epsilon): (&[f32], &[f32], f64),
        g: &[f32],
        relu: bool,
    ) -> [Vec<f32>; 6] {
        let sums = |term: &dyn Fn(usize, usize) -> f64| -> Vec<f64> {
            (0..c)
                .map(|ch| {
                    let mut total = 0f64;
                    for block in (0..rows).step_by(ROWS_PER_BLOCK) {
                        let mut acc = 0f64;
                        for r in block..(block + ROWS_PER_BLOCK).min(rows) {
                            acc += term(r, ch);
                        }
                        total += acc;
                    }
                    total
                })
                .collect()
        };
        let n = rows.max(1) as f64;
        let mean: Vec<f32> = sums(&|r, ch| x[r * c + ch] as f64)
            .iter()
            .map(|&s| (s / n) as f32)
            .collect();
        let variance: Vec<f32> = sums(&|r, ch| {
            let d = (x[r * c + ch] - mean[ch]) as f64;
            d * d
        })
        .iter()
        .map(|&s| (s / n) as f32)
        .collect();
        let inv_std: Vec<f32> = (0..c)
            .map(|ch| 1.0 / (variance[ch] + epsilon as f32).sqrt())
            .collect();
        let scale: Vec<f32> = (0..c).map(|ch| inv_std[ch] * gamma[ch]).collect();
        let norm = |r: usize, ch: usize| (x[r * c + ch] - mean[ch]) * scale[ch] + beta[ch];
        let activation = |v: f32| {
            if !relu || v.is_nan() || v > 0.0 {
                v
            } else {
                0.0
            }
        };
        let out: Vec<f32> = (0..rows * c)
            .map(|i| activation(norm(i / c, i % c)))
            .collect();
        let gated = |r: usize, ch: usize| {
            let keep = !relu || norm(r, ch).is_nan() || norm(r, ch) > 0.0;
            if keep { g[r * c + ch] } else { 0.0 }
        };
        let x_hat = |r: usize, ch: usize| (x[r * c + ch] - mean[ch]) * inv_std[ch];
        let sum_g = sums(&|r, ch| gated(r, ch) as f64);
        let sum_gx = sums(&|r, ch| (gated(r, ch) * x_hat(r, ch)) as f64);
        let dx: Vec<f32> = (0..rows * c)
            .map(|i| {
                let (r, ch) = (i / c, i % c);
                let (mean_g, mean_gx) = ((sum_g[ch] / n) as f32, (sum_gx[ch] / n) as f32);
                gamma[ch] * inv_std[ch] * ((gated(r, ch) - mean_g) - x_hat(r, ch) * mean_gx)
            })
            .collect();
        let to_f32 = |s: Vec<f64>| s.into_iter().map(|v| v as f32).collect();
        [out, mean, variance, dx, to_f32(sum_gx), to_f32(sum_g)]
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The row layout's block kernels compute the scalar loops' values to the bit: widths
    /// that do and do not fill a vector, row counts below, at and across a block, with and
    /// without the ReLU.
    #[test]
    fn the_row_kernels_give_the_scalar_loops_bits() {
        for (rows, c) in [(1, 1), (5, 3), (255, 16), (256, 7), (700, 37), (513, 64)] {
            let x: Vec<f32> = (0..rows * c)
                .map(|i| ((i * 7919) % 613) as f32 * 0.0137 - 3.0 + (i % c) as f32 * 0.5)
                .collect();
            let g: Vec<f32> = (0..rows * c)
                .map(|i| ((i * 104_729) % 211) as f32 / 50.0 - 2.0)
                .collect();
            let gamma: Vec<f32> = (0..c).map(|ch| 0.75 + ch as f32 * 0.125).collect();
            let beta: Vec<f32> = (0..c).map(|ch| ch as f32 * 0.25 - 0.5).collect();
            for relu in [false, true] {
                let input = flex_tensor(x.clone(), [rows, c]);
                let vector = |v: &[f32]| FlexTensor::from_data(TensorData::new(v.to_vec(), [c]));
                let (out, mean, variance) = forward(
                    &input,
                    &vector(&gamma),
                    &vector(&beta),
                    1e-3,
                    NormLayout::Rows,
                    relu,
                );
                let (mean, variance) = (values(&mean).into_owned(), values(&variance).into_owned());
                let grad = flex_tensor(g.clone(), [rows, c]);
                let (dx, dgamma, dbeta) = backward(
                    &input,
                    (&gamma, &mean, &variance),
                    1e-3,
                    NormLayout::Rows,
                    &grad,
                    relu.then_some(beta.as_slice()),
                );
                let reference = scalar_rows(&x, [rows, c], (&gamma, &beta, 1e-3), &g, relu);
                let got = [values(&out), mean.into(), variance.into(), values(&dx)];
                let got = [&got[..], &[values(&dgamma), values(&dbeta)]].concat();
                for (what, (a, b)) in ["output", "mean", "variance", "dx", "dγ", "dβ"]
                    .iter()
                    .zip(got.iter().zip(&reference))
                {
                    assert_eq!(bits(a), bits(b), "{what}, {rows}×{c}, ReLU {relu}");
                }
            }
        }
    }
}
