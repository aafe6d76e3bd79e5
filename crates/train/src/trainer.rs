//! The training loop: seeded initialisation, Adam with step decay, a data thread that
//! prepares the next batch while the network trains on the current one, per-epoch
//! checkpoints (weights and optimizer state) and metrics, and exact resume.

use crate::config::{ExperimentConfig, RefineConfig};
use crate::detect::{Detector, FrameResults, StageTimes};
use crate::device::ComputeDevice;
use crate::error::{Result, TrainError};
use crate::metrics_log::MetricsLog;
use crate::run_dir::{RunDir, RunState};
use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, GradientsParams, OptimizerRecord};
use burn::prelude::*;
use fusiondet_frustum::{FrustumDataset, InMemoryFrames, PreparedBatch};
use fusiondet_kitti::{DatasetDir, read_detections2d, write_atomic};
use fusiondet_models::{FConvNet, LossTargets, fconvnet_loss, load_checkpoint, save_checkpoint};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What `fusiondet train` was asked to do.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    pub config: ExperimentConfig,
    pub data_dir: PathBuf,
    pub run_dir: PathBuf,
    pub resume: bool,
    /// Show a progress bar on stderr.
    pub progress: bool,
    /// Where the network trains.
    pub device: ComputeDevice,
}

/// What a finished `train` call did.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainSummary {
    pub frames: usize,
    pub frustums: usize,
    pub epochs_run: usize,
    pub epochs_done: usize,
    pub final_loss: Option<f64>,
    pub model: PathBuf,
}

/// Loads the frames of a split (all of them, or the first `max_frames`) in the frustum
/// family's form.
pub fn load_split(
    data_dir: &Path,
    split: &str,
    max_frames: usize,
    with_labels: bool,
) -> Result<InMemoryFrames> {
    Ok(fusiondet_dataset::load_split(
        data_dir,
        split,
        max_frames,
        with_labels,
    )?)
}

fn bar(len: usize, enabled: bool) -> indicatif::ProgressBar {
    if !enabled {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{prefix} [{bar:30}] {pos}/{len} batches {elapsed}<{eta} {msg}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar
}

/// A freshly initialised network whose weights depend on the seed alone. burn's
/// initialisers draw from one process-wide generator, so seeding and drawing happen
/// under a lock: two runs in one process (tests, ablations) cannot interleave draws.
pub fn seeded_network(cfg: &ExperimentConfig, device: &Device) -> Result<FConvNet> {
    static INIT: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = INIT.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    device.seed(cfg.train.seed);
    Ok(FConvNet::new(&cfg.model, device)?)
}

/// A refinement run keeps its first stage beside its own model (`first-stage.bpk` and
/// `first-stage.toml`), and its `config.toml` names that copy: the run directory is
/// self-contained and can be moved.
pub const FIRST_STAGE_FILE: &str = "first-stage.bpk";

/// Copies the first stage named by `refine` into the run directory (atomically).
fn copy_first_stage(refine: &RefineConfig, run: &RunDir) -> Result<()> {
    let first = ExperimentConfig::for_checkpoint(&refine.first_stage, None)?;
    let bytes = std::fs::read(&refine.first_stage).map_err(|e| TrainError::RunDir {
        path: refine.first_stage.clone(),
        message: format!("cannot read the first-stage checkpoint: {e}"),
    })?;
    let dest = run.root.join(FIRST_STAGE_FILE);
    write_atomic(&dest, &bytes)?;
    write_atomic(
        &dest.with_extension("toml"),
        first.to_toml_string().as_bytes(),
    )?;
    Ok(())
}

/// The first stage's results on the training frames (from the split's 2D detections):
/// the proposals a refinement stage learns to correct.
fn training_proposals(
    first_stage: &Path,
    options: &TrainOptions,
    frames: &InMemoryFrames,
) -> Result<FrameResults> {
    let device = options.device.device();
    let config = ExperimentConfig::for_checkpoint(first_stage, None)?;
    let detector = Detector::load(config, first_stage, &device)?;
    let split = &options.config.train.split;
    let detections = read_detections2d(&DatasetDir::new(&options.data_dir).rgb_detections(split))?;
    let mut timing = StageTimes::default();
    detector.detect_frames(&device, frames.clone(), &detections, &mut timing)
}

pub fn train(options: &TrainOptions) -> Result<TrainSummary> {
    let cfg = &options.config;
    let run = RunDir::new(&options.run_dir);
    // The stored configuration names the run's own copy of a first stage.
    let mut stored = cfg.clone();
    if let Some(r) = &mut stored.refine {
        r.first_stage = PathBuf::from(FIRST_STAGE_FILE);
    }
    // A resumed run may be given more (or fewer) epochs; everything else must match.
    let compatible = |stored: &str| {
        ExperimentConfig::from_toml_str(stored, &run.config()).is_ok_and(|mut old| {
            old.train.epochs = cfg.train.epochs;
            old.refine.clone_from(&cfg.refine);
            old == *cfg
        })
    };
    let resumed = run.open(&stored.to_toml_string(), options.resume, &compatible)?;
    let log = MetricsLog::new(run.metrics());
    let first_stage = run.root.join(FIRST_STAGE_FILE);
    if let Some(r) = &cfg.refine
        && (resumed.is_none() || !first_stage.is_file())
    {
        copy_first_stage(r, &run)?;
    }

    let frames = load_split(
        &options.data_dir,
        &cfg.train.split,
        cfg.train.max_frames,
        true,
    )?;
    let num_frames = fusiondet_frustum::FrameSource::len(&frames);
    let dataset = match &cfg.refine {
        None => FrustumDataset::from_labels(frames, cfg.frustum.clone(), cfg.train.seed)?,
        Some(_) => {
            let proposals = training_proposals(&first_stage, options, &frames)?;
            if options.progress {
                eprintln!(
                    "first stage: {} boxes on {num_frames} training frames",
                    proposals.objects.values().map(Vec::len).sum::<usize>()
                );
            }
            FrustumDataset::from_proposals(frames, &proposals.objects, cfg.frustum.clone(), true)?
        }
    };
    if dataset.len() < cfg.train.batch_size {
        return Err(TrainError::Invalid(format!(
            "{} training frustums (skipped: {:?}) are fewer than one batch of {}; use more frames or a smaller train.batch_size",
            dataset.len(),
            dataset.skips(),
            cfg.train.batch_size
        )));
    }

    let ad = options.device.device().autodiff();
    let mut optim = AdamConfig::new()
        .with_weight_decay(Some(WeightDecayConfig::new(cfg.train.weight_decay as f32)))
        .init();
    let (mut model, start_epoch) = match &resumed {
        Some(state) => {
            let model = load_checkpoint(&cfg.model, &run.root.join(&state.model), &ad)?;
            let record = OptimizerRecord::load(run.root.join(&state.optimizer)).map_err(|e| {
                TrainError::RunDir {
                    path: run.root.join(&state.optimizer),
                    message: format!("cannot read the optimizer state: {e}"),
                }
            })?;
            optim = optim.load_record(record);
            log.truncate_to(state.epochs_done)?;
            (model, state.epochs_done)
        }
        None => (seeded_network(cfg, &ad)?, 0),
    };

    let mut final_loss = None;
    for epoch in start_epoch..cfg.train.epochs {
        let lr = cfg.train.lr.lr_at(epoch);
        let started = Instant::now();
        let batches = dataset.epoch(cfg.train.seed, epoch as u64, cfg.train.batch_size);
        let progress = bar(batches.len(), options.progress);
        progress.set_prefix(format!("epoch {}/{}", epoch + 1, cfg.train.epochs));
        let mut sums: Vec<(&'static str, f64)> = Vec::new();
        let mut steps = 0usize;
        // The data thread prepares batch k+1 (in parallel over its frustums) while the
        // network trains on batch k.
        let mut slot = Some(model);
        let outcome: Result<()> = std::thread::scope(|scope| {
            let (tx, rx) =
                std::sync::mpsc::sync_channel::<fusiondet_frustum::Result<PreparedBatch>>(2);
            scope.spawn(move || {
                for b in batches {
                    if tx.send(b).is_err() {
                        break;
                    }
                }
            });
            for prepared in rx {
                let prepared = prepared?;
                let net = slot.take().expect("the model is put back after every step");
                let inputs = net.inputs(&prepared.batch, &ad)?;
                let targets = LossTargets::new(&prepared.batch, &cfg.model, &cfg.loss, &ad)?;
                let loss = fconvnet_loss(&net.forward_inputs(&inputs), &targets, &cfg.loss)?;
                let grads = GradientsParams::from_grads(loss.total.backward(), &net);
                slot = Some(optim.step(lr, net, grads));
                for (k, (name, value)) in loss.components.named().into_iter().enumerate() {
                    if sums.len() <= k {
                        sums.push((name, 0.0));
                    }
                    sums[k].1 += value as f64;
                }
                steps += 1;
                progress.set_message(format!("loss {:.3}", sums[0].1 / steps as f64));
                progress.inc(1);
            }
            Ok(())
        });
        progress.finish_and_clear();
        outcome?;
        model = slot.expect("the model is put back after every step");

        let done = epoch + 1;
        let state = RunState {
            epochs_done: done,
            model: run.epoch_model(done),
            optimizer: run.epoch_optimizer(done),
        };
        save_checkpoint(&model, &run.root.join(&state.model))?;
        optim
            .to_record()
            .save(run.root.join(&state.optimizer))
            .map_err(|e| TrainError::RunDir {
                path: run.root.join(&state.optimizer),
                message: format!("cannot write the optimizer state: {e}"),
            })?;
        save_checkpoint(&model, &run.model())?;
        run.commit(&state)?;

        let mut record = json!({
            "epoch": epoch,
            "lr": lr,
            "batches": steps,
            "frustums": steps * cfg.train.batch_size,
            "seconds": started.elapsed().as_secs_f64(),
        });
        for (name, sum) in &sums {
            record[format!("loss_{name}")] = json!(sum / steps.max(1) as f64);
        }
        final_loss = sums.first().map(|(_, s)| s / steps.max(1) as f64);
        log.append(&record)?;
        if options.progress {
            eprintln!(
                "epoch {done}/{}: loss {:.4}, lr {lr:.1e}, {:.1} s",
                cfg.train.epochs,
                final_loss.unwrap_or(f64::NAN),
                started.elapsed().as_secs_f64()
            );
        }
    }
    Ok(TrainSummary {
        frames: num_frames,
        frustums: dataset.len(),
        epochs_run: cfg.train.epochs.saturating_sub(start_epoch),
        epochs_done: cfg.train.epochs.max(start_epoch),
        final_loss,
        model: run.model(),
    })
}
