//! `fusiondet bench`: detection speed of a trained model — frames/s and the share of each
//! stage, medians over repeated runs on in-memory frames.

use crate::commands::detect::config_for_checkpoint;
use fusiondet_train::{BenchOptions, bench_detect};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct BenchArgs {
    /// Model weights (a run's model.bpk, or models/fconvnet-car.bpk).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Experiment configuration; by default the checkpoint's `.toml` twin or its run's config.toml.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Dataset root.
    #[arg(long)]
    pub data: PathBuf,
    #[arg(long, default_value = "val")]
    pub split: String,
    /// 2D detection file (default: DATA/rgb_detections/rgb_detection_<split>.txt).
    #[arg(long)]
    pub detections: Option<PathBuf>,
    /// Timed runs after one warm-up run.
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Use at most this many frames of the split (0 = all).
    #[arg(long, default_value_t = 0)]
    pub max_frames: usize,
    /// Points sampled per frustum at test time (overrides detect.points_per_frustum).
    #[arg(long)]
    pub points: Option<usize>,
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    if args.repeats == 0 {
        anyhow::bail!("--repeats must be at least 1");
    }
    let mut config = config_for_checkpoint(&args.checkpoint, args.config.as_deref())?;
    if args.points.is_some() {
        config = config.with_test_points(args.points)?;
    }
    let name = config.name.clone();
    let bench = bench_detect(&BenchOptions {
        config,
        checkpoint: args.checkpoint,
        data_dir: args.data,
        split: args.split,
        detections: args.detections,
        repeats: args.repeats,
        max_frames: args.max_frames,
    })?;
    println!("{name}: {bench}");
    Ok(())
}
