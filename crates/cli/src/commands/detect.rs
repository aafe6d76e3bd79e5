//! `fusiondet detect`: runs a trained detector of any family on a split and writes KITTI
//! results.

use fusiondet_models::DetectorKind;
use fusiondet_pipeline::{ComputeDevice, DetectOptions, ExperimentConfig, detect};
use fusiondet_workflows::outln;
use std::path::PathBuf;

/// The arguments `detect` and `bench` share: a model, its configuration, the frames and
/// 2D detections to run it on, and the test-time point count.
#[derive(clap::Args)]
pub struct ModelOnSplit {
    /// Trained weights (a run's model.bpk, or a shipped model under models/).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Experiment configuration the checkpoint was trained with; by default the
    /// `config.toml` beside the checkpoint (a run directory), else `<checkpoint>.toml`.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Dataset root: KITTI (training/, ImageSets/, rgb_detections/) or, for a SUN RGB-D
    /// model, a prepared SUN RGB-D directory (points/, calib/, det_2d/, splits/).
    #[arg(long)]
    pub data: PathBuf,
    /// Frames to run on: a split name (DATA/ImageSets/<name>.txt; SUN RGB-D:
    /// DATA/splits/<name>.txt) or a file of frame ids, one per line.
    #[arg(long, default_value = "val", value_name = "NAME|FILE")]
    pub split: String,
    /// 2D detections (F-PointNet format); default DATA/rgb_detections/rgb_detection_<split>.txt
    /// (a split file's name without .txt).
    /// SUN RGB-D: a directory of `<id>.txt` files as in DATA/det_2d/ (the default).
    #[arg(long)]
    pub detections: Option<PathBuf>,
    /// Points sampled per frustum at test time (overrides detect.points_per_frustum:
    /// fewer is faster).
    #[arg(long)]
    pub points: Option<usize>,
    /// Where the network runs: `cpu`; `wgpu`, `cuda` or `cuda:N` in builds with the cargo
    /// feature of that name.
    #[arg(long, default_value = "cpu")]
    pub device: ComputeDevice,
    /// DASANet: completed depth maps (`<id>.png`, KITTI depth format, e.g. from
    /// `fusiondet depth-complete`) to make the pseudo points from, instead of completing
    /// each frame's scan.
    #[arg(long)]
    pub depth_dir: Option<PathBuf>,
}

impl ModelOnSplit {
    /// The checkpoint's configuration with `--points` applied.
    pub fn experiment_config(&self) -> anyhow::Result<ExperimentConfig> {
        let config = ExperimentConfig::for_checkpoint(&self.checkpoint, self.config.as_deref())?;
        Ok(match self.points {
            Some(_) => config.with_test_points(self.points)?,
            None => config,
        })
    }
}

#[derive(clap::Args)]
pub struct DetectArgs {
    #[command(flatten)]
    pub input: ModelOnSplit,
    /// Result directory: one KITTI (or SUN RGB-D) result file per frame (new or empty, or an earlier
    /// detect's with --force).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the results an earlier detect left in --out.
    #[arg(long)]
    pub force: bool,
    /// Detect only the frames at positions k of the split with k mod N = I. The shards of
    /// one run share --out; the last to finish writes its manifest (`fusiondet merge`
    /// checks and finishes it too), after which it equals one unsharded run's.
    /// With --force, another run's results there are replaced.
    #[arg(long, value_name = "I/N")]
    pub shard: Option<fusiondet_kitti::Shard>,
}

pub fn run(args: DetectArgs) -> anyhow::Result<()> {
    let config = args.input.experiment_config()?;
    super::data_root::check_root("--data", &args.input.data)?;
    let kind = config.kind();
    let input = args.input;
    let s = detect(&DetectOptions {
        config,
        checkpoint: input.checkpoint,
        data_dir: input.data,
        split: input.split,
        out_dir: args.out.clone(),
        detections: input.detections,
        depth_dir: input.depth_dir,
        device: input.device,
        replace: args.force,
        shard: args.shard,
    })?;
    let skipped = s.skipped;
    match kind {
        DetectorKind::Frustum => {
            outln!(
                "{} frames, {} 2D detections -> {} frustums -> {} boxes written to {}",
                s.frames,
                s.detections_2d,
                s.samples,
                s.boxes_written,
                args.out.display()
            );
            outln!(
                "skipped frustums: {} outside the image, {} too small, {} without points, {} in frames not in the split",
                skipped.outside_image,
                skipped.too_small,
                skipped.no_points,
                skipped.unknown_frame
            );
        }
        DetectorKind::VoxelRcnn => outln!(
            "{} frames ({} with LiDAR points in range) -> {} boxes written to {}",
            s.frames,
            s.samples,
            s.boxes_written,
            args.out.display()
        ),
        DetectorKind::Dasanet => outln!(
            "{} frames ({} with LiDAR and pseudo points in range) -> {} boxes written to {}",
            s.frames,
            s.samples,
            s.boxes_written,
            args.out.display()
        ),
    }
    if let (Some(shard), Some(progress)) = (args.shard, &s.shards) {
        super::shards::report(shard, &args.out, progress);
    }
    let t = &s.timing;
    let stages: Vec<String> = t
        .stages()
        .iter()
        .map(|(name, d)| format!("{name} {:.3} s", d.as_secs_f64()))
        .collect();
    outln!(
        "time: load {:.2} s, {}",
        t.load.as_secs_f64(),
        stages.join(", ")
    );
    if t.overlap() > std::time::Duration::ZERO {
        outln!(
            "      {:.3} s in all: frames were prepared beside the network while it \
             ran, {:.3} s of the stages side by side",
            t.compute().as_secs_f64(),
            t.overlap().as_secs_f64()
        );
    }
    Ok(())
}
