//! `fusiondet pseudo-points`: each frame's completed depth back-projected into a coloured
//! pseudo point cloud (DASANet's second input); the work lives in `fusiondet-depth`.

use fusiondet_depth::{IpBasic, Thinning};
use fusiondet_kitti::FrameDir;
use fusiondet_kitti::paths::{Inputs, check_output_dir};
use fusiondet_workflows::outln;
use std::path::PathBuf;

#[derive(clap::Args)]
#[command(after_help = "\
Writes OUT_DIR/<id>.bin: little-endian float32 x 8 per point: x, y, z (LiDAR frame, metres), \
r, g, b (0-255, from image_2), u, v (pixel column and row). One point per completed pixel, \
back-projected through the pixel centre at its depth with the inverse of R0_rect and \
Tr_velo_to_cam and P2's focal, centre and baseline terms.")]
pub struct PseudoPointsArgs {
    /// KITTI training/ directory (velodyne/, calib/, image_2/).
    #[arg(long)]
    pub data_dir: PathBuf,
    /// Completed depth maps (`<id>.png`, e.g. from `fusiondet depth-complete`); without
    /// it, each frame's scan is projected and completed here: IP-Basic fast with the
    /// Gaussian and without extrapolation, so no points are invented above the scan.
    #[arg(long)]
    pub depth_dir: Option<PathBuf>,
    /// Output directory (must not be an input directory).
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Frame ids (default: every frame with a velodyne scan).
    #[arg(long, value_delimiter = ',')]
    pub ids: Vec<String>,
    /// SFD's near-range thinning: where x < 13 m keep only pixels with odd u and v.
    #[arg(long)]
    pub thin: bool,
    /// Write only the frames at positions k of the frame list with k mod N = I
    /// (`fusiondet merge --dir OUT_DIR` checks that all shards ran).
    #[arg(long, value_name = "I/N")]
    pub shard: Option<fusiondet_kitti::Shard>,
}

pub fn run(args: PseudoPointsArgs) -> anyhow::Result<()> {
    super::data_root::check_frames("--data-dir", &args.data_dir)?;
    let frames = FrameDir::new(&args.data_dir);
    // Before anything is made or locked: the output may not touch what is read.
    let inputs = Inputs::new()
        .with("--data-dir", Some(&args.data_dir))
        .with("--depth-dir", args.depth_dir.as_deref());
    check_output_dir("--out-dir", &args.out_dir, &inputs)?;
    let ids = fusiondet_depth::frame_ids(&frames, &args.ids)?;
    let completer = IpBasic {
        extrapolate: false,
        ..IpBasic::measured_best()
    };
    let thinning = args.thin.then(Thinning::default);
    let run = format!(
        "{completer:?} {thinning:?} {} {}",
        super::shards::canonical(&args.data_dir),
        args.depth_dir
            .as_deref()
            .map(super::shards::canonical)
            .unwrap_or_default()
    );
    let summary = super::shards::run_frames(
        "pseudo-points",
        &args.out_dir,
        args.shard,
        &[run.as_bytes()],
        &frames,
        ids,
        |ids| {
            let bar = super::progress::bar("pseudo-points", ids.len(), "frames");
            let summary = fusiondet_depth::pseudo_frames(
                &frames,
                ids,
                args.depth_dir.as_deref(),
                &args.out_dir,
                &completer,
                thinning,
                &|| bar.inc(1),
            )?;
            bar.finish_and_clear();
            Ok(summary)
        },
    )?;
    outln!(
        "{} frames: {} pseudo points ({:.0} per frame) -> {}",
        summary.frames,
        summary.points,
        summary.points as f64 / summary.frames.max(1) as f64,
        args.out_dir.display()
    );
    Ok(())
}
