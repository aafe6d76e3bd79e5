//! Train → resume → detect → evaluate on a small simulated dataset with the tiny network.

use burn::prelude::*;
use fusiondet_dataset::ClassSet;
use fusiondet_frustum::{BoxCoder, FrustumConfig, InMemoryFrames};
use fusiondet_kitti::{DatasetDir, read_detections2d, read_split};
use fusiondet_models::{ModelConfig, load_checkpoint};
use fusiondet_pipeline::frustum::FrustumDetector;
use fusiondet_pipeline::{
    DetectOptions, ExperimentConfig, RefineConfig, TrainOptions, detect, detect_in_chunks, train,
};
use std::path::Path;
use std::sync::OnceLock;

/// A 12-frame simulated dataset shared by the tests of this file.
fn dataset() -> &'static Path {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let opts = fusiondet_sim::DatasetOptions::new(dir.path().join("sim"), 12, 5);
        fusiondet_sim::write_dataset(&opts, &|_, _| {}).unwrap();
        dir
    })
    .path()
    .join("sim")
    .leak()
}

/// Bit-for-bit reproducibility holds for one training per process: two trainings
/// sharing rayon's pool change how its parallel float reductions split. The tests of
/// this file therefore take turns.
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|p| p.into_inner())
}

fn tiny(epochs: usize) -> ExperimentConfig {
    let mut c = ExperimentConfig {
        name: "tiny".into(),
        model: ModelConfig::tiny(),
        ..Default::default()
    };
    c.frustum = FrustumConfig {
        points_per_frustum: 256,
        ..FrustumConfig::car()
    };
    c.frustum.augment.copies = 2;
    c.train.epochs = epochs;
    c.train.batch_size = 4;
    c.train.split = "trainval".into();
    c.detect.batch_size = 8;
    c
}

fn train_run(dir: &Path, epochs: usize, resume: bool) -> fusiondet_pipeline::TrainSummary {
    train(&TrainOptions {
        resume,
        ..TrainOptions::new(tiny(epochs), dataset(), dir)
    })
    .unwrap()
}

/// The network's outputs on the same val frames, as a fingerprint of the weights.
fn fingerprint(model_path: &Path) -> Vec<f64> {
    let cfg = tiny(1);
    let device = Device::flex();
    let detector = FrustumDetector {
        model: load_checkpoint(&cfg.model, model_path, &device).unwrap(),
        config: cfg,
        first_stage: None,
    };
    let ds = DatasetDir::new(dataset());
    let ids = read_split(&ds.split("val")).unwrap();
    let frames = InMemoryFrames::load(&ds.training(), &ids, false).unwrap();
    let dets = read_detections2d(&ds.rgb_detections("val")).unwrap();
    let mut timing = Default::default();
    let results = detector
        .detect_frames(&device, frames, &dets, &mut timing)
        .unwrap();
    results
        .objects
        .values()
        .flatten()
        .flat_map(|o| {
            [
                o.box3d.x,
                o.box3d.z,
                o.box3d.l,
                o.box3d.ry,
                o.score.unwrap(),
            ]
        })
        .collect()
}

#[test]
fn resume_after_an_epoch_gives_the_same_weights_as_an_uninterrupted_run() {
    let _turn = one_at_a_time();
    let straight = tempfile::tempdir().unwrap();
    let s = train_run(straight.path(), 2, false);
    assert_eq!(s.epochs_run, 2);
    assert!(s.samples >= 8, "{s:?}");
    let metrics = std::fs::read_to_string(straight.path().join("metrics.jsonl")).unwrap();
    assert_eq!(metrics.lines().count(), 2);
    assert!(metrics.contains("\"loss_total\""), "{metrics}");
    // Each epoch says where its seconds went: the three parts, none negative, within the
    // epoch's whole (which also holds the checkpoint writes).
    for line in metrics.lines() {
        let record: serde_json::Value = serde_json::from_str(line).unwrap();
        let parts = &record["step_seconds"];
        let sum: f64 = ["data_wait", "forward_loss", "backward_update"]
            .iter()
            .map(|k| {
                let v = parts[k].as_f64().unwrap_or_else(|| panic!("{k} in {line}"));
                assert!(v >= 0.0, "{line}");
                v
            })
            .sum();
        assert!(
            sum > 0.0 && sum <= record["seconds"].as_f64().unwrap(),
            "{line}"
        );
        // The data thread's own time making the batches, beside the steps.
        let making = parts["data_prepare"].as_f64().unwrap();
        assert!(
            making > 0.0 && making <= record["seconds"].as_f64().unwrap(),
            "{line}"
        );
        // Every step's total loss, in order: the first is `first_step_loss`, and their mean
        // (the epoch being shorter than the curve's cap) the epoch's loss.
        let curve: Vec<f64> = record["loss_curve"]
            .as_array()
            .unwrap_or_else(|| panic!("loss_curve in {line}"))
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let batches = record["batches"].as_u64().unwrap() as usize;
        assert!(batches >= 2 && curve.len() == batches, "{line}");
        assert_eq!(curve[0], record["first_step_loss"].as_f64().unwrap());
        assert!(curve.windows(2).any(|w| w[0] != w[1]), "{line}");
        let mean = curve.iter().sum::<f64>() / batches as f64;
        assert!(
            (mean - record["loss_total"].as_f64().unwrap()).abs() <= 1e-12 * mean.abs(),
            "{line}"
        );
    }

    let interrupted = tempfile::tempdir().unwrap();
    train_run(interrupted.path(), 1, false);
    let r = train_run(interrupted.path(), 2, true);
    assert_eq!(r.epochs_run, 1);
    let metrics = std::fs::read_to_string(interrupted.path().join("metrics.jsonl")).unwrap();
    assert_eq!(metrics.lines().count(), 2);

    let a = fingerprint(&straight.path().join("model.bpk"));
    let b = fingerprint(&interrupted.path().join("model.bpk"));
    assert!(!a.is_empty());
    assert_eq!(a, b, "resumed training diverged from the uninterrupted run");
}

#[test]
fn a_run_directory_in_use_needs_resume_and_the_same_config() {
    let _turn = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    train_run(dir.path(), 1, false);
    let err = train(&TrainOptions::new(tiny(1), dataset(), dir.path()))
        .unwrap_err()
        .to_string();
    assert!(err.contains("--resume"), "{err}");
    let mut other = tiny(1);
    other.train.seed = 99;
    let err = train(&TrainOptions {
        resume: true,
        ..TrainOptions::new(other, dataset(), dir.path())
    })
    .unwrap_err()
    .to_string();
    assert!(err.contains("another configuration"), "{err}");
}

#[test]
fn detect_writes_a_result_file_per_frame_that_the_evaluation_reads() {
    let _turn = one_at_a_time();
    let run = tempfile::tempdir().unwrap();
    train_run(run.path(), 1, false);
    let out = run.path().join("results");
    let options = |out: &Path| {
        DetectOptions::new(tiny(1), run.path().join("model.bpk"), dataset(), "val", out)
    };
    let summary = detect(&options(&out)).unwrap();
    // A frame's boxes do not depend on the frames detected beside it: one frame at a time
    // (one frame in memory) writes the same bytes.
    let one_by_one = run.path().join("one-by-one");
    let chunked = detect_in_chunks(&options(&one_by_one), 1).unwrap();
    assert_eq!(chunked.samples, summary.samples);
    assert_same_files(&out, &one_by_one);
    let ids = read_split(&DatasetDir::new(dataset()).split("val")).unwrap();
    assert_eq!(summary.frames, ids.len());
    for id in &ids {
        assert!(
            out.join(format!("{id}.txt")).is_file(),
            "no result for {id}"
        );
    }
    assert!(summary.boxes_written > 0 && summary.boxes_written <= summary.samples);
    let label_dir = dataset().join("training/label_2");
    let split = DatasetDir::new(dataset()).split("val");
    let (report, loaded) =
        fusiondet_eval::evaluate_dirs(&label_dir, &out, Some(&split), &Default::default()).unwrap();
    assert!(loaded.missing_results.is_empty());
    assert_eq!(report.frames, ids.len());
}

/// Every file of `a` is in `b` with the same bytes, and `b` holds no other.
fn assert_same_files(a: &Path, b: &Path) {
    let names = |dir: &Path| {
        let mut n: Vec<_> = std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        n.sort();
        n
    };
    assert_eq!(names(a), names(b));
    for name in names(a) {
        if name == ".fusiondet-results" {
            continue;
        }
        assert_eq!(
            std::fs::read(a.join(&name)).unwrap(),
            std::fs::read(b.join(&name)).unwrap(),
            "{name:?} differs between {} and {}",
            a.display(),
            b.display()
        );
    }
}

#[test]
fn a_checkpoint_from_another_config_is_refused() {
    let _turn = one_at_a_time();
    let run = tempfile::tempdir().unwrap();
    train_run(run.path(), 1, false);
    let mut other = tiny(1);
    other.model = ModelConfig::car();
    let err = detect(&DetectOptions::new(
        other,
        run.path().join("model.bpk"),
        dataset(),
        "val",
        run.path().join("r"),
    ))
    .unwrap_err()
    .to_string();
    assert!(err.contains("another model configuration"), "{err}");
}

/// A tiny refinement stage over the first stage trained in `first`.
fn tiny_refinement(first: &Path) -> ExperimentConfig {
    let mut c = tiny(1);
    c.name = "tiny-refine".into();
    c.frustum = FrustumConfig {
        points_per_frustum: 128,
        ..FrustumConfig::car_refinement()
    };
    // The 1-epoch first stage places boxes roughly: match generously.
    if let Some(crop) = &mut c.frustum.proposal_crop {
        crop.match_iou = 0.05;
    }
    c.train.split = "train".into();
    c.refine = Some(RefineConfig {
        first_stage: first.join("model.bpk"),
    });
    c
}

#[test]
fn a_refinement_stage_trains_on_first_stage_boxes_and_detects_through_both_stages() {
    let _turn = one_at_a_time();
    let first = tempfile::tempdir().unwrap();
    let mut first_cfg = tiny(2);
    first_cfg.train.split = "train".into();
    train(&TrainOptions::new(first_cfg, dataset(), first.path())).unwrap();
    let second = tempfile::tempdir().unwrap();
    let run = second.path().join("refine");
    let summary = train(&TrainOptions::new(
        tiny_refinement(first.path()),
        dataset(),
        run.clone(),
    ))
    .unwrap();
    assert!(summary.samples >= 4, "{summary:?}");
    // The run holds its own copy of the first stage and its config names the copy.
    assert!(run.join("first-stage.bpk").is_file());
    assert!(run.join("first-stage.toml").is_file());
    let stored = ExperimentConfig::for_checkpoint(&run.join("model.bpk"), None).unwrap();
    assert_eq!(
        stored.refine.as_ref().unwrap().first_stage,
        run.join("first-stage.bpk")
    );
    // Detection runs both stages: one refined box per first-stage box at most.
    drop(first);
    let out = second.path().join("results");
    let refined = detect(&DetectOptions::new(
        stored,
        run.join("model.bpk"),
        dataset(),
        "val",
        out.clone(),
    ))
    .unwrap();
    assert!(refined.samples > 0, "{refined:?}");
    let in_pairs = second.path().join("in-pairs");
    detect_in_chunks(
        &DetectOptions::new(
            ExperimentConfig::for_checkpoint(&run.join("model.bpk"), None).unwrap(),
            run.join("model.bpk"),
            dataset(),
            "val",
            in_pairs.clone(),
        ),
        2,
    )
    .unwrap();
    assert_same_files(&out, &in_pairs);
    assert!(refined.boxes_written > 0 && refined.boxes_written <= refined.samples);
    let first_only = detect(&DetectOptions::new(
        ExperimentConfig::for_checkpoint(&run.join("first-stage.bpk"), None).unwrap(),
        run.join("first-stage.bpk"),
        dataset(),
        "val",
        second.path().join("first"),
    ))
    .unwrap();
    // Every first-stage box became a refinement frustum or was skipped (the summary's
    // skips are both stages').
    let second_stage_skips = refined.skipped.total() - first_only.skipped.total();
    assert_eq!(
        refined.samples + second_stage_skips,
        first_only.boxes_written
    );
    let read_all = |dir: &Path| {
        let ids = read_split(&DatasetDir::new(dataset()).split("val")).unwrap();
        ids.iter()
            .map(|id| std::fs::read_to_string(dir.join(format!("{id}.txt"))).unwrap())
            .collect::<Vec<_>>()
    };
    assert_ne!(
        read_all(&out),
        read_all(&second.path().join("first")),
        "refinement changed no box"
    );
}

/// The heading bins are the network's setting, and targets, loss and decoding follow it:
/// 8 bins train and detect end to end.
#[test]
fn another_heading_bin_count_trains_and_detects() {
    let _turn = one_at_a_time();
    let mut config = tiny(1);
    config.model.num_heading_bins = 8;
    config.frustum.coder = BoxCoder::new(8, ClassSet::kitti()).unwrap();
    let run = tempfile::tempdir().unwrap();
    let summary = train(&TrainOptions::new(
        config.clone(),
        dataset(),
        run.path().join("r"),
    ))
    .unwrap();
    assert!(
        summary.final_loss.is_some_and(f64::is_finite),
        "{summary:?}"
    );
    let out = run.path().join("results");
    let detected = detect(&DetectOptions {
        device: Default::default(),
        config,
        checkpoint: summary.model,
        data_dir: dataset().to_path_buf(),
        split: "val".into(),
        out_dir: out,
        detections: None,
        depth_dir: None,
        replace: false,
        shard: None,
    })
    .unwrap();
    assert!(detected.boxes_written > 0, "{detected:?}");
}

#[test]
fn a_refinement_config_without_its_first_stage_is_a_clear_error() {
    let _turn = one_at_a_time();
    let missing = tempfile::tempdir().unwrap();
    let run = tempfile::tempdir().unwrap();
    let err = train(&TrainOptions::new(
        tiny_refinement(&missing.path().join("nowhere")),
        dataset(),
        run.path().join("r"),
    ))
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("nowhere") && err.contains("model.bpk"),
        "{err}"
    );
}
