//! The voxel family's CPU training step as the binary runs it (`fusiondet_pipeline::train`:
//! data thread, steps on the compute pool), for the Voxel R-CNN and DASANet CPU rows
//! (`configs/voxel-rcnn-car-sim.toml`, `configs/dasanet-car-sim.toml`) on a few simulated
//! frames: with the custom flex operations training takes (`fusiondet_nn::ragged`,
//! `batch_norm_ops`, `conv2d`, `sparse::fused`) and with burn's generic operations (the
//! path before them), side by side in one run. Each sample is one epoch of `STEPS` steps;
//! the figure is the epoch's time per step (its first step, with the warm-up, included),
//! read from the run's `metrics.jsonl`, so start-up (ground-truth database, model set-up)
//! is not counted.
//!
//! `cargo bench -p fusiondet-pipeline --bench train_step` (about 8 minutes on two cores).

use criterion::{Criterion, criterion_group, criterion_main};
use fusiondet_nn::ragged::set_custom_ops;
use fusiondet_pipeline::{ExperimentConfig, TrainOptions, train};
use std::path::Path;
use std::time::Duration;

/// As the binary: mimalloc, keeping freed memory (`fusiondet_alloc`).
#[global_allocator]
static ALLOCATOR: fusiondet_alloc::MiMalloc = fusiondet_alloc::MiMalloc;

/// Steps per sample (batch 2).
const STEPS: usize = 6;

/// One epoch of `config` over the first `2 · STEPS` frames; its time per step.
fn epoch_step_time(config: &ExperimentConfig, data: &Path, run: &Path) -> Duration {
    let _ = std::fs::remove_dir_all(run);
    train(&TrainOptions::new(config.clone(), data, run)).expect("a training epoch");
    let metrics = std::fs::read_to_string(run.join("metrics.jsonl")).unwrap();
    let last: serde_json::Value = serde_json::from_str(metrics.lines().last().unwrap()).unwrap();
    let (seconds, steps) = (
        last["seconds"].as_f64().unwrap(),
        last["batches"].as_f64().unwrap(),
    );
    Duration::from_secs_f64(seconds / steps)
}

fn voxel_rows(c: &mut Criterion) {
    fusiondet_alloc::keep_freed_memory();
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("sim");
    fusiondet_sim::write_dataset(
        &fusiondet_sim::DatasetOptions::new(&data, 2 * STEPS, 11),
        &|_, _| {},
    )
    .unwrap();
    let configs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
    let mut g = c.benchmark_group("train_step");
    g.sample_size(10).measurement_time(Duration::from_secs(60));
    for name in ["voxel-rcnn-car-sim", "dasanet-car-sim"] {
        let mut config =
            ExperimentConfig::from_file(&configs.join(format!("{name}.toml"))).unwrap();
        config.train.epochs = 1;
        config.train.max_frames = 2 * STEPS;
        let run = dir.path().join(name);
        for (variant, custom) in [("custom ops", true), ("generic ops", false)] {
            set_custom_ops(custom);
            g.bench_function(format!("{name} ({variant})"), |b| {
                b.iter_custom(|iters| {
                    (0..iters)
                        .map(|_| epoch_step_time(&config, &data, &run))
                        .sum()
                })
            });
        }
        set_custom_ops(true);
    }
    g.finish();
}

criterion_group!(benches, voxel_rows);
criterion_main!(benches);
