//! Training batch norm + ReLU, forward and backward, at the shapes the Voxel R-CNN CPU row
//! trains (sparse-convolution features as [rows, C], BEV maps as [B, C, H, W]): the fused
//! custom operation (`norm_rows_relu`, `norm_maps_relu`) against burn's generic `BatchNorm`
//! and ReLU, side by side in one run, on a rayon pool of the machine's cores as training runs
//! it (`fusiondet_pipeline::compute_pool`).
//!
//! `cargo bench -p fusiondet-nn --bench batch_norm` (about 2 minutes on two cores).

use burn::nn::BatchNorm;
use burn::prelude::*;
use burn::tensor::activation::relu;
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use fusiondet_nn::norm::{NormConfig, batch_norm, norm_maps_relu, norm_rows_relu};
use fusiondet_nn::ragged::set_custom_ops;

/// As the binary: mimalloc, keeping freed memory (`fusiondet_alloc`).
#[global_allocator]
static ALLOCATOR: fusiondet_alloc::MiMalloc = fusiondet_alloc::MiMalloc;

/// Deterministic values in [-1, 1) with a per-channel offset (no random source needed).
fn filled<const D: usize>(shape: [usize; D], salt: usize, device: &Device) -> Tensor<D> {
    let n: usize = shape.iter().product();
    let v: Vec<f32> = (0..n)
        .map(|i| ((i * 7919 + salt * 104_729) % 2003) as f32 / 1001.5 - 1.0)
        .collect();
    Tensor::from_data(TensorData::new(v, shape), device)
}

/// One training step of `norm` on `x`: forward, then the backward pass of Σ out·w.
fn step<const D: usize>(
    bn: &BatchNorm,
    x: &Tensor<D>,
    w: &Tensor<D>,
    norm: fn(&BatchNorm, Tensor<D>) -> Tensor<D>,
) {
    let input = x.clone().require_grad();
    let out = norm(bn, input.clone());
    let grads = (out * w.clone()).sum().backward();
    std::hint::black_box(input.grad(&grads));
}

fn generic_rows(bn: &BatchNorm, x: Tensor<2>) -> Tensor<2> {
    relu(bn.forward(x))
}

fn generic_maps(bn: &BatchNorm, x: Tensor<4>) -> Tensor<4> {
    relu(bn.forward(x))
}

fn batch_norm_relu(c: &mut Criterion) {
    fusiondet_alloc::keep_freed_memory();
    let pool = rayon::ThreadPoolBuilder::new()
        .thread_name(|i| format!("bench-compute-{i}"))
        .build()
        .expect("a rayon pool");
    let device = Device::flex().autodiff();
    let mut group = c.benchmark_group("batch_norm_relu");
    group.sample_size(20);
    for (rows, channels) in [(40_000, 16), (20_000, 32), (10_000, 64)] {
        let bn = batch_norm(channels, &NormConfig::default(), &device);
        let (x, w) = (
            filled([rows, channels], 1, &device),
            filled([rows, channels], 2, &device),
        );
        let id = format!("rows {rows}x{channels}");
        for (variant, custom, norm) in [
            (
                "custom",
                true,
                norm_rows_relu as fn(&BatchNorm, Tensor<2>) -> Tensor<2>,
            ),
            ("generic", false, generic_rows),
        ] {
            group.bench_function(BenchmarkId::new(variant, &id), |b| {
                set_custom_ops(custom);
                b.iter(|| pool.install(|| step(&bn, &x, &w, norm)));
                set_custom_ops(true);
            });
        }
    }
    let shape = [2, 64, 64, 80];
    let bn = batch_norm(shape[1], &NormConfig::default(), &device);
    let (x, w) = (filled(shape, 3, &device), filled(shape, 4, &device));
    for (variant, custom, norm) in [
        (
            "custom",
            true,
            norm_maps_relu::<4> as fn(&BatchNorm, Tensor<4>) -> Tensor<4>,
        ),
        ("generic", false, generic_maps),
    ] {
        group.bench_function(BenchmarkId::new(variant, "maps 2x64x64x80"), |b| {
            set_custom_ops(custom);
            b.iter(|| pool.install(|| step(&bn, &x, &w, norm)));
            set_custom_ops(true);
        });
    }
    group.finish();
}

criterion_group!(benches, batch_norm_relu);
criterion_main!(benches);
