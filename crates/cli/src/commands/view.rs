//! `fusiondet view`: interactive 3D pages of frames (one self-contained HTML file each),
//! for one frame (`--id … --out`) or a browsable set (`--split … --out-dir`, with an index
//! page and previous / next links). The pages live in `fusiondet-viz::web`.

use super::viz::{check_score_threshold, frame_id};
use anyhow::{Context, bail};
use fusiondet_kitti::{FrameDir, read_split, write_atomic};
use fusiondet_viz::FrameView;
use fusiondet_viz::load_frame;
use fusiondet_viz::web::{
    DEFAULT_MAX_POINTS, DEFAULT_MAX_PSEUDO_POINTS, IndexEntry, Nav, PageOptions, PseudoCloud,
    render_index, render_page,
};
use fusiondet_workflows::outln;
use std::path::{Path, PathBuf};

/// The file that marks a directory of pages as `fusiondet view`'s: the page names it wrote,
/// one per line. Without it a non-empty `--out-dir` is refused; with it, `--force` replaces.
const MARKER: &str = ".fusiondet-view";

#[derive(clap::Args)]
pub struct ViewArgs {
    /// KITTI `training/` (or `testing/`) directory with image_2/, calib/, velodyne/ and label_2/.
    #[arg(long)]
    pub data_dir: PathBuf,
    /// One frame, e.g. 000001 (written to --out).
    #[arg(long, conflicts_with = "split", requires = "out")]
    pub id: Option<String>,
    /// A browsable set: an id list (e.g. DATA/ImageSets/val.txt, or just `val` for the
    /// data set's own), written to --out-dir with an index page.
    #[arg(long, conflicts_with = "out", requires = "out_dir")]
    pub split: Option<String>,
    /// The page of --id (HTML, written atomically).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The directory of --split's pages (created; refused if it holds other files).
    #[arg(long)]
    pub out_dir: Option<PathBuf>,
    /// With --out-dir: replace the pages of an earlier `fusiondet view` there.
    #[arg(long)]
    pub force: bool,
    /// Directory of KITTI result files (ID.txt or data/ID.txt) shown as detections.
    #[arg(long)]
    pub result_dir: Option<PathBuf>,
    /// Directory of pseudo point clouds (`<id>.bin`, from `fusiondet pseudo-points`).
    #[arg(long)]
    pub pseudo_dir: Option<PathBuf>,
    /// Where the page's score slider starts.
    #[arg(long)]
    pub score_threshold: Option<f64>,
    /// LiDAR points kept per page (evenly spaced through the scan when it has more).
    #[arg(long, default_value_t = DEFAULT_MAX_POINTS)]
    pub max_points: usize,
    /// Pseudo points kept per page.
    #[arg(long, default_value_t = DEFAULT_MAX_PSEUDO_POINTS)]
    pub max_pseudo_points: usize,
}

/// The ids of `--split`: a file, or the name of one of the data set's `ImageSets/` lists.
fn split_ids(split: &str, data_dir: &Path) -> anyhow::Result<Vec<String>> {
    let given = PathBuf::from(split);
    let path = if given.is_file() {
        given
    } else {
        let named = data_dir
            .parent()
            .map(|root| root.join("ImageSets").join(format!("{split}.txt")));
        match named {
            Some(p) if !split.contains('/') && p.is_file() => p,
            _ => bail!(
                "--split {split}: no such id list (give a file of frame ids, or the name of one \
                 in the data set's ImageSets/)"
            ),
        }
    };
    let ids = read_split(&path)?;
    if ids.is_empty() {
        bail!("{}: the id list is empty", path.display());
    }
    Ok(ids)
}

/// The frame with its pseudo points, if a directory of them was given. A missing file is
/// an error for one frame, a warning in a set (the page then shows LiDAR only).
fn load(args: &ViewArgs, id: &str, in_set: bool) -> anyhow::Result<(FrameView, PageOptions)> {
    let frames = FrameDir::new(&args.data_dir);
    let view = load_frame(&frames, id, args.result_dir.as_deref())
        .with_context(|| format!("cannot load frame {id} from {}", args.data_dir.display()))?;
    for note in &view.notes {
        eprintln!("warning: {note}");
    }
    let mut options = PageOptions::new(id);
    options.score_threshold = args.score_threshold;
    options.max_points = args.max_points;
    options.max_pseudo_points = args.max_pseudo_points;
    if let Some(dir) = &args.pseudo_dir {
        let path = dir.join(format!("{id}.bin"));
        if in_set && !path.exists() {
            eprintln!(
                "warning: no pseudo points for {id} ({}): LiDAR only",
                path.display()
            );
        } else {
            let points = fusiondet_depth::read_pseudo_points(&path)?;
            options.pseudo = Some(PseudoCloud {
                xyz: points.iter().map(|p| p.xyz).collect(),
                rgb: points
                    .iter()
                    .map(|p| p.rgb.map(|c| c.clamp(0.0, 255.0).round() as u8))
                    .collect(),
            });
        }
    }
    Ok((view, options))
}

fn check_args(args: &ViewArgs) -> anyhow::Result<()> {
    check_score_threshold(args.score_threshold)?;
    for (flag, n) in [
        ("--max-points", args.max_points),
        ("--max-pseudo-points", args.max_pseudo_points),
    ] {
        if !(1..=2_000_000).contains(&n) {
            bail!("{flag} must be in 1..=2000000, got {n}");
        }
    }
    super::data_root::check_frames("--data-dir", &args.data_dir)?;
    for (flag, dir) in [
        ("--result-dir", &args.result_dir),
        ("--pseudo-dir", &args.pseudo_dir),
    ] {
        if let Some(d) = dir
            && !d.is_dir()
        {
            bail!("{flag} {}: no such directory", d.display());
        }
    }
    Ok(())
}

fn inputs(args: &ViewArgs) -> [(&'static str, Option<&Path>); 3] {
    [
        ("--data-dir", Some(args.data_dir.as_path())),
        ("--result-dir", args.result_dir.as_deref()),
        ("--pseudo-dir", args.pseudo_dir.as_deref()),
    ]
}

pub fn run(args: ViewArgs) -> anyhow::Result<()> {
    check_args(&args)?;
    match (&args.id, &args.split) {
        (Some(id), None) => one_frame(&args, &frame_id(id)?),
        (None, Some(split)) => a_set(&args, split),
        _ => bail!("give --id ID --out PAGE.html for one frame, or --split IDS --out-dir DIR"),
    }
}

fn one_frame(args: &ViewArgs, id: &str) -> anyhow::Result<()> {
    let out = args.out.as_ref().context("--id needs --out PAGE.html")?;
    super::outputs::refuse_output_in_inputs("--out", out, &inputs(args))?;
    let (view, options) = load(args, id, false)?;
    let page = render_page(&view, &options);
    write_atomic(out, page.as_bytes()).context("cannot write the page")?;
    outln!(
        "wrote {} ({:.1} MB)",
        out.display(),
        page.len() as f64 / 1e6
    );
    Ok(())
}

/// A directory the set may be written to: new, empty, or an earlier view's with `--force`.
/// Returns the pages an earlier view wrote there (to be removed once replaced).
fn claim_out_dir(dir: &Path, force: bool) -> anyhow::Result<Vec<String>> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        if dir.exists() {
            bail!("--out-dir {}: exists and is not a directory", dir.display());
        }
        return Ok(Vec::new());
    };
    if entries.flatten().next().is_none() {
        return Ok(Vec::new());
    }
    let marker = dir.join(MARKER);
    if !marker.is_file() {
        bail!(
            "--out-dir {}: holds files that `fusiondet view` did not write; choose a new or \
             empty directory",
            dir.display()
        );
    }
    if !force {
        bail!(
            "--out-dir {}: holds the pages of an earlier `fusiondet view`; pass --force to \
             replace them, or choose another directory",
            dir.display()
        );
    }
    let listed = fusiondet_kitti::error::read_text(&marker)?;
    // Only plain page names are ever removed, whatever the marker says.
    Ok(listed
        .lines()
        .filter(|n| n.ends_with(".html") && !n.contains('/') && !n.starts_with('.'))
        .map(str::to_string)
        .collect())
}

fn a_set(args: &ViewArgs, split: &str) -> anyhow::Result<()> {
    let out_dir = args
        .out_dir
        .as_ref()
        .context("--split needs --out-dir DIR")?;
    super::outputs::refuse_output_in_inputs("--out-dir", &out_dir.join(MARKER), &inputs(args))?;
    let ids: Vec<String> = split_ids(split, &args.data_dir)?
        .iter()
        .map(|id| frame_id(id))
        .collect::<anyhow::Result<_>>()?;
    let earlier = claim_out_dir(out_dir, args.force)?;
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let page_name = |id: &str| format!("{id}.html");
    let mut names: Vec<String> = ids.iter().map(|id| page_name(id)).collect();
    names.push("index.html".into());
    // The marker first, listing both runs' pages: a kill part-way leaves nothing unlisted.
    let mut listed = earlier.clone();
    listed.extend(names.iter().cloned());
    listed.sort();
    listed.dedup();
    write_atomic(&out_dir.join(MARKER), (listed.join("\n") + "\n").as_bytes())?;
    let mut entries = Vec::new();
    let mut bytes = 0usize;
    for (k, id) in ids.iter().enumerate() {
        let (view, mut options) = load(args, id, true)?;
        options.nav = Nav {
            prev: k.checked_sub(1).map(|p| page_name(&ids[p])),
            next: ids.get(k + 1).map(|n| page_name(n)),
            index: Some("index.html".into()),
        };
        let page = render_page(&view, &options);
        bytes += page.len();
        write_atomic(&out_dir.join(page_name(id)), page.as_bytes())?;
        entries.push(IndexEntry {
            id: id.clone(),
            page: page_name(id),
            ground_truth: view.boxes_gt().len(),
            // `load_frame` left `detections` empty where the directory lacks the frame.
            detections: args
                .result_dir
                .as_ref()
                .map(|_| view.detections.as_ref().map_or(0, Vec::len)),
        });
    }
    let title = format!("{} — {} frames", args.data_dir.display(), ids.len());
    write_atomic(
        &out_dir.join("index.html"),
        render_index(&title, &entries).as_bytes(),
    )?;
    for stale in earlier.iter().filter(|n| !names.contains(n)) {
        let _ = std::fs::remove_file(out_dir.join(stale));
    }
    write_atomic(&out_dir.join(MARKER), (names.join("\n") + "\n").as_bytes())?;
    outln!(
        "wrote {} pages and {} ({:.1} MB in all)",
        ids.len(),
        out_dir.join("index.html").display(),
        bytes as f64 / 1e6
    );
    Ok(())
}
