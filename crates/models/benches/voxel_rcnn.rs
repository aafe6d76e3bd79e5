//! Voxel R-CNN stage one on the flex CPU backend over a KITTI-like synthetic sweep
//! (`voxel_rcnn::synthetic`, about 20,000–30,000 voxels): the rulebooks, the sparse 3D
//! backbone, the BEV backbone + anchor head, for the published network; and one submanifold
//! layer against burn's dense `conv3d` on a window of the sweep; the backbone's training pass
//! with the custom flex operations and with burn's generic ones.
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
    // The RoI grid query over stages 2–4 (the published levels), 100 RoIs as at test time:
    // the sweep's cars, repeated with 0.3 m shifts along x.
    let geometry = VoxelGeometry {
        origin: [PUBLISHED_RANGE[0], PUBLISHED_RANGE[1], PUBLISHED_RANGE[2]],
        voxel_size: PUBLISHED_VOXEL,
    };
    let cars = &sweep.cars;
    let rois: Vec<RoiBox> = (0..100)
        .map(|i| {
            let mut roi = cars[i % cars.len()];
            roi[0] += 0.3 * (i / cars.len()) as f64;
            roi
        })
        .collect();
    let rois = vec![rois];
    let levels = &config.roi.levels;
    let level_sites: Vec<&fusiondet_nn::sparse::SparseSites> = levels
        .iter()
        .map(|l| plan.stages[l.stage - 1].1.output.as_ref())
        .collect();
    g.bench_function("roi_grid_index (100 RoIs, 6^3 points, 3 levels)", |b| {
        b.iter(|| {
            RoiGridIndex::new(
                black_box(&rois),
                &level_sites,
                levels,
                config.roi.grid_size,
                &geometry,
            )
        })
    });
    // At a published training step's size: two frames (the sweep twice) of 128 RoIs each.
    let twice: Vec<fusiondet_nn::sparse::SparseSites> = level_sites
        .iter()
        .map(|sites| {
            let coords = (0..2)
                .flat_map(|b| sites.coords().iter().map(move |c| [b, c[1], c[2], c[3]]))
                .collect();
            fusiondet_nn::sparse::SparseSites::new(coords, sites.spatial_shape(), 2)
                .expect("the sweep's sites, twice")
        })
        .collect();
    let twice: Vec<&fusiondet_nn::sparse::SparseSites> = twice.iter().collect();
    let training_rois: Vec<Vec<RoiBox>> = (0..2)
        .map(|_| {
            (0..128)
                .map(|i| {
                    let mut roi = cars[i % cars.len()];
                    roi[0] += 0.3 * (i / cars.len()) as f64;
                    roi
                })
                .collect()
        })
        .collect();
    g.bench_function(
        "roi_grid_index (2 frames × 128 RoIs, 6^3 points, 3 levels)",
        |b| {
            b.iter(|| {
                RoiGridIndex::new(
                    black_box(&training_rois),
                    &twice,
                    levels,
                    config.roi.grid_size,
                    &geometry,
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

/// One submanifold 16 → 16 layer, sparse against burn's dense `conv3d`, on the sweep's
/// voxels in a 16 × 16 m window ahead of the car ([41, 320, 320] cells of the published
/// grid: the sparsity of a KITTI scan near the sensor).
fn sparse_vs_dense(c: &mut Criterion) {
    use burn::tensor::module::conv3d;
    use burn::tensor::ops::ConvOptions;
    use fusiondet_nn::sparse::{RuleLayout, Rulebook, SparseConv3d, SparseSites};
    let device = Device::flex();
    let sweep = synthetic_sweep(1, PUBLISHED_RANGE, PUBLISHED_VOXEL);
    let window = [41usize, 320, 320];
    let (y0, x0) = (640i32, 0i32);
    let coords: Vec<[i32; 4]> = sweep
        .sites
        .coords()
        .iter()
        .filter(|c| (y0..y0 + 320).contains(&c[2]) && (x0..x0 + 320).contains(&c[3]))
        .map(|c| [0, c[1], c[2] - y0, c[3] - x0])
        .collect();
    let n = coords.len();
    let cells: usize = window.iter().product();
    eprintln!(
        "window {window:?}: {n} active sites of {cells} cells ({:.3}%)",
        100.0 * n as f64 / cells as f64
    );
    let sites = Arc::new(SparseSites::new(coords, window, 1).unwrap());
    let conv = SparseConv3d::submanifold([16, 16], [3; 3], &device);
    let x = Tensor::<2>::random([n, 16], burn::tensor::Distribution::Default, &device);
    let book = Rulebook::submanifold(&sites, [3; 3], &device);
    eprintln!(
        "{} pairs: {:.1} neighbours per site",
        book.total_pairs(),
        book.total_pairs() as f64 / n as f64
    );
    let dense_x = Tensor::<5>::random(
        [1, 16, window[0], window[1], window[2]],
        burn::tensor::Distribution::Default,
        &device,
    );
    let weight = conv
        .weight
        .val()
        .permute([2, 1, 0])
        .reshape([16, 16, 3, 3, 3]);
    let mut g = c.benchmark_group("subm_16_16_window");
    g.sample_size(10).measurement_time(Duration::from_secs(8));
    g.bench_function("sparse (rulebook + conv)", |b| {
        b.iter(|| {
            let book = Rulebook::submanifold(&sites, [3; 3], &device);
            sync(&conv.forward(x.clone(), &book))
        })
    });
    g.bench_function("sparse (conv, rulebook given)", |b| {
        b.iter(|| sync(&conv.forward(x.clone(), &book)))
    });
    // The layout GPUs take, here on the CPU: what its multiplied zeros cost where launches
    // are cheap.
    let kernel_map = Rulebook::submanifold_in(&sites, [3; 3], RuleLayout::KernelMap, &device);
    g.bench_function("sparse kernel map (conv, rulebook given)", |b| {
        b.iter(|| sync(&conv.forward(x.clone(), &kernel_map)))
    });
    g.bench_function("dense conv3d", |b| {
        b.iter(|| {
            sync(&conv3d(
                dense_x.clone(),
                weight.clone(),
                None,
                ConvOptions::new([1; 3], [1; 3], [1; 3], 1),
            ))
        })
    });
    g.finish();
}

/// The sparse backbone's training pass (forward, and backward of its output's sum) on the
/// autodiff device, with the custom flex operations that training takes (batch norm over
/// the active rows, `fusiondet_nn::ragged`) and with burn's generic ones, side by side; the
/// same for the BEV backbone and anchor head (`fusiondet_nn::conv2d`).
fn backbone_training(c: &mut Criterion) {
    let device = Device::flex().autodiff();
    let config = VoxelRcnnNetConfig::default();
    let model = VoxelRcnn::new(&config, 41, &device).unwrap();
    let sweep = synthetic_sweep(1, PUBLISHED_RANGE, PUBLISHED_VOXEL);
    let sites = Arc::new(sweep.sites);
    let n = sites.len();
    let features = Tensor::<2>::from_data(TensorData::new(sweep.features, [n, 4]), &device);
    let plan = BackbonePlan::new(sites, &device);
    let mut g = c.benchmark_group("voxel_rcnn_published_train");
    g.sample_size(10).measurement_time(Duration::from_secs(15));
    for (name, custom) in [
        ("backbone3d forward + backward", true),
        ("backbone3d forward + backward, generic ops", false),
    ] {
        fusiondet_nn::ragged::set_custom_ops(custom);
        g.bench_function(name, |b| {
            b.iter(|| {
                let out = model.backbone.forward(features.clone(), &plan);
                let grads = out.output.features.sum().backward();
                let w = model.backbone.output.conv.weight.val();
                sync(&w.grad(&grads).unwrap())
            })
        });
    }
    fusiondet_nn::ragged::set_custom_ops(true);

    // BEV backbone + anchor head on the sweep's height-compressed map (a constant input):
    // the custom path's weight gradients (`fusiondet_nn::conv2d`) against burn's.
    let bev_input =
        height_compression(&model.backbone.forward(features.clone(), &plan).output).detach();
    eprintln!("BEV input {:?}", bev_input.dims());
    for (name, custom) in [
        ("bev + anchor head forward + backward", true),
        ("bev + anchor head forward + backward, generic ops", false),
    ] {
        fusiondet_nn::ragged::set_custom_ops(custom);
        g.bench_function(name, |b| {
            b.iter(|| {
                let p = model
                    .anchor_head
                    .forward(model.bev.forward(bev_input.clone()));
                let total = p.cls.sum() + p.boxes.sum() + p.direction.sum();
                let grads = total.backward();
                let w = model.anchor_head.boxes.weight.val();
                sync(&w.grad(&grads).unwrap())
            })
        });
    }
    fusiondet_nn::ragged::set_custom_ops(true);
    g.finish();
}

criterion_group!(benches, stage_one, sparse_vs_dense, backbone_training);
criterion_main!(benches);
