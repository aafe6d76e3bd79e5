//! The per-frame data work of a full-size KITTI frame: voxelizing a 120k-point scan
//! over the published range, and assigning the 70,400 anchors to 20 cars.

use criterion::{Criterion, criterion_group, criterion_main};
use fusiondet_dataset::rng::Sampler;
use fusiondet_kitti::ObjectClass;
use fusiondet_voxel::{AnchorAssigner, AnchorConfig, GtBox, LidarBox, VoxelConfig, Voxelizer};
use std::hint::black_box;

fn scan() -> Vec<[f32; 4]> {
    let mut s = Sampler::new(1);
    (0..120_000)
        .map(|_| {
            [
                s.range(-10.0, 75.0) as f32,
                s.range(-45.0, 45.0) as f32,
                s.range(-3.0, 1.5) as f32,
                s.unit() as f32,
            ]
        })
        .collect()
}

fn cars() -> Vec<GtBox> {
    let mut s = Sampler::new(2);
    (0..20)
        .map(|_| GtBox {
            bbox: LidarBox {
                x: s.range(2.0, 70.0),
                y: s.range(-38.0, 38.0),
                z: s.range(-1.5, -0.5),
                dx: s.range(3.2, 4.8),
                dy: s.range(1.4, 1.9),
                dz: s.range(1.3, 1.8),
                heading: s.range(-3.1, 3.1),
            },
            class: ObjectClass::Car,
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let points = scan();
    let config = VoxelConfig::default();
    let v = Voxelizer::new(&config).unwrap();
    c.bench_function("voxelize 120k points, test cap", |b| {
        b.iter(|| v.voxelize(black_box(&points), config.max_voxels_test, None))
    });
    c.bench_function("voxelize 120k points, shuffled, train cap", |b| {
        b.iter(|| {
            v.voxelize(
                black_box(&points),
                config.max_voxels_train,
                Some(&mut Sampler::new(3)),
            )
        })
    });
    let assigner = AnchorAssigner::new(&config, &AnchorConfig::default()).unwrap();
    let gts = cars();
    c.bench_function("assign 70,400 anchors to 20 cars", |b| {
        b.iter(|| assigner.assign(black_box(&gts)))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
