//! Training the frustum family: frustums from the labels (or, for a refinement stage,
//! around its first stage's boxes), F-ConvNet's loss.

use crate::config::{DatasetFormat, ExperimentConfig, RefineConfig};
use crate::detection::{FrameResults, StageTimes};
use crate::error::{PipelineError, Result};
use crate::frustum::FrustumDetector;
use crate::run_dir::RunDir;
use crate::trainer::{
    LossValues, StepLoss, TrainOptions, TrainSummary, TrainingTask, open_run, run_training,
};
use burn::prelude::*;
use fusiondet_frustum::{FrameSource, FrustumDataset, InMemoryFrames, PreparedBatch};
use fusiondet_kitti::{DatasetDir, read_detections2d, write_atomic};
use fusiondet_models::{FConvNet, LossTargets, fconvnet_loss, load_checkpoint, save_checkpoint};
use std::path::{Path, PathBuf};

/// A refinement run keeps its first stage beside its own model (`first-stage.bpk` and
/// `first-stage.toml`), and its `config.toml` names that copy: the run directory is
/// self-contained and can be moved.
pub const FIRST_STAGE_FILE: &str = "first-stage.bpk";

/// A freshly initialised F-ConvNet whose weights depend on the seed alone.
pub fn seeded_network(cfg: &ExperimentConfig, device: &Device) -> Result<FConvNet> {
    crate::trainer::seeded(cfg.train.seed, device, |on| {
        Ok(FConvNet::new(&cfg.model, on)?)
    })
}

/// The frustum family's training: its frustum data set and F-ConvNet's loss.
pub struct FrustumTask<'a> {
    config: &'a ExperimentConfig,
    frames: usize,
    dataset: FrustumDataset<InMemoryFrames>,
}

impl TrainingTask for FrustumTask<'_> {
    type Model = FConvNet;
    type Batch = PreparedBatch;

    fn frames(&self) -> usize {
        self.frames
    }
    fn samples(&self) -> usize {
        self.dataset.len()
    }
    fn sample_noun(&self) -> &'static str {
        "frustums"
    }
    fn sample_note(&self) -> String {
        let k = self.dataset.skips();
        let skipped: Vec<String> = [
            ("outside the image", k.outside_image),
            ("too small", k.too_small),
            ("without points", k.no_points),
            ("without object points", k.no_object_points),
            ("in frames not in the split", k.unknown_frame),
            ("unmatched", k.unmatched),
        ]
        .iter()
        .filter(|(_, n)| *n > 0)
        .map(|(why, n)| format!("{n} {why}"))
        .collect();
        match skipped.is_empty() {
            true => String::new(),
            false => format!(" (skipped: {})", skipped.join(", ")),
        }
    }
    fn new_model(&self, device: &Device) -> Result<FConvNet> {
        seeded_network(self.config, device)
    }
    fn load_model(&self, path: &Path, device: &Device) -> Result<FConvNet> {
        Ok(load_checkpoint(&self.config.model, path, device)?)
    }
    fn save_model(&self, model: &FConvNet, path: &Path) -> Result<()> {
        Ok(save_checkpoint(model, path)?)
    }
    fn epoch_batches(
        &self,
        epoch: usize,
    ) -> Box<dyn ExactSizeIterator<Item = Result<PreparedBatch>> + Send + '_> {
        let cfg = self.config;
        Box::new(
            self.dataset
                .epoch(cfg.train.seed, epoch as u64, cfg.train.batch_size)
                .map(|b| b.map_err(PipelineError::from)),
        )
    }
    fn loss(&self, net: &FConvNet, prepared: PreparedBatch, device: &Device) -> Result<StepLoss> {
        let cfg = self.config;
        let inputs = net.inputs(&prepared.batch, device)?;
        let targets = LossTargets::new(&prepared.batch, &cfg.model, &cfg.loss, device)?;
        let loss = fconvnet_loss(&net.forward_inputs(&inputs), &targets, &cfg.loss)?;
        Ok(StepLoss {
            total: loss.total,
            components: LossValues::Read(loss.components.named().to_vec()),
            parts: Default::default(),
        })
    }
}

/// Copies the first stage named by `refine` into the run directory (atomically).
fn copy_first_stage(refine: &RefineConfig, run: &RunDir) -> Result<()> {
    let first = ExperimentConfig::for_checkpoint(&refine.first_stage, None)?;
    let bytes = fusiondet_kitti::error::read_regular(
        &refine.first_stage,
        fusiondet_kitti::error::MAX_BINARY_BYTES,
    )?;
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
    let detector = FrustumDetector::load(config, first_stage, &device)?;
    let split = &options.config.train.split;
    let detections = read_detections2d(&DatasetDir::new(&options.data_dir).rgb_detections(split))?;
    let mut timing = StageTimes::default();
    detector.detect_frames(&device, frames.clone(), &detections, &mut timing)
}

/// Trains a frustum detector (first stage or refinement stage).
pub fn train(options: &TrainOptions) -> Result<TrainSummary> {
    let cfg = &options.config;
    cfg.validate(Path::new("the training configuration"))?;
    // The stored configuration names the run's own copy of a first stage.
    let mut stored = cfg.clone();
    if let Some(r) = &mut stored.refine {
        r.first_stage = PathBuf::from(FIRST_STAGE_FILE);
    }
    let opened = open_run(options, &stored, |mut old| {
        old.refine.clone_from(&cfg.refine);
        old == *cfg
    })?;
    let first_stage = opened.run.root.join(FIRST_STAGE_FILE);
    if let Some(r) = &cfg.refine
        && (opened.resumed.is_none() || !first_stage.is_file())
    {
        copy_first_stage(r, &opened.run)?;
    }

    let frames: InMemoryFrames = match cfg.dataset.format {
        DatasetFormat::Kitti => fusiondet_dataset::load_split(
            &options.data_dir,
            &cfg.train.split,
            cfg.train.max_frames,
            true,
        )?,
        DatasetFormat::SunRgbd => fusiondet_dataset::indoor::load_scene_split(
            &options.data_dir,
            &cfg.train.split,
            cfg.train.max_frames,
            true,
        )?,
    };
    let num_frames = frames.len();
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
    let task = FrustumTask {
        config: cfg,
        frames: num_frames,
        dataset,
    };
    run_training(&task, options, opened)
}

/// Parameters of a trained model as the papers count them: both stages of a refinement
/// model (its first stage's configuration found beside its checkpoint).
pub fn trained_parameters(config: &ExperimentConfig) -> Result<usize> {
    let own = fusiondet_models::info::parameter_count(&config.model)?;
    let first = match &config.refine {
        Some(r) => fusiondet_models::info::parameter_count(
            &ExperimentConfig::for_checkpoint(&r.first_stage, None)?.model,
        )?,
        None => 0,
    };
    Ok(own + first)
}
