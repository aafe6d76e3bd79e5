//! `fusiondet viz`: draws one frame (camera image with projected 3D boxes above a
//! bird's-eye view) to a PNG, of a KITTI frame or of a prepared SUN RGB-D scene (told
//! apart by the directory: `splits/` and `points/` are SUN RGB-D's). The drawing lives in
//! `fusiondet-viz`.

use anyhow::{Context, bail};
use fusiondet_kitti::FrameDir;
use fusiondet_kitti::image::write_png;
use fusiondet_viz::image::RgbImage;
use fusiondet_viz::{
    BevRange, RenderOptions, indoor_render_options, load_frame, load_indoor_scene,
    render_frame_with,
};
use fusiondet_workflows::outln;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct VizArgs {
    /// KITTI `training/` (or `testing/`) directory with image_2/, calib/, velodyne/ and
    /// label_2/; or a prepared SUN RGB-D directory (splits/, points/, image/, calib/, label/).
    #[arg(long)]
    pub data_dir: PathBuf,
    /// Frame id, e.g. 000001 (shorter numbers are zero-padded to six digits).
    #[arg(long)]
    pub id: String,
    /// Directory of result files (ID.txt or data/ID.txt; KITTI lines, or SUN RGB-D's
    /// upright-depth lines for a SUN RGB-D directory) drawn as detections.
    /// A directory without this frame draws ground truth only, with a warning.
    #[arg(long)]
    pub result_dir: Option<PathBuf>,
    /// Leave out detections scoring below this.
    #[arg(long)]
    pub score_threshold: Option<f64>,
    /// Output PNG (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// Bird's-eye view: metres shown ahead of the camera [default: 70; 8 for SUN RGB-D].
    #[arg(long)]
    pub bev_forward: Option<f64>,
    /// Bird's-eye view: metres shown to each side [default: 40; 5 for SUN RGB-D].
    #[arg(long)]
    pub bev_side: Option<f64>,
    /// Do not draw KITTI's DontCare regions (faint dashed 2D boxes on the image).
    #[arg(long)]
    pub no_dont_care: bool,
    /// Directory of pseudo point clouds (`<id>.bin`, from `fusiondet pseudo-points`),
    /// drawn on the bird's-eye view in their own colour.
    #[arg(long)]
    pub pseudo_dir: Option<PathBuf>,
    /// Directory of completed depth maps (`<id>.png`, from `fusiondet depth-complete`),
    /// drawn as a colour map above the image.
    #[arg(long)]
    pub depth_dir: Option<PathBuf>,
}

/// Normalises a frame id: digits only, zero-padded to KITTI's six.
pub(crate) fn frame_id(id: &str) -> anyhow::Result<String> {
    if id.is_empty() || !id.bytes().all(|b| b.is_ascii_digit()) {
        bail!("--id `{id}` is not a frame id (digits, e.g. 000001)");
    }
    Ok(format!("{id:0>6}"))
}

/// The bird's-eye view's extent: each side at least 1 m and at most 500 m (a map of
/// nanometres would never finish its grid), and the picture at most 20 times taller than
/// wide or wider than tall (its height follows from the aspect; a needle of a map would not
/// fit in memory).
pub(crate) fn check_bev_extent(forward: f64, side: f64) -> anyhow::Result<()> {
    for (name, v) in [("--bev-forward", forward), ("--bev-side", side)] {
        if !(v.is_finite() && (1.0..=500.0).contains(&v)) {
            bail!("{name} must be in [1, 500] metres, got {v}");
        }
    }
    let aspect = forward / (2.0 * side);
    if !(0.05..=20.0).contains(&aspect) {
        bail!(
            "--bev-forward {forward} against --bev-side {side} (both sides: {}) makes a map {aspect:.3} \
             times as tall as wide; keep the ratio within 1/20 to 20",
            2.0 * side
        );
    }
    Ok(())
}

/// `--score-threshold`, where given, must be a number (`viz` and `view`).
pub(crate) fn check_score_threshold(threshold: Option<f64>) -> anyhow::Result<()> {
    if let Some(t) = threshold
        && !t.is_finite()
    {
        bail!("--score-threshold must be a finite number, got {t}");
    }
    Ok(())
}

pub fn run(args: VizArgs) -> anyhow::Result<()> {
    let id = frame_id(&args.id)?;
    check_score_threshold(args.score_threshold)?;
    super::data_root::check_frames("--data-dir", &args.data_dir)?;
    let indoor = fusiondet_viz::is_sun_rgbd_dir(&args.data_dir);
    let (forward, side) = match indoor {
        true => (8.0, 5.0),
        false => (70.0, 40.0),
    };
    let bev_forward = args.bev_forward.unwrap_or(forward);
    let bev_side = args.bev_side.unwrap_or(side);
    check_bev_extent(bev_forward, bev_side)?;
    super::outputs::refuse_output_in_inputs(
        "--out",
        &args.out,
        &[
            ("--data-dir", Some(args.data_dir.as_path())),
            ("--result-dir", args.result_dir.as_deref()),
            ("--pseudo-dir", args.pseudo_dir.as_deref()),
            ("--depth-dir", args.depth_dir.as_deref()),
        ],
    )?;
    if indoor {
        return run_indoor(&args, &id, bev_forward, bev_side);
    }
    let frames = FrameDir::new(&args.data_dir);
    let mut view = load_frame(&frames, &id, args.result_dir.as_deref())
        .with_context(|| format!("cannot load frame {id} from {}", args.data_dir.display()))?;
    if let Some(dir) = &args.pseudo_dir {
        let points = fusiondet_depth::read_pseudo_points(&dir.join(format!("{id}.bin")))?;
        view.pseudo_points = Some(points.iter().map(|p| p.xyz).collect());
    }
    if let Some(dir) = &args.depth_dir {
        let path = dir.join(format!("{id}.png"));
        let depth = fusiondet_depth::read_depth_png(&path)?;
        if (depth.width as u32, depth.height as u32) != view.image.dimensions() {
            bail!(
                "{}: the depth map is {}x{} but the image {}x{}",
                path.display(),
                depth.width,
                depth.height,
                view.image.width(),
                view.image.height()
            );
        }
        view.depth = Some(depth);
    }
    for note in &view.notes {
        eprintln!("warning: {note}");
    }
    let options = RenderOptions {
        score_threshold: args.score_threshold,
        bev_range: BevRange {
            forward: (0.0, bev_forward),
            lateral: (-bev_side, bev_side),
        },
        dont_care: !args.no_dont_care,
        ..RenderOptions::default()
    };
    write_picture(&args.out, &render_frame_with(&view, &options))
}

fn write_picture(out: &Path, picture: &RgbImage) -> anyhow::Result<()> {
    write_png(out, picture).context("cannot write the picture")?;
    outln!(
        "wrote {} ({}x{})",
        out.display(),
        picture.width(),
        picture.height()
    );
    Ok(())
}

/// A prepared SUN RGB-D scene: the image with its boxes above the room seen from above.
fn run_indoor(args: &VizArgs, id: &str, bev_forward: f64, bev_side: f64) -> anyhow::Result<()> {
    for (flag, given) in [
        ("--pseudo-dir", args.pseudo_dir.is_some()),
        ("--depth-dir", args.depth_dir.is_some()),
    ] {
        if given {
            bail!(
                "{flag} is for KITTI frames; {} is a prepared SUN RGB-D directory",
                args.data_dir.display()
            );
        }
    }
    let view = load_indoor_scene(&args.data_dir, id, args.result_dir.as_deref())
        .with_context(|| format!("cannot load scene {id} from {}", args.data_dir.display()))?;
    for note in &view.notes {
        eprintln!("warning: {note}");
    }
    let options = RenderOptions {
        score_threshold: args.score_threshold,
        bev_range: BevRange {
            forward: (0.0, bev_forward),
            lateral: (-bev_side, bev_side),
        },
        ..indoor_render_options()
    };
    write_picture(&args.out, &render_frame_with(&view, &options))
}

#[cfg(test)]
mod tests {
    use super::frame_id;

    #[test]
    fn ids_are_padded_and_checked() {
        assert_eq!(frame_id("1").unwrap(), "000001");
        assert_eq!(frame_id("000134").unwrap(), "000134");
        assert!(frame_id("abc").is_err());
        assert!(frame_id("").is_err());
        assert!(frame_id("../1").is_err());
    }
}
