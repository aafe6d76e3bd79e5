//! Training batch norm of channels-first maps ([B, C, …]: the BEV backbone's [B, C, H, W],
//! the frustum FCN's [B, C, L]) as a custom operation on the flex CPU device.
//!
//! Why: burn 0.22's generic training batch norm swaps the batch and channel axes and
//! reshapes to [C, B·H·W] twice forward (mean, then the centred squares) and twice backward
//! (the output gradient, and its product with the normalised input); with a batch of more
//! than one, each of these is a full copy of the map, on top of about eight element-wise
//! passes each way. Here each channel's statistics are read where they lie (B runs of H·W
//! values) in two passes, the output written in one, and the backward reads once for its
//! two sums and writes once. Channels are reduced in parallel, each in a fixed order, so the
//! result does not depend on the number of threads.
//!
//! The same `#[backend_extension]` route as [`crate::ragged::RaggedOps::batch_norm_rows`],
//! which does the same for [rows, C] point features; [`crate::norm::norm_maps`] picks this
//! path (training on the flex device) or `BatchNorm::forward`.

use crate::ragged::values;
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

/// The custom operation (see the module's documentation).
#[backend_extension(Flex, Autodiff)]
pub trait MapNormOps: Backend {
    /// Training batch norm over every axis but the second of `x` ([B, C, …]): the output,
    /// and the batch's per-channel mean and biased variance ([C] each, constants).
    fn batch_norm_maps(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

/// [`MapNormOps::batch_norm_maps`] on tensors on the flex device: (output, batch mean,
/// batch variance).
pub fn batch_norm_maps<const D: usize>(
    x: Tensor<D>,
    gamma: Tensor<1>,
    beta: Tensor<1>,
    epsilon: f64,
) -> (Tensor<D>, Tensor<1>, Tensor<1>) {
    let (out, mean, variance) = <Dispatch as MapNormOps>::batch_norm_maps(
        x.into_dispatch(),
        gamma.into_dispatch(),
        beta.into_dispatch(),
        epsilon,
    );
    (
        Tensor::from_dispatch(out),
        Tensor::from_dispatch(mean),
        Tensor::from_dispatch(variance),
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

/// Writes `write(ch, run_offset, out_run)` for every (frame, channel) run of the output, in
/// parallel over blocks of whole runs.
fn per_run_mut(
    out: &mut [f32],
    [_, channels, spatial]: [usize; 3],
    write: impl Fn(usize, usize, &mut [f32]) + Sync,
) {
    if spatial == 0 || channels == 0 {
        return;
    }
    // Enough runs a task that small maps (the FCN's 35-long slices) are not one task each.
    let runs_per_task = (4096 / spatial).max(1);
    out.par_chunks_mut(runs_per_task * spatial)
        .enumerate()
        .for_each(|(task, block)| {
            for (i, run) in block.chunks_exact_mut(spatial).enumerate() {
                let index = task * runs_per_task + i;
                write(index % channels, index * spatial, run);
            }
        });
}

/// `1 / √(σ² + ε)` per channel.
fn inverse_std(variance: &[f32], epsilon: f64) -> Vec<f32> {
    variance
        .iter()
        .map(|&v| 1.0 / (v + epsilon as f32).sqrt())
        .collect()
}

/// Training batch norm of [B, C, …]: (output, mean, biased variance). Per channel, one
/// reading pass for the mean and one for the centred squares (f64 sums); one pass writes
/// the output.
fn forward(
    x: &FlexTensor,
    gamma: &FlexTensor,
    beta: &FlexTensor,
    epsilon: f64,
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
    let scale: Vec<f32> = inverse_std(&variance, epsilon)
        .iter()
        .zip(gamma.iter())
        .map(|(&s, &g)| s * g)
        .collect();
    let mut out = vec![0f32; data.len()];
    per_run_mut(&mut out, dims, |ch, offset, run| {
        let (m, k, b) = (mean[ch], scale[ch], beta[ch]);
        for (o, &v) in run.iter_mut().zip(&data[offset..offset + spatial]) {
            *o = (v - m) * k + b;
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

/// The gradients (x, γ, β) from the output's: with x̂ the normalised input, β' = Σ g,
/// γ' = Σ g·x̂ and x' = γ/σ · (g − mean(g) − x̂·mean(g·x̂)). One reading pass per channel
/// for both sums, one pass writing x'.
fn backward(
    x: &FlexTensor,
    gamma: &[f32],
    mean: &[f32],
    variance: &[f32],
    epsilon: f64,
    grad: &FlexTensor,
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
                sum_g += gv as f64;
                sum_gx += (gv * ((v - m) * s)) as f64;
            }
        }
        (sum_g, sum_gx)
    });
    let n = (batch * spatial).max(1) as f64;
    let mean_g: Vec<f32> = sums.iter().map(|&(s, _)| (s / n) as f32).collect();
    let mean_gx: Vec<f32> = sums.iter().map(|&(_, s)| (s / n) as f32).collect();
    let mut dx = vec![0f32; data.len()];
    per_run_mut(&mut dx, dims, |ch, offset, run| {
        let (m, s, k) = (mean[ch], inv_std[ch], gamma[ch] * inv_std[ch]);
        let (mg, mgx) = (mean_g[ch], mean_gx[ch]);
        let src = data[offset..offset + spatial].iter().zip(&g[offset..]);
        for (d, (&v, &gv)) in run.iter_mut().zip(src) {
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

impl MapNormOps for Flex {
    fn batch_norm_maps(
        x: FlexTensor,
        gamma: FlexTensor,
        beta: FlexTensor,
        epsilon: f64,
    ) -> (FlexTensor, FlexTensor, FlexTensor) {
        forward(&x, &gamma, &beta, epsilon)
    }
}

/// The backward step of [`MapNormOps::batch_norm_maps`].
#[derive(Debug)]
struct BatchNormMapsBackward;

impl Backward<Flex, 3> for BatchNormMapsBackward {
    /// The input, γ, the batch mean and variance, ε.
    type State = (FlexTensor, Arc<Vec<f32>>, Arc<Vec<f32>>, Arc<Vec<f32>>, f64);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (x, gamma, mean, variance, epsilon) = ops.state;
        let grad = grads.consume::<Flex>(&ops.node);
        let (dx, dgamma, dbeta) = backward(&x, &gamma, &mean, &variance, epsilon, &grad);
        let [node_x, node_gamma, node_beta] = ops.parents;
        for (node, g) in [(node_x, dx), (node_gamma, dgamma), (node_beta, dbeta)] {
            if let Some(node) = node {
                grads.register::<Flex>(node.id, g);
            }
        }
    }
}

impl<C: CheckpointStrategy> MapNormOps for Autodiff<Flex, C> {
    fn batch_norm_maps(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let (x, a) = x.into_parts();
        let (gamma, b) = gamma.into_parts();
        let (beta, c) = beta.into_parts();
        let (out, mean, variance) = forward(&x, &gamma, &beta, epsilon);
        let out = match BatchNormMapsBackward
            .prepare::<C>([a, b, c])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let host = |t: &FlexTensor| Arc::new(values(t).into_owned());
                let state = (x, host(&gamma), host(&mean), host(&variance), epsilon);
                prep.finish(state, out)
            }
            OpsKind::UnTracked(prep) => prep.finish(out),
        };
        // The statistics are constants (the running statistics' update detaches them).
        (out, Self::from_inner(mean), Self::from_inner(variance))
    }
}
