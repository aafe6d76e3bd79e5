//! `fusiondet eval`: the official KITTI object evaluation on a label directory and a
//! result directory, printed as the familiar devkit/OpenPCDet table and optionally
//! written as JSON; with `--dataset sunrgbd`, the indoor evaluation of SUN RGB-D (VoteNet's
//! protocol with an exact IoU). The work lives in `fusiondet-eval`.

use anyhow::bail;
use fusiondet_eval::indoor::{
    IOU_THRESHOLDS, evaluate_indoor, load_indoor_dirs, write_indoor_json,
};
use fusiondet_eval::{
    EvalConfig, JsonExtras, Resampling, breakdown_table, count_lidar_points, errors_table,
    evaluate, evaluate_breakdown, frame_ids, load_dirs, paired_bootstrap, parse_classes,
    true_positive_errors, write_json,
};
use fusiondet_kitti::{ObjectClass, read_manifest, split_file, split_is_file};
use fusiondet_workflows::{out, outln};
use std::path::{Path, PathBuf};
use std::time::Instant;

const AFTER_HELP: &str = "\
Protocol: the official devkit (evaluate_object.cpp, 41 recall samples): difficulties
easy/moderate/hard (min box height 40/25/25 px, max occlusion 0/1/2, max truncation
0.15/0.30/0.50), Van ignored for Car and Person_sitting for Pedestrian, DontCare regions
suppress false positives. Every row is reported for the official minimum overlaps (Car
0.7, Pedestrian/Cyclist 0.5 for bbox, bev and 3d) and the looser ones (Car 0.7/0.5/0.5,
Pedestrian/Cyclist 0.5/0.25/0.25). AP in percent; AP11 averages 11 recall points, AP_R40
40. A class without ground truth gets AP 0.

--json OUT writes {\"results\": [{\"class\", \"metric\" (bbox|bev|3d|aos), \"min_overlap\",
\"ap11\": [easy, moderate, hard], \"ap40\": [...]}, ...]}, plus a \"breakdown\" array with
--breakdown ({\"class\", \"metric\", \"min_overlap\", \"by\", \"bin\", \"n_gt\", \"ap40\"}, null
where a bin has no ground truth).

--breakdown reports AP_R40 (bev and 3d, easy/moderate/hard) per bin of:
  distance      0-20m, 20-40m, 40m+: range of the 3D box centre in the rectified camera
                frame, sqrt(x^2 + (y - h/2)^2 + z^2), with (x, y, z) the label's
                bottom-face centre;
  occlusion     0, 1, 2: the label's occlusion level (3, unknown, is in no bin);
  lidar_points  <100, 100-200 (inclusive), >200: LiDAR points inside the 3D box, from
                --velodyne-dir (NNNNNN.bin) and --calib-dir (NNNNNN.txt), both required.
Filtering rule, per bin: ground truth outside the bin is treated like the devkit's
ignored ground truth (neither a miss nor a hit; a detection matched to it is dropped).
A detection matched to an in-bin box is a true positive wherever the detection lies.
An unmatched detection (a would-be false positive) is charged to the bin of the
ground-truth box (class or neighbour class) it overlaps most in the measure evaluated
(overlap > 0); if it overlaps none, by its own box: its centre range for distance, the
LiDAR points inside it for lidar_points, and to every bin for occlusion (detections have
no occlusion level). In other bins it is not counted. Thus every ground-truth box and
every false positive belongs to exactly one bin (false positives overlapping nothing:
every occlusion bin).

--baseline DIR compares --result-dir with another model's results on the same frames: for
AP_R40 of every bbox, bev and 3d row it prints both APs, their difference, the interval of
the difference over --resamples resamples of the frames (drawn with replacement, the same
resample for both, each evaluated with the devkit's matching; --confidence 0.95: the 2.5th
to 97.5th percentile; --seed), and the share of resamples in which --result-dir leads. An
interval that includes 0 says the frames do not settle which model is ahead. With --json,
a \"baseline\" object holds the rows.

--dataset sunrgbd: SUN RGB-D's indoor evaluation, on label and result files of the prepared
layout (<id>.txt, one box a line: class cx cy cz dx dy dz yaw x1 y1 x2 y2, results with the
score appended; upright depth, yaw about +z). For each of the 10 classes (bed, table, sofa,
chair, toilet, desk, dresser, night_stand, bookshelf, bathtub; other names are ignored) all
its detections over all scenes, highest score first (equal scores in split, then file
order), each take the box of the class in their scene with the largest rotated 3D IoU; a
true positive if that IoU is above the threshold and the box not yet taken. AP = area under
the precision envelope (all points), at IoU 0.25 and 0.5, and the mean over the classes with
ground truth (a class without is `-`, null in JSON). VoteNet's eval_det.py, except that the
IoU is exact. --json OUT writes {\"results\": [{\"class\", \"iou\", \"ap\"}, ...], \"map\":
{\"0.25\": m, \"0.5\": m}}, AP in percent.";

/// Which data set's files and protocol `eval` uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Dataset {
    /// KITTI's object benchmark (label_2 files, the official devkit).
    Kitti,
    /// SUN RGB-D's indoor 3D detection (VoteNet's protocol, exact IoU).
    Sunrgbd,
}

#[derive(clap::Args)]
#[command(after_long_help = AFTER_HELP)]
pub struct EvalArgs {
    /// The data set's format and protocol: kitti, or sunrgbd (see --help).
    #[arg(long, value_enum, default_value_t = Dataset::Kitti)]
    dataset: Dataset,
    /// Ground-truth directory in KITTI label_2 format (NNNNNN.txt), or SUN RGB-D label files
    /// with --dataset sunrgbd.
    #[arg(long, value_name = "DIR")]
    label_dir: PathBuf,
    /// Detection results: NNNNNN.txt per frame, label format plus a 16th column (score; SUN
    /// RGB-D: a 13th).
    /// A missing file is a frame without detections (the count is reported).
    #[arg(long, value_name = "DIR")]
    result_dir: PathBuf,
    /// Frames to evaluate: a split name (`val`: ImageSets/val.txt of the data set whose
    /// training/label_2 is --label-dir; SUN RGB-D: splits/val.txt) or a file of ids. Default:
    /// the frames of the results' manifest (what `detect` wrote), else every label file.
    #[arg(long, value_name = "NAME|FILE")]
    split: Option<String>,
    /// Classes to evaluate, comma-separated, KITTI spelling. Default: those of Car,
    /// Pedestrian, Cyclist that occur in the results (all three if none does).
    #[arg(long, value_name = "LIST")]
    classes: Option<String>,
    /// Also write the results as JSON to this file (atomically).
    #[arg(long, value_name = "OUT")]
    json: Option<PathBuf>,
    /// Also report true-positive errors: for detections within 2 m of a ground-truth centre,
    /// median and mean error along depth, laterally, in height, in size (1 - IoU aligned) and
    /// heading, per difficulty and per distance and occlusion bin, and LiDAR-points bin with
    /// --breakdown (also in the JSON).
    #[arg(long)]
    errors: bool,
    /// Also report AP_R40 by distance, occlusion and LiDAR point count (needs
    /// --velodyne-dir and --calib-dir; the rule is in --help).
    #[arg(long)]
    breakdown: bool,
    /// LiDAR scans (NNNNNN.bin) for --breakdown.
    #[arg(long, value_name = "DIR")]
    velodyne_dir: Option<PathBuf>,
    /// Calibration files (NNNNNN.txt) for --breakdown.
    #[arg(long, value_name = "DIR")]
    calib_dir: Option<PathBuf>,
    /// A second result directory of the same frames (e.g. the model to beat): also report
    /// AP_R40 of --result-dir minus this one's, with a paired bootstrap interval over frames
    /// (see --help).
    #[arg(long, value_name = "DIR")]
    baseline: Option<PathBuf>,
    /// Frame resamples for --baseline's interval.
    #[arg(long, value_name = "N", default_value_t = 1000, requires = "baseline")]
    resamples: usize,
    /// Coverage of --baseline's interval.
    #[arg(long, value_name = "P", default_value_t = 0.95, requires = "baseline")]
    confidence: f64,
    /// Seed of --baseline's frame resamples.
    #[arg(long, value_name = "S", default_value_t = 0, requires = "baseline")]
    seed: u64,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    if args.dataset == Dataset::Sunrgbd {
        return run_sunrgbd(args);
    }
    let lidar = match (args.breakdown, &args.velodyne_dir, &args.calib_dir) {
        (true, Some(v), Some(c)) => Some((v.clone(), c.clone())),
        (true, _, _) => bail!(
            "--breakdown needs both --velodyne-dir and --calib-dir (the LiDAR points inside each box are counted from them)"
        ),
        (false, v, c) => {
            if v.is_some() || c.is_some() {
                eprintln!("warning: --velodyne-dir and --calib-dir are only used with --breakdown");
            }
            None
        }
    };

    if let Some(out) = &args.json {
        super::outputs::refuse_output_in_inputs(
            "--json",
            out,
            &[
                ("--label-dir", Some(args.label_dir.as_path())),
                ("--result-dir", Some(args.result_dir.as_path())),
                ("--baseline", args.baseline.as_deref()),
                ("--velodyne-dir", args.velodyne_dir.as_deref()),
                ("--calib-dir", args.calib_dir.as_deref()),
                (
                    "--split",
                    split_input(&args, "training/label_2", "ImageSets").as_deref(),
                ),
            ],
        )?;
    }
    let start = Instant::now();
    refuse_non_results(&args.result_dir)?;
    if let Some(baseline) = &args.baseline {
        refuse_non_results(baseline)?;
    }
    let (ids, frames_from) = eval_frames(&args, "training/label_2", "ImageSets")?;
    let frames = load_dirs(&args.label_dir, &args.result_dir, &ids)?;
    let (classes, classes_from) = match &args.classes {
        Some(list) => (
            parse_classes(list).map_err(|m| anyhow::anyhow!("--classes: {m}"))?,
            "--classes",
        ),
        None => classes_in_results(&frames.det),
    };
    let names: Vec<&str> = classes.iter().map(|c| c.as_str()).collect();
    outln!(
        "evaluating {} frames ({frames_from}) for {} ({classes_from}); --split and --classes choose others",
        ids.len(),
        names.join(", ")
    );
    let cfg = EvalConfig {
        classes,
        ..EvalConfig::default()
    };
    warn_missing_results(&frames.missing_results, ids.len(), &args.result_dir);
    let report = evaluate(&frames.gt, &frames.det, &cfg)?;
    out!("{}", report.table());

    let points = match &lidar {
        Some((velodyne_dir, calib_dir)) => Some(count_lidar_points(
            &frames.gt,
            &frames.det,
            velodyne_dir,
            calib_dir,
        )?),
        None => None,
    };
    let breakdown = match &points {
        Some(points) => {
            let rows = evaluate_breakdown(&frames.gt, &frames.det, &cfg, Some(points))?;
            out!("{}", breakdown_table(&rows));
            Some(rows)
        }
        None => None,
    };
    let errors = args
        .errors
        .then(|| true_positive_errors(&frames.gt, &frames.det, &cfg.classes, points.as_deref()));
    if let Some(rows) = &errors {
        out!("{}", errors_table(rows));
    }
    let versus = match &args.baseline {
        Some(dir) => {
            let baseline = load_dirs(&args.label_dir, dir, &ids)?;
            warn_missing_results(&baseline.missing_results, ids.len(), dir);
            let resampling = Resampling {
                resamples: args.resamples,
                seed: args.seed,
                confidence: args.confidence,
            };
            let result =
                paired_bootstrap(&frames.gt, &frames.det, &baseline.det, &cfg, resampling)?;
            out!("{}", result.table());
            Some(result)
        }
        None => None,
    };
    if let Some(out) = &args.json {
        let extras = JsonExtras {
            breakdown: breakdown.as_deref(),
            errors: errors.as_deref(),
            baseline: versus.as_ref(),
        };
        write_json(out, &report, extras)?;
        eprintln!("wrote {}", out.display());
    }
    eprintln!(
        "evaluated {} frames in {:.3} s",
        report.frames,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Warns that `missing` of `total` frames have no result file in `dir` (they are evaluated as
/// frames without detections).
fn warn_missing_results(missing: &[String], total: usize, dir: &Path) {
    if missing.is_empty() {
        return;
    }
    let shown: Vec<&str> = missing.iter().take(5).map(String::as_str).collect();
    eprintln!(
        "warning: {} of {} frames have no result file in {} (evaluated as frames without detections): {}{}",
        missing.len(),
        total,
        dir.display(),
        shown.join(", "),
        if missing.len() > shown.len() {
            ", ..."
        } else {
            ""
        }
    );
}

/// `--dataset sunrgbd`: the indoor evaluation of every scene of the split (default: every
/// label file), printed as the papers' table and optionally written as JSON.
fn run_sunrgbd(args: EvalArgs) -> anyhow::Result<()> {
    let kitti_only = [
        ("--breakdown", args.breakdown),
        ("--errors", args.errors),
        ("--velodyne-dir", args.velodyne_dir.is_some()),
        ("--calib-dir", args.calib_dir.is_some()),
        ("--classes", args.classes.is_some()),
        ("--baseline", args.baseline.is_some()),
    ];
    if let Some((flag, _)) = kitti_only.iter().find(|(_, given)| *given) {
        bail!(
            "{flag} is for --dataset kitti; the SUN RGB-D evaluation always reports its 10 classes"
        );
    }
    if let Some(out) = &args.json {
        super::outputs::refuse_output_in_inputs(
            "--json",
            out,
            &[
                ("--label-dir", Some(args.label_dir.as_path())),
                ("--result-dir", Some(args.result_dir.as_path())),
                ("--split", split_input(&args, "label", "splits").as_deref()),
            ],
        )?;
    }
    let start = Instant::now();
    refuse_non_results(&args.result_dir)?;
    let (ids, frames_from) = eval_frames(&args, "label", "splits")?;
    outln!(
        "evaluating {} scenes ({frames_from}) for the 10 SUN RGB-D classes; --split chooses others",
        ids.len()
    );
    let loaded = load_indoor_dirs(&args.label_dir, &args.result_dir, &ids)?;
    let missing = &loaded.missing_results;
    if !missing.is_empty() {
        let shown: Vec<&str> = missing.iter().take(5).map(String::as_str).collect();
        eprintln!(
            "warning: {} of {} scenes have no result file in {} (evaluated as scenes without detections): {}{}",
            missing.len(),
            ids.len(),
            args.result_dir.display(),
            shown.join(", "),
            if missing.len() > shown.len() {
                ", ..."
            } else {
                ""
            }
        );
    }
    let report = evaluate_indoor(&loaded.scenes, &IOU_THRESHOLDS)?;
    out!("{}", report.table());
    if let Some(out) = &args.json {
        write_indoor_json(out, &report)?;
        eprintln!("wrote {}", out.display());
    }
    eprintln!(
        "evaluated {} scenes in {:.3} s",
        report.scenes,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The split file `--split` reads, for the check that `--json` does not replace it: the file
/// given, or the named list beside `--label-dir` (`label_sub` below the data set's root).
fn split_input(args: &EvalArgs, label_sub: &str, lists: &str) -> Option<PathBuf> {
    let split = args.split.as_deref()?;
    if split_is_file(split) {
        return Some(PathBuf::from(split));
    }
    let depth = Path::new(label_sub).components().count();
    let root = args.label_dir.ancestors().nth(depth)?;
    Some(split_file(&root.join(lists), split))
}

/// The frames to evaluate and where they came from: `--split` (a name is looked up in the
/// `lists` folder of the data set whose `label_sub` is --label-dir, e.g. `ImageSets/` for
/// `training/label_2`), else the frames the results' manifest lists, else every label file.
fn eval_frames(
    args: &EvalArgs,
    label_sub: &str,
    lists: &str,
) -> anyhow::Result<(Vec<String>, String)> {
    if let Some(split) = &args.split {
        let path = if split_is_file(split) {
            PathBuf::from(split)
        } else {
            let depth = Path::new(label_sub).components().count();
            let root = args.label_dir.ancestors().nth(depth).filter(|root| {
                root.join(label_sub).canonicalize().ok() == args.label_dir.canonicalize().ok()
            });
            match root {
                Some(root) => split_file(&root.join(lists), split),
                None => bail!(
                    "--split {split}: a split name is looked up in the data set's {lists}/, but \
                     --label-dir {} is not a data set's {label_sub}/; give the split as a file \
                     (e.g. --split DATA/{lists}/{split}.txt)",
                    args.label_dir.display()
                ),
            }
        };
        let ids = frame_ids(&args.label_dir, Some(&path))?;
        return Ok((ids, format!("split {}", path.display())));
    }
    if let Some(manifest) = read_manifest(&args.result_dir)?
        && !manifest.frames.is_empty()
    {
        return Ok((
            manifest.frames,
            "the frames the results' manifest lists".into(),
        ));
    }
    let ids = frame_ids(&args.label_dir, None)?;
    Ok((
        ids,
        "every label file; the results have no detect manifest".into(),
    ))
}

/// Refuses a result directory that cannot be one: a data set root (or one of its folders)
/// or a folder with neither result files nor a detect manifest, which would be scored as
/// zeros.
fn refuse_non_results(dir: &Path) -> anyhow::Result<()> {
    if !dir.is_dir() {
        bail!(
            "--result-dir {}: no such directory (give the --out of `fusiondet detect`)",
            dir.display()
        );
    }
    let data_set = [
        "training",
        "ImageSets",
        "label_2",
        "velodyne",
        "calib",
        "points",
    ];
    if let Some(found) = data_set.iter().find(|d| dir.join(d).is_dir()) {
        bail!(
            "--result-dir {}: holds {found}/, so it is a data set, not detection results; give \
             the --out of `fusiondet detect` (and the data set's training/label_2 as --label-dir)",
            dir.display()
        );
    }
    let has_results = std::fs::read_dir(dir)
        .map_err(|e| anyhow::anyhow!("--result-dir {}: {e}", dir.display()))?
        .filter_map(|e| e.ok())
        .any(|e| e.file_name().to_str().is_some_and(|n| n.ends_with(".txt")));
    if !has_results && read_manifest(dir)?.is_none() {
        bail!(
            "--result-dir {}: holds no result files (NNNNNN.txt) and no detect manifest; run \
             `fusiondet detect --out {}` first",
            dir.display(),
            dir.display()
        );
    }
    Ok(())
}

/// The evaluated classes (Car, Pedestrian, Cyclist) that occur in the results, in that
/// order; all three when none does, so an empty result set still reports every class.
fn classes_in_results(det: &[fusiondet_eval::FrameDet]) -> (Vec<ObjectClass>, &'static str) {
    let found: Vec<ObjectClass> = ObjectClass::EVALUATED
        .into_iter()
        .filter(|c| det.iter().any(|f| f.objects.iter().any(|o| o.class == *c)))
        .collect();
    if found.is_empty() {
        (
            ObjectClass::EVALUATED.to_vec(),
            "no evaluated class in the results, so all three",
        )
    } else {
        (found, "the classes in the results")
    }
}
