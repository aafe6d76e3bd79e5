//! The dense 3×3 convolutions of the Voxel R-CNN CPU row's BEV backbone (stride 1, padding
//! 1; [2, 64, 64, 80] and [2, 128, 32, 40] maps) on the flex device: the forward pass, and the
//! input gradient two ways — flex's (`conv2d_x_backward`: a transposed convolution, one
//! product into a [C_in·9, H·W] column buffer per frame and a scatter of the columns) and as
//! a forward convolution of the output gradient with the kernel flipped and its channel axes
//! swapped. On a rayon pool of the machine's cores, as training runs them.
//!
//! `cargo bench -p fusiondet-nn --bench conv2d` (about 1 minute on two cores).

use burn::backend::Flex;
use burn::backend::flex::FlexTensor;
use burn::backend::ops::{ConvOptions, ModuleOps};
use burn::prelude::*;
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use fusiondet_nn::conv2d::flipped_kernel;

/// As the binary: mimalloc, keeping freed memory (`fusiondet_alloc`).
#[global_allocator]
static ALLOCATOR: fusiondet_alloc::MiMalloc = fusiondet_alloc::MiMalloc;

fn filled(shape: [usize; 4], salt: usize) -> FlexTensor {
    let n: usize = shape.iter().product();
    let v: Vec<f32> = (0..n)
        .map(|i| ((i * 7919 + salt * 104_729) % 2003) as f32 / 1001.5 - 1.0)
        .collect();
    FlexTensor::from_data(TensorData::new(v, shape))
}

fn dense_convolutions(c: &mut Criterion) {
    fusiondet_alloc::keep_freed_memory();
    let pool = rayon::ThreadPoolBuilder::new()
        .build()
        .expect("a rayon pool");
    let mut group = c.benchmark_group("conv3x3");
    group.sample_size(20);
    for [batch, channels, height, width] in [[2, 64, 64, 80], [2, 128, 32, 40]] {
        let id = format!("{batch}x{channels}x{height}x{width}");
        let x = filled([batch, channels, height, width], 1);
        let weight_shape = [channels, channels, 3, 3];
        let weight = filled(weight_shape, 2);
        let weight_values = weight.clone().into_data().try_to_vec::<f32>().unwrap();
        let weight_flipped = FlexTensor::from_data(TensorData::new(
            flipped_kernel(&weight_values, weight_shape),
            [channels, channels, 3, 3],
        ));
        let grad = filled([batch, channels, height, width], 3);
        let options = ConvOptions::new([1, 1], [1, 1], [1, 1], 1);
        group.bench_function(BenchmarkId::new("forward", &id), |b| {
            b.iter(|| {
                pool.install(|| Flex::conv2d(x.clone(), weight.clone(), None, options.clone()))
            })
        });
        group.bench_function(BenchmarkId::new("input gradient, transposed", &id), |b| {
            b.iter(|| {
                pool.install(|| {
                    Flex::conv2d_x_backward(
                        x.clone(),
                        weight.clone(),
                        grad.clone(),
                        options.clone(),
                    )
                })
            })
        });
        group.bench_function(
            BenchmarkId::new("input gradient, flipped forward", &id),
            |b| {
                b.iter(|| {
                    pool.install(|| {
                        Flex::conv2d(grad.clone(), weight_flipped.clone(), None, options.clone())
                    })
                })
            },
        );
    }
    group.finish();
}

/// The matrix products behind one frame's 3×3 convolution of the 64-channel 64 × 80 map, in
/// both orientations: weights · patches ([64, 576] · [576, 5120], channels-first) and
/// patches · weights ([5120, 576] · [576, 64], pixels-first), beside a 1024³ product.
fn convolution_products(c: &mut Criterion) {
    use fusiondet_nn::matmul::{MatrixRef, product};
    let pool = rayon::ThreadPoolBuilder::new()
        .build()
        .expect("a rayon pool");
    let mut group = c.benchmark_group("conv3x3_products");
    group.sample_size(20);
    for (name, [m, k, n]) in [
        ("channels-first 64x576x5120", [64, 576, 5120]),
        ("pixels-first 5120x576x64", [5120, 576, 64]),
        ("1024x1024x1024", [1024, 1024, 1024]),
    ] {
        let a: Vec<f32> = (0..m * k).map(|i| (i % 7) as f32 - 3.0).collect();
        let b: Vec<f32> = (0..k * n).map(|i| (i % 5) as f32 - 2.0).collect();
        group.throughput(criterion::Throughput::Elements((2 * m * k * n) as u64));
        group.bench_function(name, |bench| {
            bench.iter(|| {
                pool.install(|| product(MatrixRef::new(&a, [m, k]), MatrixRef::new(&b, [k, n])))
            })
        });
    }
    group.finish();
}

criterion_group!(benches, dense_convolutions, convolution_products);
criterion_main!(benches);
