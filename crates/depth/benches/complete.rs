//! Depth completion per 1242×375 frame: projecting a bundled KITTI scan, and IP-Basic's
//! fast pipeline with each blur.
//!
//! `cargo bench -p fusiondet-depth`

use criterion::{Criterion, criterion_group, criterion_main};
use fusiondet_dataset::SensorFrame;
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
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
