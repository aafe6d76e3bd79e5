//! STCA's crops (`dasanet::stca::RoiPoints::new`) at a published training step's size: 512
//! RoIs (four frames of 128 sampled RoIs) over a pseudo cloud of 1,024,000 points, 2,000
//! around each RoI, thinned to the default 1,024 a RoI; host work on the network's path
//! in every DASANet training step and detected frame.
//!
//! `cargo bench -p fusiondet-models --bench stca_crops`

use criterion::{Criterion, criterion_group, criterion_main};
use fusiondet_frustum::rng::Sampler;
use fusiondet_models::dasanet::stca::{RoiPoints, StcaConfig};
use std::hint::black_box;
use std::time::Duration;

/// A seeded cloud (x, y, z, r, g, b) of `per_roi` points around each of `rois` car-sized
/// boxes laid out on a grid, and the boxes turned by assorted headings.
fn scene(rois: usize, per_roi: usize) -> (Vec<f32>, Vec<[f64; 7]>) {
    let mut rng = Sampler::new(29);
    let boxes: Vec<[f64; 7]> = (0..rois)
        .map(|r| {
            let (x, y) = (5.0 + (r % 16) as f64 * 4.0, -30.0 + (r / 16) as f64 * 2.0);
            [x, y, -1.0, 3.9, 1.6, 1.5, (r as f64 * 0.37) % 3.1]
        })
        .collect();
    let cloud = boxes
        .iter()
        .flat_map(|b| {
            (0..per_roi)
                .flat_map(|_| {
                    [
                        (b[0] + rng.range(-2.5, 2.5)) as f32,
                        (b[1] + rng.range(-1.5, 1.5)) as f32,
                        (b[2] + rng.range(-1.0, 1.0)) as f32,
                        0.5,
                        0.5,
                        0.5,
                    ]
                })
                .collect::<Vec<f32>>()
        })
        .collect();
    (cloud, boxes)
}

fn crops(c: &mut Criterion) {
    let (cloud, rois) = scene(512, 2_000);
    let batch_of_roi = vec![0; rois.len()];
    let config = StcaConfig::default();
    let kept = RoiPoints::new(&[(&cloud, 6)], &rois, &batch_of_roi, &config).num_points();
    assert!(kept > 200_000, "the RoIs hold points: {kept}");
    let mut g = c.benchmark_group("stca_crops");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    g.bench_function("RoiPoints::new (512 RoIs, 1.02 M points)", |b| {
        b.iter(|| RoiPoints::new(&[(black_box(&cloud), 6)], &rois, &batch_of_roi, &config))
    });
    g.finish();
}

criterion_group!(benches, crops);
criterion_main!(benches);
