//! Training Voxel R-CNN: frames augmented and voxelized on the data thread, stage one's
//! anchor loss, proposals from its (detached) predictions, RoIs sampled against the
//! ground truth, stage two's loss; AdamW with the one-cycle schedule by default.

use super::config::VoxelRcnnSection;
use super::data::{VoxelBatch, VoxelData, collate};
use super::detector::{batch_proposals, pool_and_head, roi_grid_query};
use crate::config::ExperimentConfig;
use crate::error::{PipelineError, Result};
use crate::trainer::{
    ForwardParts, StepLoss, TrainOptions, TrainSummary, TrainingTask, open_run, run_training,
};
use burn::prelude::*;
use fusiondet_dataset::rng::Sampler;
use fusiondet_dataset::{FrameSource, InMemoryFrames, SensorFrame};
use fusiondet_models::voxel_rcnn::loss::box_corners;
use fusiondet_models::voxel_rcnn::{
    RoiLossTargets, VoxelRcnn, VoxelRcnnShape, anchor_loss, load_voxel_rcnn, roi_loss,
    save_voxel_rcnn,
};
use fusiondet_nn::gather::RowGather;
use fusiondet_voxel::{GtDatabase, GtSampler, RoiTargets, sample_rois};
use rayon::prelude::*;
use std::path::Path;

/// The parts a training step's forward pass is timed in (`metrics.jsonl`,
/// `step_seconds.forward_parts`), shared by DASANet's. Stage one's part is the network and
/// its anchor loss; the proposals read back what they need of its predictions (on a GPU the
/// kept anchors' rows, waiting for the queue); RoI sampling is host work, and so is the RoI
/// query on the CPU (on a GPU its kernels are queued); DASANet's STCA crops its points on
/// the host (`stca_crops`) and then builds its encoder's indices on the host and queues its
/// network (`stca`); the loss part queues the terms (they are read once the backward pass
/// and the update are queued, `trainer::LossValues`).
pub(crate) const PART_STAGE_ONE: &str = "stage_one";
pub(crate) const PART_PROPOSALS: &str = "proposals";
pub(crate) const PART_ROI_SAMPLING: &str = "roi_sampling";
pub(crate) const PART_ROI_QUERY: &str = "roi_query";
pub(crate) const PART_STCA_CROPS: &str = "stca_crops";
pub(crate) const PART_STCA: &str = "stca";
pub(crate) const PART_STAGE_TWO: &str = "stage_two";
pub(crate) const PART_LOSS: &str = "loss";

/// Where a run keeps the ground-truth database it built from its training split.
pub const GT_DATABASE_DIR: &str = "gt_database";

pub struct VoxelRcnnTask<'a> {
    config: &'a ExperimentConfig,
    frames: InMemoryFrames<SensorFrame>,
    data: VoxelData,
    shape: VoxelRcnnShape,
    /// The training device: batches (and their rulebooks) are built on it by the data
    /// thread, ahead of the step.
    device: Device,
    /// Frames with at least one LiDAR point in range (the others have nothing to learn
    /// from and would leave a batch without voxels).
    usable: Vec<usize>,
}

/// A batch and the stream its RoI sampling draws from.
pub struct TrainBatch {
    pub batch: VoxelBatch,
    pub roi_seed: u64,
}

/// A freshly initialised network whose weights depend on the seed alone.
pub fn seeded_network(
    config: &ExperimentConfig,
    shape: &VoxelRcnnShape,
    device: &Device,
) -> Result<VoxelRcnn> {
    crate::trainer::seeded(config.train.seed, device, |on| {
        VoxelRcnn::new(&shape.network, shape.grid_z, on).map_err(PipelineError::Invalid)
    })
}

/// Stage two's loss targets from the sampled RoIs of every frame (in batch order).
pub(crate) fn roi_loss_targets(targets: &[RoiTargets], device: &Device) -> RoiLossTargets {
    let cls: Vec<f32> = targets
        .iter()
        .flat_map(|t| t.cls_targets.iter().copied())
        .collect();
    let r = cls.len();
    let mut fg_rows = Vec::new();
    let (mut reg, mut sizes, mut centres, mut gt_sizes, mut headings) =
        (vec![], vec![], vec![], vec![], vec![]);
    let mut row = 0u32;
    for t in targets {
        for i in 0..t.len() {
            if t.reg_valid[i] {
                fg_rows.push(row);
                reg.extend(t.reg_targets[i]);
                let roi = &t.rois[i];
                sizes.extend([roi.dx as f32, roi.dy as f32, roi.dz as f32]);
                let g = &t.canonical_gt[i];
                centres.extend([g.x as f32, g.y as f32, g.z as f32]);
                gt_sizes.extend([g.dx as f32, g.dy as f32, g.dz as f32]);
                headings.push(g.heading as f32);
            }
            row += 1;
        }
    }
    let f = fg_rows.len();
    let t2 = |v: Vec<f32>, c: usize| Tensor::<2>::from_data(TensorData::new(v, [f, c]), device);
    let flipped: Vec<f32> = headings.iter().map(|h| h + std::f32::consts::PI).collect();
    let corners =
        |h: Vec<f32>| box_corners(t2(centres.clone(), 3), t2(gt_sizes.clone(), 3), t2(h, 1));
    RoiLossTargets {
        cls: Tensor::from_data(TensorData::new(cls, [r, 1]), device),
        fg_rows: (f > 0).then(|| RowGather::new(&fg_rows, r, device)),
        reg: t2(reg, 7),
        roi_sizes: t2(sizes, 3),
        gt_corners: corners(headings.clone()),
        gt_corners_flipped: corners(flipped),
    }
}

impl TrainingTask for VoxelRcnnTask<'_> {
    type Model = VoxelRcnn;
    type Batch = TrainBatch;

    fn frames(&self) -> usize {
        self.frames.len()
    }
    fn samples(&self) -> usize {
        self.usable.len()
    }
    fn sample_noun(&self) -> &'static str {
        "frames"
    }
    fn sample_note(&self) -> String {
        format!(
            " ({} of {} frames have no LiDAR point in range)",
            self.frames.len() - self.usable.len(),
            self.frames.len()
        )
    }
    fn new_model(&self, device: &Device) -> Result<VoxelRcnn> {
        seeded_network(self.config, &self.shape, device)
    }
    fn load_model(&self, path: &Path, device: &Device) -> Result<VoxelRcnn> {
        Ok(load_voxel_rcnn(&self.shape, path, device)?)
    }
    fn save_model(&self, model: &VoxelRcnn, path: &Path) -> Result<()> {
        Ok(save_voxel_rcnn(model, &self.shape, path)?)
    }
    fn epoch_batches(
        &self,
        epoch: usize,
    ) -> Box<dyn ExactSizeIterator<Item = Result<TrainBatch>> + Send + '_> {
        let seed = self.config.train.seed;
        let batches = epoch_frame_batches(&self.usable, seed, epoch, self.config.train.batch_size);
        Box::new(batches.into_iter().enumerate().map(move |(k, frames)| {
            // Frames of a batch in parallel (each draws from its own seeded stream), so that
            // beside a GPU the data thread keeps ahead of the steps.
            let samples = frames
                .par_iter()
                .map(|&i| {
                    let frame = self.frames.frame(i)?;
                    self.data
                        .sample(&frame, Some(&mut augment_sampler(seed, epoch, i)))
                })
                .collect::<Result<Vec<_>>>()?;
            Ok(TrainBatch {
                batch: collate(&self.data, samples, true, &self.device)?,
                roi_seed: roi_seed(seed, epoch, k),
            })
        }))
    }
    fn loss(&self, net: &VoxelRcnn, prepared: TrainBatch, device: &Device) -> Result<StepLoss> {
        let section: &VoxelRcnnSection = &self.data.section;
        let TrainBatch { batch, roi_seed } = prepared;
        let mut parts = ForwardParts::default();
        let out = parts.time(PART_STAGE_ONE, || {
            net.stage_one(batch.features.to_device(device), &batch.plan)
        });
        let targets = batch
            .anchor_targets
            .as_ref()
            .expect("training batches carry targets");
        let [cls, loc, dir] = parts.time(PART_STAGE_ONE, || {
            anchor_loss(&out.anchors, targets, &section.loss)
        });
        let proposals = parts.time(PART_PROPOSALS, || {
            batch_proposals(&self.data, &out.anchors, &section.proposals.train)
        });
        let (sampled, rois) = parts.time(PART_ROI_SAMPLING, || {
            sample_training_rois(section, &proposals, &batch.gts, roi_seed)
        })?;
        let index = parts.time(PART_ROI_QUERY, || {
            roi_grid_query(section, &out.backbone, &rois)
        });
        let pred = parts.time(PART_STAGE_TWO, || {
            pool_and_head(net, section, &out.backbone, &index)
        });
        let loss = parts.time(PART_LOSS, || {
            let [rcnn_cls, rcnn_reg, corner] =
                roi_loss(&pred, &roi_loss_targets(&sampled, device), &section.loss);
            StepLoss::from_terms(vec![
                ("cls", cls),
                ("loc", loc),
                ("dir", dir),
                ("rcnn_cls", rcnn_cls),
                ("rcnn_reg", rcnn_reg),
                ("rcnn_corner", corner),
            ])
        });
        Ok(loss.with_parts(parts))
    }
}

/// The frames of each batch of epoch `epoch`: the usable frames in the epoch's seeded order.
pub(crate) fn epoch_frame_batches(
    usable: &[usize],
    seed: u64,
    epoch: usize,
    batch_size: usize,
) -> Vec<Vec<usize>> {
    let mut order = usable.to_vec();
    Sampler::from_path(seed, &[0x5A11, epoch as u64]).shuffle(&mut order);
    order.chunks(batch_size).map(<[usize]>::to_vec).collect()
}

/// The stream frame `frame`'s augmentation draws from in epoch `epoch`.
pub(crate) fn augment_sampler(seed: u64, epoch: usize, frame: usize) -> Sampler {
    Sampler::from_path(seed, &[0xA06, epoch as u64, frame as u64])
}

/// The seed of batch `k`'s RoI sampling in epoch `epoch`.
pub(crate) fn roi_seed(seed: u64, epoch: usize, k: usize) -> u64 {
    fusiondet_dataset::rng::derive(&[seed, 0x2015, epoch as u64, k as u64])
}

/// The sampled RoIs of every frame with their targets, and the same RoIs as boxes.
pub(crate) type SampledRois = (Vec<RoiTargets>, Vec<Vec<[f64; 7]>>);

/// Stage two's training RoIs of every frame: sampled from its proposals against its
/// ground truth (OpenPCDet's proposal target layer), with their targets.
pub(crate) fn sample_training_rois(
    section: &VoxelRcnnSection,
    proposals: &[Vec<fusiondet_voxel::Proposal>],
    gts: &[Vec<fusiondet_voxel::GtBox>],
    roi_seed: u64,
) -> Result<SampledRois> {
    let mut rng = Sampler::new(roi_seed);
    let sampled = proposals
        .iter()
        .zip(gts)
        .map(|(p, gts)| sample_rois(p, gts, &section.roi_targets, &mut rng))
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(|e| PipelineError::Invalid(e.to_string()))?;
    let rois = sampled
        .iter()
        .map(|t| t.rois.iter().map(|b| b.to_array()).collect())
        .collect();
    Ok((sampled, rois))
}

/// Where `fusiondet gt-database` keeps a data set's database of `split`: beside the data,
/// as OpenPCDet keeps its `kitti_dbinfos_<split>.pkl`.
pub fn data_gt_database_dir(data_dir: &Path, split: &str) -> std::path::PathBuf {
    data_dir.join("gt_database").join(split)
}

/// The labelled objects of `frames` with their points, built in parallel (in frame order).
/// `frame_done` is called once per frame (a progress bar's tick).
pub fn build_gt_database(
    frames: &InMemoryFrames<SensorFrame>,
    frame_done: &(dyn Fn() + Sync),
) -> Result<GtDatabase> {
    let parts = (0..frames.len())
        .into_par_iter()
        .map(|i| {
            let part = GtDatabase::of_frame(frames.frame(i)?.as_ref());
            frame_done();
            Ok(part)
        })
        .collect::<Result<Vec<GtDatabase>>>()?;
    let mut db = GtDatabase::new();
    for part in parts {
        db.extend(part);
    }
    Ok(db)
}

/// A training database: the data set's prepared one (`fusiondet gt-database`) when it has
/// one, restricted to the objects of `frames` (those the run trains on), else the run's,
/// read back on resume or built from `frames` and written into the run directory.
pub(crate) fn cached_gt_database(
    prepared: &Path,
    run_dir: &Path,
    frames: &InMemoryFrames<SensorFrame>,
    build: impl FnOnce() -> Result<GtDatabase>,
) -> Result<GtDatabase> {
    for dir in [prepared, run_dir] {
        if dir.join("index.json").is_file() {
            let db = GtDatabase::load(dir).map_err(|e| PipelineError::Invalid(e.to_string()))?;
            // A prepared database holds the whole split; a run on part of it (`max_frames`)
            // pastes only its own frames' objects, so that its result does not depend on
            // whether the data set was prepared (issue 34: 18.5 against 64.5 3D AP).
            let ids: std::collections::HashSet<&str> =
                (0..frames.len()).map(|i| frames.frame_id(i)).collect();
            return Ok(db.restricted_to_frames(|frame| ids.contains(frame)));
        }
    }
    let db = build()?;
    db.save(run_dir)
        .map_err(|e| PipelineError::Invalid(e.to_string()))?;
    Ok(db)
}

/// Trains a Voxel R-CNN.
pub fn train(options: &TrainOptions) -> Result<TrainSummary> {
    let cfg = &options.config;
    cfg.validate(Path::new("the training configuration"))?;
    let section = super::detector::VoxelRcnnDetector::section(cfg)?.clone();
    let opened = open_run(options, cfg, |old| old == *cfg)?;
    let frames: InMemoryFrames<SensorFrame> = fusiondet_dataset::load_split(
        &options.data_dir,
        &cfg.train.split,
        cfg.train.max_frames,
        true,
    )?;
    let sampler = if section.augment.sample_groups.is_empty() {
        None
    } else {
        let db = cached_gt_database(
            &data_gt_database_dir(&options.data_dir, &cfg.train.split),
            &opened.run.root.join(GT_DATABASE_DIR),
            &frames,
            || build_gt_database(&frames, &|| {}),
        )?;
        Some(
            GtSampler::new(db, &section.augment)
                .map_err(|e| PipelineError::Invalid(e.to_string()))?,
        )
    };
    let data = VoxelData::new(&section, sampler)?;
    let usable = (0..frames.len())
        .into_par_iter()
        .map(|i| {
            let frame = frames.frame(i)?;
            Ok((i, !data.sample(&frame, None)?.voxels.is_empty()))
        })
        .collect::<Result<Vec<(usize, bool)>>>()?
        .into_iter()
        .filter_map(|(i, has_points)| has_points.then_some(i))
        .collect();
    let task = VoxelRcnnTask {
        config: cfg,
        data,
        shape: section.shape(),
        frames,
        device: options.device.device().autodiff(),
        usable,
    };
    run_training(&task, options, opened)
}

/// Parameters of the configuration's network.
pub fn trained_parameters(config: &ExperimentConfig) -> Result<usize> {
    let section = super::detector::VoxelRcnnDetector::section(config)?;
    let shape = section.shape();
    let model = VoxelRcnn::new(&shape.network, shape.grid_z, &Device::flex())
        .map_err(PipelineError::Invalid)?;
    Ok(fusiondet_models::info::trainable_params(&model))
}
