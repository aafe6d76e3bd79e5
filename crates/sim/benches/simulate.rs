//! Frames per second of the simulator on this machine: a full frame (scene, LiDAR,
//! camera, labels, 2D detections), its parts, and encoding/writing its files; and an indoor
//! scene (room, RGB-D capture, points, labels, 2D detections) with its JPEG.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use fusiondet_sim::{SimConfig, simulate_frame};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let cfg = SimConfig::default();
    let mut g = c.benchmark_group("sim");
    g.sample_size(20);
    // Reported as elements/s = frames per second.
    g.throughput(Throughput::Elements(1));
    // Different frames (worlds) per iteration, so the median covers scene variety.
    let mut i = 0usize;
    g.bench_function("simulate_frame", |b| {
        b.iter(|| {
            i += 1;
            black_box(simulate_frame(7, i % 50, &cfg))
        })
    });
    let frame = simulate_frame(7, 3, &cfg);
    g.bench_function("png_encode", |b| {
        b.iter(|| {
            let mut bytes = Vec::new();
            frame
                .image
                .write_to(
                    &mut std::io::Cursor::new(&mut bytes),
                    image::ImageFormat::Png,
                )
                .unwrap();
            black_box(bytes)
        })
    });
    g.bench_function("velodyne_encode", |b| {
        b.iter(|| black_box(fusiondet_kitti::velodyne::encode_velodyne(&frame.points)))
    });
    g.finish();
    let cfg = fusiondet_sim::indoor::IndoorConfig::default();
    let mut g = c.benchmark_group("sim_indoor");
    g.sample_size(20);
    g.throughput(Throughput::Elements(1));
    let mut i = 0usize;
    g.bench_function("simulate_indoor_frame", |b| {
        b.iter(|| {
            i += 1;
            black_box(fusiondet_sim::indoor::simulate_indoor_frame(
                7,
                i % 50,
                &cfg,
            ))
        })
    });
    let frame = fusiondet_sim::indoor::simulate_indoor_frame(7, 3, &cfg);
    g.bench_function("jpeg_encode", |b| {
        b.iter(|| black_box(fusiondet_sim::indoor::writer::encode_jpeg(&frame.image)))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
