//! Speed of a validation-split-sized evaluation (3769 frames, ~10 ground-truth boxes and
//! ~10 detections per frame; the devkit needs about 31 s): in memory, and from disk
//! including reading and parsing the 7538 files. The synthetic set is seeded, so every
//! run measures the same data.

use criterion::{Criterion, criterion_group, criterion_main};
use fusiondet_eval::{EvalConfig, evaluate, evaluate_dirs, synthetic};
use std::hint::black_box;
use std::time::Duration;

const FRAMES: usize = 3769;
const SEED: u64 = 20_240_601;

fn bench(c: &mut Criterion) {
    let (gt, det) = synthetic::generate(FRAMES, SEED);
    let cfg = EvalConfig::default();

    let dir = tempfile::tempdir().expect("temporary directory");
    let (label_dir, result_dir) = (dir.path().join("label_2"), dir.path().join("results"));
    std::fs::create_dir_all(&label_dir).unwrap();
    std::fs::create_dir_all(&result_dir).unwrap();
    for (g, d) in gt.iter().zip(&det) {
        fusiondet_kitti::write_objects(&label_dir.join(format!("{}.txt", g.id)), &g.objects)
            .unwrap();
        fusiondet_kitti::write_objects(&result_dir.join(format!("{}.txt", d.id)), &d.objects)
            .unwrap();
    }

    let mut group = c.benchmark_group("kitti_eval_3769_frames");
    group
        .sample_size(20)
        .measurement_time(Duration::from_secs(15));
    group.bench_function("in_memory", |b| {
        b.iter(|| evaluate(black_box(&gt), black_box(&det), &cfg).unwrap())
    });
    group.bench_function("from_disk", |b| {
        b.iter(|| evaluate_dirs(black_box(&label_dir), &result_dir, None, &cfg).unwrap())
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
