//! Ablations: train, detect and evaluate a list of configurations on one data set (or
//! detect and evaluate trained checkpoints), and write the seeds' ablation tables (AP3D and
//! APBEV, easy/moderate/hard, AP40 and AP11), the per-occlusion / per-distance /
//! per-LiDAR-points breakdown and the precision–recall curves.
//!
//! Each training runs in its own `fusiondet train` process: a training is bit-reproducible
//! in a process of its own (two in one process share rayon's pool), and a finished run is
//! resumed rather than repeated, and a row whose checkpoint was already detected keeps its
//! result files, so an interrupted ablation continues where it stopped.

use crate::{out, outln};
use anyhow::{Context, bail};
use fusiondet_eval::saf_tables::saf_table;
use fusiondet_eval::{
    AblationRow, Difficulty, EvalConfig, FrameDet, FrameGt, Metric, Resampling, RowDifference,
    SeedGroup, ablation_breakdown_table, ablation_table, count_lidar_points, difference_table,
    evaluate, evaluate_breakdown, frame_ids, load_dirs, paired_bootstrap, seed_ablation_table,
    seed_breakdown_table, write_ablation_json,
};
use fusiondet_kitti::DatasetDir;
use fusiondet_pipeline::{
    ComputeDevice, DetectOptions, ExperimentConfig, detect, frames_per_second,
    inference_multiply_adds, trained_parameters,
};
use std::path::{Path, PathBuf};
use std::process::Command;

/// What an ablation is asked to do.
#[derive(Debug, Clone)]
pub struct AblationOptions {
    /// Configurations to compare, in table order; the first is the baseline. A refinement
    /// config refines the nearest first-stage config before it.
    pub configs: Vec<PathBuf>,
    /// Trained checkpoints to compare instead of `configs`, in table order (nothing is
    /// trained): each with the configuration `detect` finds for it (`<model>.toml` beside a
    /// shipped model, `config.toml` in a run), a refinement model with its own first stage.
    pub models: Vec<PathBuf>,
    /// Data set root with training/, ImageSets/{train,val}.txt and rgb_detections/.
    pub data: PathBuf,
    /// Output directory.
    pub out: PathBuf,
    /// Extra `fusiondet train` flags for every configuration (`--epochs 4`, ...).
    pub train_flags: Vec<String>,
    /// Training seeds: every configuration is trained once per seed and the tables also
    /// give the mean, the seeds' range and which differences exceed it. Empty: each
    /// configuration's own seed, once.
    pub seeds: Vec<u64>,
    /// The `fusiondet` executable the trainings run in.
    pub executable: PathBuf,
    /// Where detection runs (each training takes the `train` default).
    pub device: ComputeDevice,
    /// Resamples of the val frames for each row's interval against the baseline (0: no
    /// interval tables).
    pub resamples: usize,
    /// Seed of those resamples.
    pub resample_seed: u64,
}

/// One configuration's results.
struct Entry {
    name: String,
    /// The training seed given for this run (`None`: the configuration's own).
    seed: Option<u64>,
    /// The val frames' ground truth and this row's detections.
    gt: Vec<FrameGt>,
    det: Vec<FrameDet>,
    report: fusiondet_eval::EvalReport,
    breakdown: Vec<fusiondet_eval::BreakdownRow>,
    params: usize,
    multiply_adds: Option<u64>,
    frames_per_second: f64,
}

pub fn run(args: &AblationOptions) -> anyhow::Result<()> {
    let trained = !args.models.is_empty();
    if trained != args.configs.is_empty() {
        bail!(
            "give either --configs (train, then compare) or --models (compare trained checkpoints)"
        );
    }
    if trained && (!args.seeds.is_empty() || !args.train_flags.is_empty()) {
        bail!(
            "--models compares checkpoints that are already trained: --seeds, --epochs, --seed \
             and --max-frames apply to training and cannot be given with it"
        );
    }
    let configs: Vec<(PathBuf, ExperimentConfig)> = if trained {
        args.models
            .iter()
            .map(|p| Ok((p.clone(), ExperimentConfig::for_checkpoint(p, None)?)))
            .collect::<anyhow::Result<_>>()?
    } else {
        args.configs
            .iter()
            .map(|p| Ok((p.clone(), ExperimentConfig::from_file(p)?)))
            .collect::<anyhow::Result<_>>()?
    };
    let mut names: Vec<&str> = configs.iter().map(|(_, c)| c.name.as_str()).collect();
    names.sort_unstable();
    if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
        bail!(
            "two configurations are named `{}`; names become directories, give each its own",
            w[0]
        );
    }
    let classes = configs[0].1.frustum.kitti_classes();
    if let Some((p, c)) = configs
        .iter()
        .find(|(_, c)| c.frustum.kitti_classes() != classes)
    {
        bail!(
            "{}: detects {:?} but {} detects {:?}; an ablation compares models of the same classes",
            p.display(),
            c.frustum.kitti_classes(),
            configs[0].0.display(),
            classes
        );
    }
    if let Some((p, _)) = configs
        .first()
        .filter(|(_, c)| !trained && c.refine.is_some())
    {
        bail!(
            "{}: a refinement stage needs its first stage listed before it in --configs \
             (e.g. fconvnet-car.toml fconvnet-refine-car.toml)",
            p.display()
        );
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create", args.out.display()))?;
    let dataset = DatasetDir::new(&args.data);
    let label_dir = dataset.training().root.join("label_2");
    let ids = frame_ids(&label_dir, Some(&dataset.split("val")))?;

    let seeds: Vec<Option<u64>> = if args.seeds.is_empty() {
        vec![None]
    } else {
        args.seeds.iter().copied().map(Some).collect()
    };
    // Per configuration, its runs (one per seed).
    let mut groups: Vec<Vec<Entry>> = configs.iter().map(|_| Vec::new()).collect();
    for &seed in &seeds {
        // A refinement row refines the boxes of the nearest first-stage row above it
        // (trained with the same seed).
        let mut first_stage: Option<PathBuf> = None;
        for ((path, config), runs) in configs.iter().zip(&mut groups) {
            if trained {
                let results = dir_of(args, "results", config, None);
                let row = Row {
                    name: &config.name,
                    config,
                    checkpoint: path,
                    results: &results,
                };
                runs.push(evaluate_row(args, &row, &label_dir, &ids)?);
                continue;
            }
            let first = config.refine.as_ref().and(first_stage.as_deref());
            runs.push(run_one(args, path, config, seed, first, &label_dir, &ids)?);
            if config.refine.is_none() {
                first_stage = Some(run_dir_of(args, config, seed).join("model.bpk"));
            }
        }
    }
    let entries: Vec<&Entry> = groups.iter().flatten().collect();

    let row = |e: &Entry| AblationRow {
        name: e.name.clone(),
        report: e.report.clone(),
        breakdown: Some(e.breakdown.clone()),
        params: Some(e.params),
        multiply_adds: e.multiply_adds,
        frames_per_second: Some(e.frames_per_second),
    };
    let rows: Vec<AblationRow> = entries.iter().map(|e| row(e)).collect();
    // Stages of each row's detector, in the order of `rows` (each configuration's runs).
    let row_stages: Vec<u32> = groups
        .iter()
        .zip(&configs)
        .flat_map(|(runs, (_, c))| runs.iter().map(|_| 1 + u32::from(c.refine.is_some())))
        .collect();
    let frustum_only = configs
        .iter()
        .all(|(_, c)| c.kind() == fusiondet_models::DetectorKind::Frustum);
    let seed_groups: Vec<SeedGroup> = configs
        .iter()
        .zip(&groups)
        .map(|((_, c), runs)| SeedGroup {
            name: c.name.clone(),
            runs: runs.iter().map(row).collect(),
        })
        .collect();
    let bootstraps = row_bootstraps(args, &groups, &classes)?;
    let intervals: Vec<RowDifference> = bootstraps
        .iter()
        .map(|(e, result)| RowDifference {
            name: &e.name,
            seed: e.seed,
            result,
        })
        .collect();
    let mut text = format!(
        "# Ablation on {} ({} val frames)\n\n",
        args.data.display(),
        ids.len()
    );
    for &class in &classes {
        text += &format!("## {class}\n\n");
        text += &ablation_table(&rows, class, 0);
        text +=
            &format!("\n### {class}: AP_R40 by distance, occlusion and LiDAR points (hard)\n\n");
        text += &ablation_breakdown_table(&rows, class, 0, Difficulty::Hard);
        text += "\n";
        if !intervals.is_empty() {
            text +=
                &format!("### {class}: differences from the baseline beyond the frames drawn\n\n");
            for metric in [Metric::ThreeD, Metric::Bev] {
                text += &difference_table(&intervals, class, metric);
                text += "\n";
            }
        }
        if seeds.len() >= 2 {
            text += &format!("### {class}: over {} seeds\n\n", seeds.len());
            text += &seed_ablation_table(&seed_groups, class, 0);
            text += "\n";
            for metric in [Metric::ThreeD, Metric::Bev] {
                text += &seed_breakdown_table(&seed_groups, class, 0, metric, Difficulty::Hard);
            }
        }
        // The frustum family's rows beside SAF's Tables 4–6 (one per class it has).
        if frustum_only && let Some(table) = saf_table(&rows, &row_stages, class) {
            text += &format!("### {class}: beside the SAF paper\n\n{table}\n");
        }
        for (metric, tag) in [(Metric::ThreeD, "3d"), (Metric::Bev, "bev")] {
            let curves: Vec<(&str, &fusiondet_eval::MetricResult)> = rows
                .iter()
                .filter_map(|r| Some((r.name.as_str(), r.report.get(class, metric, 0)?)))
                .collect();
            let image = fusiondet_viz::render_pr_difficulties(
                &format!("{class} {} precision-recall", tag.to_uppercase()),
                &curves,
                &Default::default(),
            );
            let png = args
                .out
                .join(format!("pr-{}-{tag}.png", class.to_string().to_lowercase()));
            fusiondet_viz::write_plot_png(&png, &image)?;
            text += &format!(
                "![{class} {tag}]({})\n\n",
                png.file_name().unwrap().to_string_lossy()
            );
        }
    }
    out!("{text}");
    fusiondet_kitti::write_atomic(&args.out.join("ablation.md"), text.as_bytes())
        .with_context(|| format!("{}: cannot write", args.out.display()))?;
    write_ablation_json(&args.out.join("ablation.json"), &rows, &intervals)?;
    outln!(
        "wrote {}/ablation.md, ablation.json and the PR plots",
        args.out.display()
    );
    Ok(())
}

/// `OUT/<kind>/<name>`, or `OUT/<kind>/<name>/seed-<seed>` when the ablation has seeds.
/// Each row after the baseline against the baseline's run of the same seed, by a paired
/// bootstrap over the val frames (none with `resamples` 0 or a single row).
fn row_bootstraps<'a>(
    args: &AblationOptions,
    groups: &'a [Vec<Entry>],
    classes: &[fusiondet_kitti::ObjectClass],
) -> anyhow::Result<Vec<(&'a Entry, fusiondet_eval::PairedBootstrap)>> {
    let Some((baselines, others)) = groups.split_first() else {
        return Ok(Vec::new());
    };
    if args.resamples == 0 {
        return Ok(Vec::new());
    }
    let cfg = EvalConfig {
        classes: classes.to_vec(),
        ..Default::default()
    };
    let resampling = Resampling {
        resamples: args.resamples,
        seed: args.resample_seed,
        confidence: 0.95,
    };
    let mut out = Vec::new();
    for runs in others {
        for (run, baseline) in runs.iter().zip(baselines) {
            let result = paired_bootstrap(&run.gt, &run.det, &baseline.det, &cfg, resampling)?;
            out.push((run, result));
        }
    }
    Ok(out)
}

fn dir_of(
    args: &AblationOptions,
    kind: &str,
    config: &ExperimentConfig,
    seed: Option<u64>,
) -> PathBuf {
    let dir = args.out.join(kind).join(&config.name);
    match seed {
        Some(s) => dir.join(format!("seed-{s}")),
        None => dir,
    }
}

fn run_dir_of(args: &AblationOptions, config: &ExperimentConfig, seed: Option<u64>) -> PathBuf {
    dir_of(args, "runs", config, seed)
}

/// Makes the child end when this process does, however it ends (a kill included): an
/// ablation stopped by the user must not leave its training running. The child gets
/// SIGTERM, which leaves its run resumable (every checkpoint is written atomically).
#[cfg(target_os = "linux")]
fn ends_with_this_process(command: &mut Command) {
    use std::os::unix::process::CommandExt;
    let parent = std::process::id();
    // SAFETY: the closure runs in the child between fork and exec and calls only
    // async-signal-safe functions (prctl, getppid).
    unsafe {
        command.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The parent may have died before the request: then end now.
            if libc::getppid() as u32 != parent {
                libc::raise(libc::SIGTERM);
            }
            Ok(())
        });
    }
}

/// Elsewhere the child outlives a killed ablation (no portable way to ask otherwise).
#[cfg(not(target_os = "linux"))]
fn ends_with_this_process(_command: &mut Command) {}

/// Trains (in a child process; a refinement stage over `first_stage`), detects on the
/// val split and evaluates one configuration.
fn run_one(
    args: &AblationOptions,
    path: &Path,
    config: &ExperimentConfig,
    seed: Option<u64>,
    first_stage: Option<&Path>,
    label_dir: &Path,
    ids: &[String],
) -> anyhow::Result<Entry> {
    let run_dir = run_dir_of(args, config, seed);
    let name = match seed {
        Some(s) => format!("{} (seed {s})", config.name),
        None => config.name.clone(),
    };
    let mut train = Command::new(&args.executable);
    // The name the child reports itself by (its usage lines), whatever path runs it.
    #[cfg(unix)]
    std::os::unix::process::CommandExt::arg0(&mut train, "fusiondet");
    train
        .arg("train")
        .arg("--config")
        .arg(path)
        .arg("--data")
        .arg(&args.data)
        .arg("--out")
        .arg(&run_dir);
    // A run that has begun (its config.toml is written first) is resumed, also when it was
    // stopped before its first epoch was committed.
    if run_dir.join("config.toml").exists() {
        train.arg("--resume");
    }
    train.args(&args.train_flags);
    if let Some(s) = seed {
        train.arg("--seed").arg(s.to_string());
    }
    if let Some(first) = first_stage {
        train.arg("--first-stage").arg(first);
    }
    ends_with_this_process(&mut train);
    eprintln!("== {name}: training ({})", path.display());
    let status = train.status().context("cannot start `fusiondet train`")?;
    if !status.success() {
        bail!(
            "training {name} failed ({status}); its run directory is {}",
            run_dir.display()
        );
    }
    // The run directory holds the configuration it was trained with (overrides included).
    let trained = ExperimentConfig::from_file(&run_dir.join("config.toml"))?;
    let results = dir_of(args, "results", config, seed);
    let row = Row {
        name: &name,
        config: &trained,
        checkpoint: &run_dir.join("model.bpk"),
        results: &results,
    };
    let entry = evaluate_row(args, &row, label_dir, ids)?;
    Ok(Entry { seed, ..entry })
}

/// A trained model to detect with and evaluate: its row name, its configuration, its
/// checkpoint and where its result files go.
struct Row<'a> {
    name: &'a str,
    config: &'a ExperimentConfig,
    checkpoint: &'a Path,
    results: &'a Path,
}

/// Detects on the val split with a trained model and evaluates it (AP, breakdown, size,
/// speed).
fn evaluate_row(
    args: &AblationOptions,
    row: &Row,
    label_dir: &Path,
    ids: &[String],
) -> anyhow::Result<Entry> {
    let Row {
        name,
        config: trained,
        checkpoint,
        results,
    } = *row;
    let fingerprint = Fingerprint::of(checkpoint)?;
    let marker = Detected::marker(results);
    let kept = Detected::read(&marker)
        .filter(|d| d.checkpoint == fingerprint && d.frames == ids.len() && results.is_dir());
    let detected = match kept {
        Some(detected) => {
            eprintln!(
                "== {name}: detections of this checkpoint kept from an earlier run ({})",
                results.display()
            );
            detected
        }
        None => {
            // The marker goes first: results being replaced are never taken as finished.
            for stale in [&marker, results] {
                let removed = match std::fs::metadata(stale) {
                    Ok(m) if m.is_dir() => std::fs::remove_dir_all(stale),
                    Ok(_) => std::fs::remove_file(stale),
                    Err(_) => Ok(()),
                };
                removed.with_context(|| format!("{}: cannot clear", stale.display()))?;
            }
            let summary = detect(&DetectOptions {
                device: args.device,
                replace: true,
                ..DetectOptions::new(trained.clone(), checkpoint, &args.data, "val", results)
            })?;
            let detected = Detected {
                checkpoint: fingerprint,
                frames: summary.frames,
                boxes: summary.boxes_written,
                frames_per_second: frames_per_second(summary.frames, &summary.timing),
            };
            detected.write(&marker)?;
            detected
        }
    };
    let frames_per_second = detected.frames_per_second;
    let eval_config = EvalConfig {
        classes: trained.frustum.kitti_classes(),
        ..Default::default()
    };
    let frames = load_dirs(label_dir, results, ids)?;
    let report = evaluate(&frames.gt, &frames.det, &eval_config)?;
    let training = DatasetDir::new(&args.data).training();
    let points = count_lidar_points(
        &frames.gt,
        &frames.det,
        &training.root.join("velodyne"),
        &training.root.join("calib"),
    )?;
    let breakdown = evaluate_breakdown(&frames.gt, &frames.det, &eval_config, Some(&points))?;
    // A refinement row counts both stages, as the papers do.
    let params = trained_parameters(trained)?;
    let multiply_adds = inference_multiply_adds(trained)?;
    eprintln!(
        "== {name}: {} frames, {} boxes, {frames_per_second:.1} frames/s, {params} parameters",
        detected.frames, detected.boxes
    );
    Ok(Entry {
        name: name.to_string(),
        seed: None,
        gt: frames.gt,
        det: frames.det,
        report,
        breakdown,
        params,
        multiply_adds,
        frames_per_second,
    })
}

/// A checkpoint's identity: its length and the CRC-32 of its bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Fingerprint {
    bytes: u64,
    crc32: u32,
}

impl Fingerprint {
    fn of(checkpoint: &Path) -> anyhow::Result<Fingerprint> {
        let data = std::fs::read(checkpoint)
            .with_context(|| format!("{}: cannot read the checkpoint", checkpoint.display()))?;
        Ok(Fingerprint {
            bytes: data.len() as u64,
            crc32: crc32fast::hash(&data),
        })
    }
}

/// A row's finished detection on the val split, recorded beside its result files
/// (`<results>.detected`) so that a resumed ablation keeps the detections of a checkpoint
/// it has already run (and the speed measured then) instead of detecting again. One line:
/// `<checkpoint bytes> <checkpoint CRC-32> <frames> <boxes> <frames/s>`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Detected {
    checkpoint: Fingerprint,
    frames: usize,
    boxes: usize,
    frames_per_second: f64,
}

impl Detected {
    fn marker(results: &Path) -> PathBuf {
        let mut name = results.as_os_str().to_owned();
        name.push(".detected");
        PathBuf::from(name)
    }

    /// The record at `marker`; `None` where there is none or it does not parse (then the
    /// row is detected again).
    fn read(marker: &Path) -> Option<Detected> {
        let text = std::fs::read_to_string(marker).ok()?;
        let fields: Vec<&str> = text.split_whitespace().collect();
        let [bytes, crc32, frames, boxes, fps] = fields[..] else {
            return None;
        };
        Some(Detected {
            checkpoint: Fingerprint {
                bytes: bytes.parse().ok()?,
                crc32: crc32.parse().ok()?,
            },
            frames: frames.parse().ok()?,
            boxes: boxes.parse().ok()?,
            frames_per_second: fps.parse().ok()?,
        })
    }

    fn write(&self, marker: &Path) -> anyhow::Result<()> {
        let line = format!(
            "{} {} {} {} {}\n",
            self.checkpoint.bytes,
            self.checkpoint.crc32,
            self.frames,
            self.boxes,
            self.frames_per_second
        );
        fusiondet_kitti::write_atomic(marker, line.as_bytes())
            .with_context(|| format!("{}: cannot record the detection", marker.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A record reads back as written; a torn or foreign one reads as none.
    #[test]
    fn detection_records_round_trip_and_refuse_garbage() {
        let dir = tempfile::tempdir().unwrap();
        let marker = Detected::marker(&dir.path().join("results/row/seed-1"));
        assert!(marker.ends_with("row/seed-1.detected"));
        std::fs::create_dir_all(marker.parent().unwrap()).unwrap();
        let record = Detected {
            checkpoint: Fingerprint {
                bytes: 123,
                crc32: 4_000_000_000,
            },
            frames: 300,
            boxes: 2279,
            frames_per_second: 3.4125,
        };
        record.write(&marker).unwrap();
        assert_eq!(Detected::read(&marker), Some(record));
        for garbage in ["", "123 4000000000 300 2279", "a b c d e", "1 2 3 4 5 6"] {
            std::fs::write(&marker, garbage).unwrap();
            assert_eq!(Detected::read(&marker), None, "{garbage:?}");
        }
        assert_eq!(Detected::read(&dir.path().join("absent")), None);
    }
}
