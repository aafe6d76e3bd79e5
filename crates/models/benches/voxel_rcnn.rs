//! Voxel R-CNN stage one on the flex CPU backend over a KITTI-like synthetic sweep
//! (`voxel_rcnn::synthetic`, about 20,000–30,000 voxels): the rulebooks, the sparse 3D
//! backbone, the BEV backbone + anchor head, for the published network.
//!
//! `cargo bench -p fusiondet-models --bench voxel_rcnn`

use burn::prelude::*;
use criterion::{Criterion, criterion_group, criterion_main};
use fusiondet_models::voxel_rcnn::synthetic::{PUBLISHED_RANGE, PUBLISHED_VOXEL, synthetic_sweep};
use fusiondet_models::voxel_rcnn::*;
use std::hint::black_box;
use std::sync::Arc;
use std::time::Duration;

fn sync<const D: usize>(t: &Tensor<D>) -> f32 {
    t.try_to_vec_as::<f32>().unwrap()[0]
}

fn stage_one(c: &mut Criterion) {
    let device = Device::flex();
    let config = VoxelRcnnNetConfig::default();
    let model = VoxelRcnn::new(&config, 41, &device).unwrap().valid();
    let sweep = synthetic_sweep(1, PUBLISHED_RANGE, PUBLISHED_VOXEL);
    let sites = Arc::new(sweep.sites);
    let n = sites.len();
    let features = Tensor::<2>::from_data(TensorData::new(sweep.features, [n, 4]), &device);
    let plan = BackbonePlan::new(sites.clone(), &device);
    eprintln!(
        "{} points → {n} voxels; sites per stage {:?}; backbone {:.2} G multiply-adds",
        sweep.points,
        plan.site_counts(),
        plan.multiply_adds(&config) as f64 / 1e9
    );
    let mut g = c.benchmark_group("voxel_rcnn_published");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    g.bench_function("rulebooks", |b| {
        b.iter(|| BackbonePlan::new(black_box(sites.clone()), &device))
    });
    g.bench_function("backbone3d_forward", |b| {
        b.iter(|| {
            sync(
                &model
                    .backbone
                    .forward(features.clone(), &plan)
                    .output
                    .features,
            )
        })
    });
    let out = model.backbone.forward(features.clone(), &plan);
    g.bench_function("height_compression", |b| {
        b.iter(|| {
            height_compression(&out.output)
                .slice([0..1, 0..1, 0..1, 0..1])
                .into_scalar::<f32>()
        })
    });
    g.bench_function(
        "bev_stage (height compression, BEV backbone, anchor head)",
        |b| {
            b.iter(|| {
                sync(
                    &model
                        .anchor_head
                        .forward(model.bev.forward(height_compression(&out.output)))
                        .cls,
                )
            })
        },
    );
    g.finish();

    // The machine's matrix-multiply rate, for the ratio in the notes.
    let mut g = c.benchmark_group("reference");
    g.sample_size(10).measurement_time(Duration::from_secs(6));
    let a = Tensor::<2>::random([2048, 2048], burn::tensor::Distribution::Default, &device);
    g.bench_function("matmul 2048^3 (8.59 G multiply-adds)", |b| {
        b.iter(|| sync(&a.clone().matmul(a.clone())))
    });
    g.finish();
}

criterion_group!(benches, stage_one);
criterion_main!(benches);
