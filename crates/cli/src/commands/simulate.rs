//! `fusiondet simulate`: writes a simulated KITTI-format dataset (LiDAR, camera,
//! labels, calibration, splits, F-PointNet-style 2D detections). The work lives in
//! `fusiondet-sim`.

use anyhow::Context;
use fusiondet_sim::{DatasetOptions, SimConfig, write_dataset, write_dataset_shard};
use fusiondet_workflows::{out, outln};
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::time::Instant;

const AFTER_HELP: &str = "\
Writes DIR/training/{velodyne,calib,label_2,image_2,depth_2}/NNNNNN.* (depth_2: the
camera's true depth, KITTI depth-completion PNGs), DIR/ImageSets/{train,val,trainval}.txt, DIR/rgb_detections/rgb_detection_{train,val}.txt (F-PointNet format) and
DIR/sim_stats.json (realism statistics). The same seed gives byte-identical files on any
machine; frames are generated in parallel.

Each frame is a random street (city, residential, arterial road or campus) seen by a
Velodyne HDL-64E (64 rings at KITTI's measured elevations, 2,160 firings per laser,
120 m) and KITTI's left colour camera (1242x375), both ray cast through the same scene.
Labels: truncation = share of the projected 3D box outside the image; occlusion from the
share of the object's pixels hidden by nearer surfaces (0: <10%, 1: <60%, 2: <90%, 3);
far (> 80 m) or small (< 18 px) objects become DontCare.

--stats prints the realism report (points on cars by distance next to KITTI's curve,
class mix, occlusion and truncation shares, difficulty counts, 2D detector behaviour).

--indoor writes rooms instead, in the prepared SUN RGB-D layout: DIR/points/NNNNNN.bin
(float32 x y z r g b, upright depth), image/NNNNNN.jpg, depth/NNNNNN.png (raw 16-bit depth,
millimetres rotated right by 3 bits), calib/NNNNNN.txt (3x3 depth-to-image matrix),
label/NNNNNN.txt (class cx cy cz dx dy dz yaw x1 y1 x2 y2), det_2d/NNNNNN.txt (simulated 2D
detections), splits/{train,val}.txt and sim_stats.json. Bedrooms, offices, bathrooms, living
rooms and classrooms furnished with the ten SUN RGB-D classes and clutter, seen by a 640x480
Kinect-like camera 1-1.6 m high pitched down 5-25 degrees (depth noise growing as z^2,
disparity quantisation, holes at dark, glass, glancing and far surfaces). Statistics are
printed after every indoor run.";

#[derive(clap::Args)]
#[command(after_long_help = AFTER_HELP)]
pub struct SimulateArgs {
    /// Output dataset directory (created if missing; must be empty unless --force).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Number of frames to simulate.
    #[arg(long, value_name = "N")]
    frames: usize,
    /// Random seed: the same seed gives the same dataset.
    #[arg(long, value_name = "S", default_value_t = 0)]
    seed: u64,
    /// Share of frames in the validation split.
    #[arg(long, value_name = "F", default_value_t = 0.5)]
    val_fraction: f64,
    /// Write into a non-empty directory, replacing an earlier simulated dataset there
    /// (only the simulator's own files are removed).
    #[arg(long)]
    force: bool,
    /// Print the realism report after generation.
    #[arg(long)]
    stats: bool,
    /// Multiplies the moving traffic (driving cars, pedestrians, cyclists): above 1 gives
    /// denser streets and more occluded objects (ablations of occlusion-aware models).
    #[arg(long, value_name = "F", default_value_t = 1.0)]
    traffic_scale: f64,
    /// Simulate only the frames k with k mod N = I, into the same --out as the other shards
    /// (same --frames, --seed and options). The last shard to finish writes the split lists,
    /// 2D detections and statistics; the data set is then byte-identical to an unsharded
    /// run's. `fusiondet merge --dir OUT` checks it.
    #[arg(long, value_name = "I/N")]
    shard: Option<fusiondet_kitti::Shard>,
    /// Simulate indoor rooms seen by an RGB-D camera, written as a prepared SUN RGB-D data
    /// set, instead of KITTI street scenes.
    #[arg(long)]
    indoor: bool,
    /// With --indoor: points written per scene (the prepared real scenes have 50,000).
    #[arg(long, value_name = "N")]
    points: Option<usize>,
}

/// `simulate --indoor`.
fn run_indoor(args: SimulateArgs) -> anyhow::Result<()> {
    if args.shard.is_some() {
        anyhow::bail!(
            "--shard is not supported with --indoor: simulate the whole indoor data set in one run"
        );
    }
    if args.traffic_scale != 1.0 {
        anyhow::bail!("--traffic-scale applies to street scenes, not to --indoor");
    }
    let defaults = fusiondet_sim::indoor::IndoorConfig::default();
    // A scene has at most one point per camera pixel: more cannot be written, and fewer
    // than asked would be written silently.
    let pixels = defaults.camera.width as usize * defaults.camera.height as usize;
    if let Some(points) = args.points
        && !(1..=pixels).contains(&points)
    {
        anyhow::bail!(
            "--points must be in 1..={pixels} (one point per pixel of the {}×{} camera at most), \
             got {points}",
            defaults.camera.width,
            defaults.camera.height
        );
    }
    let opts = fusiondet_sim::indoor::IndoorOptions {
        out: args.out.clone(),
        frames: args.frames,
        seed: args.seed,
        force: args.force,
        config: fusiondet_sim::indoor::IndoorConfig {
            val_fraction: args.val_fraction,
            points: args.points.unwrap_or(defaults.points),
            ..defaults
        },
    };
    let start = Instant::now();
    let interactive = std::io::stderr().is_terminal();
    let progress = |done: usize, total: usize| {
        if interactive {
            eprint!("\rsimulated {done}/{total} scenes");
            let _ = std::io::stderr().flush();
        }
    };
    let stats =
        fusiondet_sim::indoor::write_indoor_dataset(&opts, &progress).with_context(|| {
            format!(
                "cannot simulate an indoor data set into {}",
                args.out.display()
            )
        })?;
    let secs = start.elapsed().as_secs_f64();
    if interactive {
        eprintln!();
    }
    outln!(
        "wrote {} indoor scenes to {} in {:.1} s ({:.2} scenes/s, seed {})",
        args.frames,
        args.out.display(),
        secs,
        args.frames as f64 / secs.max(1e-9),
        args.seed
    );
    out!("{}", stats.report());
    outln!(
        "statistics written to {}",
        args.out.join(fusiondet_sim::dataset::STATS_FILE).display()
    );
    Ok(())
}

pub fn run(args: SimulateArgs) -> anyhow::Result<()> {
    if args.indoor {
        return run_indoor(args);
    }
    if args.points.is_some() {
        anyhow::bail!("--points applies to --indoor data sets only");
    }
    if !(args.traffic_scale.is_finite() && args.traffic_scale > 0.0) {
        anyhow::bail!(
            "--traffic-scale {} must be a positive number (1 = the default traffic)",
            args.traffic_scale
        );
    }
    let opts = DatasetOptions {
        out: args.out.clone(),
        frames: args.frames,
        seed: args.seed,
        force: args.force,
        config: SimConfig {
            val_fraction: args.val_fraction,
            layout: fusiondet_sim::LayoutConfig {
                traffic_scale: args.traffic_scale,
                ..Default::default()
            },
            ..SimConfig::default()
        },
    };
    let start = Instant::now();
    let interactive = std::io::stderr().is_terminal();
    let step = (args.frames / 100).max(1);
    let progress = |done: usize, total: usize| {
        if interactive && (done.is_multiple_of(step) || done == total) {
            eprint!("\rsimulated {done}/{total} frames");
            let _ = std::io::stderr().flush();
        }
    };
    let context = || format!("cannot simulate a dataset into {}", args.out.display());
    let (frames, stats) = match args.shard {
        None => (
            args.frames,
            Some(write_dataset(&opts, &progress).with_context(context)?),
        ),
        Some(shard) => {
            let outcome = write_dataset_shard(&opts, shard, &progress).with_context(context)?;
            super::shards::report(shard, &args.out, &outcome.progress);
            (outcome.frames, outcome.stats)
        }
    };
    let secs = start.elapsed().as_secs_f64();
    if interactive {
        eprintln!();
    }
    outln!(
        "wrote {} frames to {} in {:.1} s ({:.1} frames/s, seed {})",
        frames,
        args.out.display(),
        secs,
        frames as f64 / secs.max(1e-9),
        args.seed
    );
    let Some(stats) = stats else {
        return Ok(());
    };
    if args.stats {
        out!("{}", stats.report());
        outln!(
            "statistics written to {}",
            args.out.join(fusiondet_sim::dataset::STATS_FILE).display()
        );
    }
    Ok(())
}
