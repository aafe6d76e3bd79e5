//! `fusiondet detect`: runs a trained frustum detector on a split and writes KITTI results.

use fusiondet_train::{DetectOptions, ExperimentConfig, detect};
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct DetectArgs {
    /// Trained weights (a run's model.bpk, or a shipped model under models/).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Experiment configuration the checkpoint was trained with; by default the
    /// `config.toml` beside the checkpoint (a run directory), else `<checkpoint>.toml`.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Dataset root with training/, ImageSets/ and rgb_detections/.
    #[arg(long)]
    pub data: PathBuf,
    #[arg(long, default_value = "val")]
    pub split: String,
    /// Result directory: one KITTI result file per frame.
    #[arg(long)]
    pub out: PathBuf,
    /// 2D detections (F-PointNet format); default DATA/rgb_detections/rgb_detection_<split>.txt.
    #[arg(long)]
    pub detections: Option<PathBuf>,
    /// Points sampled per frustum at test time (overrides detect.points_per_frustum:
    /// fewer is faster).
    #[arg(long)]
    pub points: Option<usize>,
}

/// The configuration that belongs to a checkpoint.
pub fn config_for_checkpoint(
    checkpoint: &Path,
    explicit: Option<&Path>,
) -> anyhow::Result<ExperimentConfig> {
    if let Some(path) = explicit {
        return Ok(ExperimentConfig::from_file(path)?);
    }
    let beside = checkpoint.with_extension("toml");
    let run_config = checkpoint.parent().map(|d| d.join("config.toml"));
    for candidate in [Some(beside), run_config].into_iter().flatten() {
        if candidate.is_file() {
            return Ok(ExperimentConfig::from_file(&candidate)?);
        }
    }
    anyhow::bail!(
        "no configuration found for {}: pass --config, or keep the run's config.toml beside it",
        checkpoint.display()
    )
}

pub fn run(args: DetectArgs) -> anyhow::Result<()> {
    let mut config = config_for_checkpoint(&args.checkpoint, args.config.as_deref())?;
    if args.points.is_some() {
        config = config.with_test_points(args.points)?;
    }
    let s = detect(&DetectOptions {
        config,
        checkpoint: args.checkpoint,
        data_dir: args.data,
        split: args.split,
        out_dir: args.out.clone(),
        detections: args.detections,
    })?;
    let skipped = s.skipped;
    println!(
        "{} frames, {} 2D detections -> {} frustums -> {} boxes written to {}",
        s.frames,
        s.detections_2d,
        s.frustums,
        s.boxes_written,
        args.out.display()
    );
    println!(
        "skipped frustums: {} outside the image, {} too small, {} without points, {} in frames not in the split",
        skipped.outside_image, skipped.too_small, skipped.no_points, skipped.unknown_frame
    );
    let t = &s.timing;
    println!(
        "time: load {:.2} s, frustums {:.2} s, network {:.2} s, decode+nms {:.3} s",
        t.load.as_secs_f64(),
        t.frustums.as_secs_f64(),
        t.network.as_secs_f64(),
        t.decode_nms.as_secs_f64()
    );
    Ok(())
}
