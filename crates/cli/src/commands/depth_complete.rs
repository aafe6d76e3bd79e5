//! `fusiondet depth-complete`: dense depth from sparse depth (IP-Basic's fast pipeline),
//! in the KITTI depth-completion format; the work lives in `fusiondet-depth`.

use anyhow::bail;
use fusiondet_depth::{
    Blur, DepthCompleter, DepthErrors, DepthMap, IpBasic, read_depth_png, write_depth_png,
};
use fusiondet_kitti::FrameDir;
use fusiondet_kitti::paths::{Inputs, check_output_dir, check_output_file};
use fusiondet_workflows::outln;
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Method {
    /// IP-Basic's fast pipeline.
    Fast,
    /// IP-Basic's multiscale pipeline (per-range dilations; the image above the scan
    /// stays empty with --no-extrapolate).
    Multiscale,
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum BlurArg {
    Gaussian,
    Bilateral,
}

#[derive(clap::Args)]
#[command(after_help = "\
Inputs and outputs are KITTI depth-completion PNGs: 16-bit grey, value = metres x 256, \
0 = no measurement. Give one of --sparse (one map, with --out), --sparse-dir (every PNG of a \
directory, with --out-dir) or --data-dir (a KITTI training/ directory: each frame's velodyne \
scan projected into image_2, nearest point per pixel, then completed; with --out-dir).")]
pub struct DepthCompleteArgs {
    /// One sparse depth map.
    #[arg(long, conflicts_with_all = ["sparse_dir", "data_dir"])]
    pub sparse: Option<PathBuf>,
    /// Output PNG for --sparse (written atomically).
    #[arg(long, requires = "sparse")]
    pub out: Option<PathBuf>,
    /// A directory of sparse depth maps.
    #[arg(long, conflicts_with = "data_dir")]
    pub sparse_dir: Option<PathBuf>,
    /// KITTI training/ directory (velodyne/, calib/, image_2/).
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Output directory for --sparse-dir and --data-dir (must not be an input directory).
    #[arg(long)]
    pub out_dir: Option<PathBuf>,
    /// Frame ids for --data-dir (default: every frame with a velodyne scan).
    #[arg(long, value_delimiter = ',')]
    pub ids: Vec<String>,
    /// The pipeline (default: the one that measured best here; see docs/depth.md).
    #[arg(long, value_enum, default_value = "fast")]
    pub method: Method,
    /// The last smoothing step.
    #[arg(long, value_enum, default_value = "gaussian")]
    pub blur: BlurArg,
    /// Extend each column's top depth upward and fill large holes (31x31): the default.
    #[arg(long, overrides_with = "no_extrapolate")]
    pub extrapolate: bool,
    /// Leave the image above the scan empty.
    #[arg(long)]
    pub no_extrapolate: bool,
    /// With --data-dir: measure instead of writing. Hold out this share of each frame's
    /// projected LiDAR pixels (seeded by --seed), complete from the rest and print MAE,
    /// RMSE (mm), iMAE and iRMSE (1/km) on the held-out pixels.
    #[arg(long, requires = "data_dir", conflicts_with_all = ["out_dir", "truth_dir"])]
    pub holdout: Option<f64>,
    /// With --data-dir: measure instead of writing, against the dense depth maps in this
    /// directory (`<id>.png`; a simulated data set has them in training/depth_2/), on the
    /// pixels a LiDAR-based truth covers: up to --max-depth, at or below each column's
    /// topmost scanned pixel.
    #[arg(long, requires = "data_dir", conflicts_with = "out_dir")]
    pub truth_dir: Option<PathBuf>,
    /// Ground-truth depths beyond this (metres) are left out of --truth-dir errors
    /// (KITTI's depth-completion truth ends near 80 m).
    #[arg(long, default_value_t = 80.0)]
    pub max_depth: f32,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// With --data-dir and --out-dir: complete only the frames at positions k of the frame
    /// list with k mod N = I (`fusiondet merge --dir OUT_DIR` checks that all shards ran).
    #[arg(long, value_name = "I/N", requires = "out_dir")]
    pub shard: Option<fusiondet_kitti::Shard>,
}

pub fn run(args: DepthCompleteArgs) -> anyhow::Result<()> {
    let completer = IpBasic {
        method: match args.method {
            Method::Fast => fusiondet_depth::Method::Fast,
            Method::Multiscale => fusiondet_depth::Method::Multiscale,
        },
        extrapolate: !args.no_extrapolate,
        blur: match args.blur {
            BlurArg::Gaussian => Blur::Gaussian,
            BlurArg::Bilateral => Blur::Bilateral,
        },
        ..Default::default()
    };
    if let Some(sparse) = &args.sparse {
        let Some(out) = &args.out else {
            bail!("--sparse needs --out FILE.png");
        };
        let inputs = Inputs::new().with("--sparse", Some(sparse));
        check_output_file("--out", out, &inputs)?;
        let map = read_depth_png(sparse)?;
        let dense = completer.complete(&map);
        write_depth_png(out, &dense)?;
        outln!(
            "{}: {} of {} pixels measured -> {} filled -> {}",
            sparse.display(),
            map.valid_count(),
            map.width * map.height,
            dense.valid_count(),
            out.display()
        );
        return Ok(());
    }
    if let Some(dir) = &args.data_dir {
        super::data_root::check_frames("--data-dir", dir)?;
        let frames = FrameDir::new(dir);
        if let Some(fraction) = args.holdout {
            if !(fraction > 0.0 && fraction < 1.0) {
                bail!("--holdout must be in (0, 1), got {fraction}");
            }
            return measure(&frames, &args.ids, &|k, _, sparse| {
                let seed = args.seed ^ k as u64;
                Ok(fusiondet_depth::holdout_errors(
                    sparse, fraction, seed, &completer,
                )?)
            });
        }
        if let Some(truth_dir) = &args.truth_dir {
            return measure(&frames, &args.ids, &|_, id, sparse| {
                let path = truth_dir.join(format!("{id}.png"));
                let mut truth = read_depth_png(&path)?;
                fusiondet_depth::restrict_to_scan_coverage(&mut truth, sparse, args.max_depth);
                let dense = completer.complete(sparse);
                fusiondet_depth::depth_errors(&dense, &truth)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
            });
        }
    }
    let Some(out_dir) = &args.out_dir else {
        bail!("give --sparse FILE --out FILE, or --sparse-dir / --data-dir with --out-dir DIR");
    };
    let summary = match (&args.sparse_dir, &args.data_dir) {
        (Some(_), None) if args.shard.is_some() => {
            bail!("--shard splits the frames of --data-dir; complete a --sparse-dir unsharded")
        }
        (Some(dir), None) => {
            let maps = std::fs::read_dir(dir).map_or(0, |d| d.count());
            let bar = super::progress::bar("depth-complete", maps, "maps");
            let summary = fusiondet_depth::complete_dir(dir, out_dir, &completer, &|| bar.inc(1))?;
            bar.finish_and_clear();
            summary
        }
        (None, Some(dir)) => {
            let frames = FrameDir::new(dir);
            // Before anything is made or locked: the output may not touch what is read.
            check_output_dir(
                "--out-dir",
                out_dir,
                &Inputs::new().with("--data-dir", Some(dir)),
            )?;
            let ids = fusiondet_depth::frame_ids(&frames, &args.ids)?;
            let run = format!("{:?} {}", completer, super::shards::canonical(dir));
            super::shards::run_frames(
                "depth-complete",
                out_dir,
                args.shard,
                &[run.as_bytes()],
                &frames,
                ids,
                |ids| {
                    let bar = super::progress::bar("depth-complete", ids.len(), "frames");
                    let summary = fusiondet_depth::complete_frames(
                        &frames,
                        ids,
                        out_dir,
                        &completer,
                        &|| bar.inc(1),
                    )?;
                    bar.finish_and_clear();
                    Ok(summary)
                },
            )?
        }
        _ => bail!("give --sparse-dir or --data-dir (one of them) with --out-dir"),
    };
    outln!(
        "{} depth maps: {} measured pixels -> {} filled -> {}",
        summary.maps,
        summary.sparse_pixels,
        summary.dense_pixels,
        out_dir.display()
    );
    Ok(())
}

/// Prints the errors of each frame (projected scan → `errors_of`) and over all of them.
fn measure(
    frames: &FrameDir,
    ids: &[String],
    errors_of: &dyn Fn(usize, &str, &DepthMap) -> anyhow::Result<DepthErrors>,
) -> anyhow::Result<()> {
    let ids = fusiondet_depth::frame_ids(frames, ids)?;
    let line = |e: &DepthErrors| {
        format!(
            "{} pixels ({} left empty), MAE {:.1} mm, RMSE {:.1} mm, iMAE {:.2} /km, iRMSE {:.2} /km",
            e.pixels, e.missing, e.mae_mm, e.rmse_mm, e.imae_per_km, e.irmse_per_km
        )
    };
    let mut per_frame = Vec::with_capacity(ids.len());
    for (k, id) in ids.iter().enumerate() {
        let frame = fusiondet_dataset::SensorFrame::load(frames, id, false)?;
        let e = errors_of(k, id, &fusiondet_depth::project_scan(&frame))?;
        outln!("{id}: {}", line(&e));
        per_frame.push(e);
    }
    outln!(
        "all {} frames: {}",
        ids.len(),
        line(&DepthErrors::pool(&per_frame))
    );
    Ok(())
}
