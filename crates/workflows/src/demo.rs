//! The demo chain: simulate a small street data set, run a shipped model (built into the
//! binary unless the `embedded-models` feature is off, see [`crate::bundled`]) on its
//! validation split and on the bundled real KITTI frames, evaluate both with the official
//! protocol and draw pictures. With `train_tiny`, the tiny network is trained on the
//! simulated frames first (seconds) and detects instead.
//!
//! Nothing here reads the source tree: an installed binary runs it from any directory.

use crate::bundled::{self, ShippedFiles};
use crate::{out, outln};
use anyhow::{Context, bail};
use fusiondet_eval::{EvalConfig, evaluate_dirs};
use fusiondet_kitti::{DatasetDir, read_split};
use fusiondet_models::DetectorKind;
use fusiondet_pipeline::{
    DetectOptions, ExperimentConfig, TrainOptions, detect, train, trained_parameters,
};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Marks a directory as the demo's own, so a re-run may replace what it wrote.
const MARKER: &str = ".fusiondet-demo";

/// What the demo is asked to do (the CLI's `fusiondet demo` flags).
#[derive(Debug, Clone)]
pub struct DemoOptions {
    /// Output directory (sim/, kitti/, run/, model/, results/, pictures/, eval-*.json).
    pub out: PathBuf,
    /// Simulated frames (half train, half val).
    pub frames: usize,
    /// Seed of the simulated world (and of training, with `train_tiny`).
    pub seed: u64,
    /// Which shipped model detects.
    pub model: ShippedModel,
    /// Train the tiny network and detect with it instead of a shipped model.
    pub train_tiny: bool,
    /// Training epochs of the tiny network.
    pub epochs: usize,
}

/// The shipped models (all trained on simulated data; see the README): five Car models,
/// F-ConvNet's two-stage Car model, and the Pedestrian + Cyclist models of SAF's Tables 5-6.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShippedModel {
    /// F-ConvNet.
    Fconvnet,
    /// FCAM: F-ConvNet with the improved CBAM.
    Fcam,
    /// SAF: depth-guided slicing, LFA and the projection loss.
    Saf,
    /// Voxel R-CNN: the LiDAR scan alone, no 2D detections.
    VoxelRcnn,
    /// DASANet: the scan and pseudo points completed from the image, fused by TDIS and STCA.
    Dasanet,
    /// F-ConvNet with its refinement stage over the shipped F-ConvNet's boxes.
    FconvnetRefine,
    /// F-ConvNet's Pedestrian + Cyclist network.
    FconvnetPeople,
    /// SAF's Pedestrian + Cyclist network.
    SafPeople,
    /// F-ConvNet's refinement stage over the shipped people model's boxes.
    FconvnetRefinePeople,
}

impl ShippedModel {
    pub const ALL: [ShippedModel; 9] = [
        Self::Fconvnet,
        Self::Fcam,
        Self::Saf,
        Self::VoxelRcnn,
        Self::Dasanet,
        Self::FconvnetRefine,
        Self::FconvnetPeople,
        Self::SafPeople,
        Self::FconvnetRefinePeople,
    ];

    /// The file stem under `models/`, also the name `--model` takes without `-car`.
    pub fn stem(self) -> &'static str {
        match self {
            ShippedModel::Fconvnet => "fconvnet-car",
            ShippedModel::Fcam => "fcam-car",
            ShippedModel::Saf => "saf-car",
            ShippedModel::VoxelRcnn => "voxel-rcnn-car",
            ShippedModel::Dasanet => "dasanet-car",
            ShippedModel::FconvnetRefine => "fconvnet-refine-car",
            ShippedModel::FconvnetPeople => "fconvnet-people",
            ShippedModel::SafPeople => "saf-people",
            ShippedModel::FconvnetRefinePeople => "fconvnet-refine-people",
        }
    }

    /// The name `--model` takes: the stem without `-car`.
    pub fn name(self) -> &'static str {
        let stem = self.stem();
        stem.strip_suffix("-car").unwrap_or(stem)
    }

    /// Every `--model` name, in [`Self::ALL`]'s order (the CLI's possible values).
    pub fn names() -> [&'static str; Self::ALL.len()] {
        Self::ALL.map(Self::name)
    }

    pub fn title(self) -> &'static str {
        match self {
            ShippedModel::Fconvnet | ShippedModel::FconvnetPeople => "F-ConvNet",
            ShippedModel::Fcam => "FCAM",
            ShippedModel::Saf | ShippedModel::SafPeople => "SAF",
            ShippedModel::VoxelRcnn => "Voxel R-CNN",
            ShippedModel::Dasanet => "DASANet",
            ShippedModel::FconvnetRefine | ShippedModel::FconvnetRefinePeople => {
                "two-stage F-ConvNet"
            }
        }
    }

    /// The classes it detects, as the demo names them.
    pub fn classes(self) -> &'static str {
        if self.stem().ends_with("-people") {
            "Pedestrian + Cyclist"
        } else {
            "Car"
        }
    }

    /// The shipped model whose boxes a refinement stage refines (its configuration names
    /// the first stage's file, which the demo writes beside it).
    pub fn first_stage(self) -> Option<ShippedModel> {
        match self {
            ShippedModel::FconvnetRefine => Some(ShippedModel::Fconvnet),
            ShippedModel::FconvnetRefinePeople => Some(ShippedModel::FconvnetPeople),
            _ => None,
        }
    }

    /// Its checkpoint and configuration as built into the binary; `None` in a build
    /// without the `embedded-models` feature.
    fn files(self) -> Option<&'static ShippedFiles> {
        #[cfg(feature = "embedded-models")]
        return Some(match self {
            ShippedModel::Fconvnet => &bundled::FCONVNET_CAR,
            ShippedModel::Fcam => &bundled::FCAM_CAR,
            ShippedModel::Saf => &bundled::SAF_CAR,
            ShippedModel::VoxelRcnn => &bundled::VOXEL_RCNN_CAR,
            ShippedModel::Dasanet => &bundled::DASANET_CAR,
            ShippedModel::FconvnetRefine => &bundled::FCONVNET_REFINE_CAR,
            ShippedModel::FconvnetPeople => &bundled::FCONVNET_PEOPLE,
            ShippedModel::SafPeople => &bundled::SAF_PEOPLE,
            ShippedModel::FconvnetRefinePeople => &bundled::FCONVNET_REFINE_PEOPLE,
        });
        #[cfg(not(feature = "embedded-models"))]
        None
    }
}

impl std::str::FromStr for ShippedModel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                format!(
                    "unknown model `{s}` (expected one of {})",
                    Self::names().join(", ")
                )
            })
    }
}

/// Creates `out`, or clears the demo's own sub-directories from an earlier run (of the
/// street or of the indoor demo).
pub(crate) fn prepare_out(out: &Path) -> anyhow::Result<()> {
    if out.exists() {
        let empty = std::fs::read_dir(out)
            .with_context(|| format!("{}: cannot read", out.display()))?
            .next()
            .is_none();
        if !empty && !out.join(MARKER).exists() {
            bail!(
                "{}: exists and was not written by `fusiondet demo`; choose another --out",
                out.display()
            );
        }
        for sub in [
            "sim", "kitti", "real", "run", "model", "results", "pictures",
        ] {
            let p = out.join(sub);
            if p.exists() {
                std::fs::remove_dir_all(&p)
                    .with_context(|| format!("{}: cannot remove", p.display()))?;
            }
        }
        // The evaluations of either demo, so that none is left from the other one.
        for file in ["eval-sim.json", "eval-kitti.json", "eval-real.json"] {
            let p = out.join(file);
            if p.is_file() {
                std::fs::remove_file(&p)
                    .with_context(|| format!("{}: cannot remove", p.display()))?;
            }
        }
    }
    std::fs::create_dir_all(out).with_context(|| format!("{}: cannot create", out.display()))?;
    std::fs::write(out.join(MARKER), b"written by fusiondet demo\n")
        .with_context(|| format!("{}: cannot write", out.display()))?;
    Ok(())
}

/// Detects on the val split of `data` into `results` and prints what it did (`unit`: what
/// a frame is called, "frames" or "scenes"). Shared by both demos.
pub(crate) fn detect_val(
    title: &str,
    unit: &str,
    config: &ExperimentConfig,
    model: &Path,
    data: &Path,
    results: &Path,
) -> anyhow::Result<()> {
    let started = Instant::now();
    let s = detect(&DetectOptions {
        // The demo's own directory (it refuses directories it did not write).
        replace: true,
        ..DetectOptions::new(config.clone(), model, data, "val", results)
    })?;
    let seconds = started.elapsed().as_secs_f64();
    match config.kind() {
        DetectorKind::Frustum => outln!(
            "\n== {title}: {} {unit}, {} 2D detections -> {} frustums -> {} boxes ({seconds:.1} s)",
            s.frames,
            s.detections_2d,
            s.samples,
            s.boxes_written,
        ),
        // The voxel families read whole scans (DASANet also the image): no 2D detections.
        DetectorKind::VoxelRcnn | DetectorKind::Dasanet => outln!(
            "\n== {title}: {} {unit} -> {} boxes ({seconds:.1} s)",
            s.frames,
            s.boxes_written,
        ),
    }
    Ok(())
}

/// Detects on the val split of `data`, evaluates, prints the table and writes the JSON.
fn detect_and_evaluate(
    title: &str,
    config: &ExperimentConfig,
    model: &Path,
    data: &Path,
    results: &Path,
    json: &Path,
) -> anyhow::Result<fusiondet_eval::EvalReport> {
    detect_val(title, "frames", config, model, data, results)?;
    let dataset = DatasetDir::new(data);
    let eval_config = EvalConfig {
        classes: config.frustum.kitti_classes(),
        ..Default::default()
    };
    let (report, _) = evaluate_dirs(
        &dataset.training().root.join("label_2"),
        results,
        Some(&dataset.split("val")),
        &eval_config,
    )?;
    out!("{}", report.table());
    fusiondet_eval::write_json(json, &report, Default::default())?;
    Ok(report)
}

/// 3D AP_R40 at the official overlap of each evaluated class, easy / moderate / hard, for
/// the demo's closing line.
fn ap3d_summary(report: &fusiondet_eval::EvalReport) -> String {
    report
        .classes
        .iter()
        .filter_map(|&class| {
            let row = report.get(class, fusiondet_eval::Metric::ThreeD, 0)?;
            let [e, m, h] = row.ap40;
            Some(format!("{} {e:.1} / {m:.1} / {h:.1}", class.as_str()))
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// Draws the first `n` frames of the val split with their detections.
fn pictures(
    data: &Path,
    results: &Path,
    out: &Path,
    prefix: &str,
    n: usize,
) -> anyhow::Result<Vec<PathBuf>> {
    let dataset = DatasetDir::new(data);
    let dir = dataset.training();
    let mut written = Vec::new();
    for id in read_split(&dataset.split("val"))?.into_iter().take(n) {
        let view = fusiondet_viz::load_frame(&dir, &id, Some(results))?;
        let path = out.join(format!("{prefix}-{id}.png"));
        fusiondet_kitti::image::write_png(&path, &fusiondet_viz::render_frame(&view))?;
        written.push(path);
    }
    Ok(written)
}

pub fn run(args: &DemoOptions) -> anyhow::Result<()> {
    let started = Instant::now();
    if args.frames < 4 {
        bail!("--frames must be at least 4 (the demo needs both a train and a val split)");
    }
    let out = &args.out;
    prepare_out(out)?;
    let kitti = &out.join("kitti");
    bundled::write_kitti_sample(kitti)?;

    // 1. Simulate.
    let t = Instant::now();
    let sim = out.join("sim");
    let stats = fusiondet_sim::write_dataset(
        &fusiondet_sim::DatasetOptions::new(&sim, args.frames, args.seed),
        &|_, _| {},
    )?;
    outln!(
        "== simulated {} frames ({} labelled objects, median {:.0} LiDAR points per frame) in {:.1} s -> {}",
        stats.frames,
        stats.labels.values().sum::<usize>(),
        stats.points_per_frame_median,
        t.elapsed().as_secs_f64(),
        sim.display()
    );

    // 2. The model: the shipped one, or the tiny network trained here.
    let (config, model) = if args.train_tiny {
        train_tiny(args, &sim)?
    } else {
        shipped_model(out, args.model)?
    };

    // 3. Detect and evaluate: simulated val split, then the real KITTI frames.
    let results = out.join("results");
    let sim_report = detect_and_evaluate(
        "simulated val split",
        &config,
        &model,
        &sim,
        &results.join("sim"),
        &out.join("eval-sim.json"),
    )?;
    let kitti_report = detect_and_evaluate(
        match config.kind() {
            DetectorKind::Frustum => "bundled KITTI frames (val split, F-PointNet 2D detections)",
            DetectorKind::VoxelRcnn | DetectorKind::Dasanet => "bundled KITTI frames (val split)",
        },
        &config,
        &model,
        kitti,
        &results.join("kitti"),
        &out.join("eval-kitti.json"),
    )?;

    // 4. Pictures.
    let pics = out.join("pictures");
    std::fs::create_dir_all(&pics).with_context(|| format!("{}: cannot create", pics.display()))?;
    let mut drawn = pictures(&sim, &results.join("sim"), &pics, "sim", 2)?;
    drawn.extend(pictures(kitti, &results.join("kitti"), &pics, "kitti", 2)?);
    outln!("\n== pictures:");
    for p in &drawn {
        outln!("   {}", p.display());
    }
    let what = if args.train_tiny {
        "a tiny network trained for seconds: the numbers show the pipeline, not F-ConvNet's accuracy".to_string()
    } else {
        format!(
            "the shipped {} {} model, trained on simulated data only; see the README for its full evaluation",
            args.model.title(),
            args.model.classes()
        )
    };
    outln!(
        "\n3D AP_R40 easy / moderate / hard: simulated val {}; bundled KITTI frames {}",
        ap3d_summary(&sim_report),
        ap3d_summary(&kitti_report)
    );
    outln!(
        "demo finished in {:.1} s ({what})",
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Writes a shipped model and its configuration to `out/model/` (a refinement model with
/// its first stage beside it, where its configuration looks for it).
fn shipped_model(out: &Path, which: ShippedModel) -> anyhow::Result<(ExperimentConfig, PathBuf)> {
    let dir = out.join("model");
    std::fs::create_dir_all(&dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    let files = |m: ShippedModel| {
        m.files().with_context(|| {
            format!(
                "this fusiondet was built without its models (cargo feature `embedded-models` \
                 off), so `demo --model {}` has nothing to run; use `demo --train-tiny`, or \
                 `detect --checkpoint models/{}.bpk` from the repository",
                which.name(),
                m.stem()
            )
        })
    };
    let write = |m: ShippedModel| -> anyhow::Result<(PathBuf, PathBuf)> {
        let ShippedFiles {
            checkpoint: bytes,
            config: toml,
        } = files(m)?;
        let config_path = dir.join(format!("{}.toml", m.stem()));
        let model = dir.join(format!("{}.bpk", m.stem()));
        fusiondet_kitti::write_atomic(&config_path, toml.as_bytes())?;
        fusiondet_kitti::write_atomic(&model, bytes)?;
        Ok((config_path, model))
    };
    if let Some(first) = which.first_stage() {
        write(first)?;
    }
    let (config_path, model) = write(which)?;
    let size = files(which)?.checkpoint.len();
    let config = ExperimentConfig::from_file(&config_path)?;
    let params = trained_parameters(&config)?;
    outln!(
        "== the shipped {} {} model ({:.1} MB, {params} parameters) -> {}",
        which.title(),
        which.classes(),
        size as f64 / 1e6,
        model.display()
    );
    Ok((config, model))
}

/// Trains the tiny network on the simulated train split.
fn train_tiny(args: &DemoOptions, sim: &Path) -> anyhow::Result<(ExperimentConfig, PathBuf)> {
    let tiny = TinyTraining {
        config_toml: bundled::TINY_CONFIG,
        config_name: "configs/tiny.toml",
        classes: "",
        unit: "frames",
    };
    tiny.train(args.epochs, args.seed, sim, &args.out.join("run"))
}

/// A bundled tiny configuration both demos train for seconds, and how its line reads.
pub(crate) struct TinyTraining {
    pub config_toml: &'static str,
    /// The name the configuration's errors and relative paths go by.
    pub config_name: &'static str,
    /// What it learns, said after "the tiny F-ConvNet" ("" or " on …").
    pub classes: &'static str,
    /// What a frame is called ("frames", "rooms").
    pub unit: &'static str,
}

impl TinyTraining {
    /// Trains on `data` into `run_dir`, prints what it did, returns the configuration and
    /// the model.
    pub(crate) fn train(
        &self,
        epochs: usize,
        seed: u64,
        data: &Path,
        run_dir: &Path,
    ) -> anyhow::Result<(ExperimentConfig, PathBuf)> {
        let t = Instant::now();
        let mut config =
            ExperimentConfig::from_toml_str(self.config_toml, Path::new(self.config_name))?;
        config.train.epochs = epochs;
        config.train.seed = seed;
        let summary = train(&TrainOptions {
            progress: std::io::stderr().is_terminal(),
            ..TrainOptions::new(config.clone(), data, run_dir)
        })?;
        outln!(
            "== trained the tiny F-ConvNet{} ({} epochs, {} frustums from {} {}, final loss {:.3}) in {:.1} s -> {}",
            self.classes,
            summary.epochs_run,
            summary.samples,
            summary.frames,
            self.unit,
            summary.final_loss.unwrap_or(f64::NAN),
            t.elapsed().as_secs_f64(),
            summary.model.display()
        );
        Ok((config, summary.model))
    }
}
