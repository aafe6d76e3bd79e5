//! The indoor demo (`fusiondet demo --indoor`): simulate a few furnished rooms seen by a
//! Kinect-like RGB-D camera (`fusiondet_sim::indoor`), train the tiny F-ConvNet on SUN
//! RGB-D's ten classes (`configs/tiny-sunrgbd.toml`, built into the binary) for a few
//! epochs, detect on the simulated val rooms and on the real SUN RGB-D scene 000017 (built
//! into the binary, written out as a prepared directory), evaluate both with the indoor
//! evaluation (VoteNet's protocol) and draw pictures.
//!
//! Nothing here reads the source tree: an installed binary runs it from any directory.

use crate::bundled;
use crate::demo::{TinyTraining, detect_val, prepare_out};
use crate::{out, outln};
use anyhow::{Context, bail};
use fusiondet_eval::indoor::{
    IOU_THRESHOLDS, IndoorReport, evaluate_indoor, load_indoor_dirs, write_indoor_json,
};
use fusiondet_pipeline::ExperimentConfig;
use fusiondet_sunrgbd::{Detection2d, SunRgbdDir};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What the indoor demo is asked to do (`fusiondet demo --indoor` flags).
#[derive(Debug, Clone)]
pub struct IndoorDemoOptions {
    /// Output directory (sim/, real/, run/, results/, pictures/, eval-*.json).
    pub out: PathBuf,
    /// Simulated rooms (about half train, half val).
    pub frames: usize,
    /// Seed of the simulated rooms and of training.
    pub seed: u64,
    /// Training epochs of the tiny network.
    pub epochs: usize,
    /// Points kept per simulated scene (the prepared real scenes have 50,000; fewer is
    /// faster and what the tiny network samples from anyway).
    pub points: usize,
}

/// Writes the bundled real scene 000017 as a prepared SUN RGB-D directory with a val
/// split of that one scene and 2D detections taken from its labels' 2D boxes (of the
/// ten evaluated classes; the real scene has no 2D detector's output).
pub fn write_real_scene(root: &Path) -> anyhow::Result<()> {
    for (relative, bytes) in bundled::SUNRGBD_SCENE {
        let path = root.join(relative);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("{}: cannot create", parent.display()))?;
        }
        fusiondet_kitti::write_atomic(&path, bytes)?;
    }
    let dir = SunRgbdDir::new(root);
    let id = bundled::SUNRGBD_SCENE_ID;
    let detections: Vec<Detection2d> = fusiondet_sunrgbd::read_labels(&dir.label(id))?
        .into_iter()
        .filter(|o| o.sun_class().is_some())
        .map(|o| Detection2d {
            class: o.class,
            bbox: o.bbox,
            score: 1.0,
        })
        .collect();
    for sub in ["det_2d", "splits"] {
        std::fs::create_dir_all(dir.root.join(sub))
            .with_context(|| format!("{}: cannot create {sub}/", root.display()))?;
    }
    fusiondet_sunrgbd::write_detections_2d(&dir.detections_2d(id), &detections)?;
    fusiondet_kitti::write_split(&dir.split("val"), &[id.to_string()])?;
    Ok(())
}

/// Detects on the val split of the prepared directory `data`, evaluates, prints the
/// table and writes the JSON; returns the report.
fn detect_and_evaluate(
    title: &str,
    config: &ExperimentConfig,
    model: &Path,
    data: &Path,
    results: &Path,
    json: &Path,
) -> anyhow::Result<IndoorReport> {
    detect_val(title, "scenes", config, model, data, results)?;
    let dir = SunRgbdDir::new(data);
    let ids = fusiondet_kitti::read_split(&dir.split("val"))?;
    let loaded = load_indoor_dirs(&dir.label_dir(), results, &ids)?;
    let report = evaluate_indoor(&loaded.scenes, &IOU_THRESHOLDS)?;
    out!("{}", report.table());
    write_indoor_json(json, &report)?;
    Ok(report)
}

/// Draws the first `n` scenes of the val split with their detections.
fn pictures(
    data: &Path,
    results: &Path,
    out: &Path,
    prefix: &str,
    n: usize,
) -> anyhow::Result<Vec<PathBuf>> {
    let dir = SunRgbdDir::new(data);
    let mut written = Vec::new();
    for id in fusiondet_kitti::read_split(&dir.split("val"))?
        .into_iter()
        .take(n)
    {
        let view = fusiondet_viz::load_indoor_scene(data, &id, Some(results))?;
        let picture =
            fusiondet_viz::render_frame_with(&view, &fusiondet_viz::indoor_render_options());
        let path = out.join(format!("{prefix}-{id}.png"));
        fusiondet_kitti::image::write_png(&path, &picture)?;
        written.push(path);
    }
    Ok(written)
}

/// mAP at IoU 0.25 and 0.5 (percent), for the summary line.
fn maps(report: &IndoorReport) -> (f64, f64) {
    let at = |iou| report.map(iou).unwrap_or(f64::NAN);
    (at(0.25), at(0.5))
}

pub fn run(args: &IndoorDemoOptions) -> anyhow::Result<()> {
    let started = Instant::now();
    if args.frames < 4 {
        bail!("--frames must be at least 4 (the demo needs both a train and a val split)");
    }
    if args.points < 1000 {
        bail!("--points must be at least 1000");
    }
    let out = &args.out;
    prepare_out(out)?;
    let real = out.join("real");
    write_real_scene(&real)?;

    // 1. Simulate.
    let t = Instant::now();
    let sim = out.join("sim");
    let stats = fusiondet_sim::indoor::write_indoor_dataset(
        &fusiondet_sim::indoor::IndoorOptions {
            out: sim.clone(),
            frames: args.frames,
            seed: args.seed,
            force: false,
            config: fusiondet_sim::indoor::IndoorConfig {
                points: args.points,
                ..Default::default()
            },
        },
        &|_, _| {},
    )?;
    let train_ids = fusiondet_kitti::read_split(&SunRgbdDir::new(&sim).split("train"))?;
    let val_ids = fusiondet_kitti::read_split(&SunRgbdDir::new(&sim).split("val"))?;
    if train_ids.is_empty() || val_ids.is_empty() {
        bail!(
            "the {} simulated rooms fell into one split ({} train, {} val): give more --frames or another --seed",
            args.frames,
            train_ids.len(),
            val_ids.len()
        );
    }
    outln!(
        "== simulated {} rooms ({} train, {} val; {:.1} labelled objects a room) in {:.1} s -> {}",
        stats.frames,
        train_ids.len(),
        val_ids.len(),
        stats.labels_per_scene,
        t.elapsed().as_secs_f64(),
        sim.display()
    );

    // 2. Train the tiny network.
    let tiny = TinyTraining {
        config_toml: bundled::TINY_SUNRGBD_CONFIG,
        config_name: "configs/tiny-sunrgbd.toml",
        classes: " on SUN RGB-D's ten classes",
        unit: "rooms",
    };
    let (config, model) = tiny.train(args.epochs, args.seed, &sim, &out.join("run"))?;

    // 3. Detect and evaluate: simulated val rooms, then the real scene.
    let results = out.join("results");
    let sim_report = detect_and_evaluate(
        "simulated val rooms (the simulated 2D detector's boxes)",
        &config,
        &model,
        &sim,
        &results.join("sim"),
        &out.join("eval-sim.json"),
    )?;
    let real_report = detect_and_evaluate(
        "real SUN RGB-D scene 000017 (2D boxes from its labels)",
        &config,
        &model,
        &real,
        &results.join("real"),
        &out.join("eval-real.json"),
    )?;

    // 4. Pictures.
    let pics = out.join("pictures");
    std::fs::create_dir_all(&pics).with_context(|| format!("{}: cannot create", pics.display()))?;
    let mut drawn = pictures(&sim, &results.join("sim"), &pics, "sim", 2)?;
    drawn.extend(pictures(&real, &results.join("real"), &pics, "real", 1)?);
    outln!("\n== pictures:");
    for p in &drawn {
        outln!("   {}", p.display());
    }
    let (sim25, sim50) = maps(&sim_report);
    let (real25, real50) = maps(&real_report);
    outln!(
        "\nmAP@0.25 / @0.5: simulated val {sim25:.1} / {sim50:.1}, real scene {real25:.1} / {real50:.1}"
    );
    outln!(
        "indoor demo finished in {:.1} s (a tiny network trained for seconds on {} simulated rooms: the numbers show the pipeline, not F-ConvNet's accuracy)",
        started.elapsed().as_secs_f64(),
        train_ids.len()
    );
    Ok(())
}
