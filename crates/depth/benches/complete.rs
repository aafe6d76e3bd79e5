//! Depth completion per 1242×375 frame: projecting a bundled KITTI scan, IP-Basic's
//! pipelines, and the steps that cost most on the default setting's dense map.
//!
//! `cargo bench -p fusiondet-depth`

use criterion::{Criterion, criterion_group, criterion_main};
use fusiondet_dataset::SensorFrame;
use fusiondet_depth::image_ops::{Kernel, bilateral, dilate, median5};
use fusiondet_depth::{Blur, IpBasic, Method, complete, project_scan};
use fusiondet_kitti::FrameDir;
use std::hint::black_box;
use std::path::Path;

fn bench(c: &mut Criterion) {
    let dir = FrameDir::new(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/kitti-sample/training"),
    );
    let frame = SensorFrame::load(&dir, "000001", false).unwrap();
    c.bench_function("project scan 000001", |b| {
        b.iter(|| project_scan(black_box(&frame)))
    });
    let sparse = project_scan(&frame);
    for (name, settings) in [
        (
            "gaussian",
            IpBasic {
                blur: Blur::Gaussian,
                ..Default::default()
            },
        ),
        (
            "bilateral",
            IpBasic {
                blur: Blur::Bilateral,
                ..Default::default()
            },
        ),
        ("gaussian extrapolated (default)", IpBasic::measured_best()),
        (
            "multiscale gaussian",
            IpBasic {
                method: Method::Multiscale,
                ..Default::default()
            },
        ),
    ] {
        c.bench_function(&format!("ip-basic {name}"), |b| {
            b.iter(|| complete(black_box(&sparse), &settings))
        });
    }
    let dense = complete(&sparse, &IpBasic::measured_best());
    c.bench_function("median 5x5 (dense)", |b| {
        b.iter(|| median5(black_box(&dense)))
    });
    c.bench_function("dilate 31x31 (dense)", |b| {
        b.iter(|| dilate(black_box(&dense), &Kernel::full(31)))
    });
    c.bench_function("bilateral 5 (dense)", |b| {
        b.iter(|| bilateral(black_box(&dense), 5, 1.5, 2.0))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
