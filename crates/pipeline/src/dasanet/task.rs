//! Training DASANet: frames with their pseudo clouds augmented and voxelized on the data
//! thread; stage one's anchor loss (Voxel R-CNN's L_RPN); proposals from its detached
//! predictions; RoIs sampled against the ground truth; L_RCNN of the detection head
//! (BCE, smooth-L1, 3D GIoU) and, when both modules are on, the auxiliary heads.

use super::config::DasanetSection;
use super::data::{DasanetBatch, DasanetData, collate};
use super::detector::{roi_grids, roi_points, sections};
use super::pseudo::PseudoCloudMaker;
use crate::config::ExperimentConfig;
use crate::error::{PipelineError, Result};
use crate::trainer::{
    ForwardParts, StepLoss, TrainOptions, TrainSummary, TrainingTask, open_run, run_training,
};
use crate::voxel_rcnn::VoxelRcnnSection;
use crate::voxel_rcnn::data::VoxelData;
use crate::voxel_rcnn::detector::batch_proposals;
use crate::voxel_rcnn::task::{
    PART_LOSS, PART_PROPOSALS, PART_ROI_QUERY, PART_ROI_SAMPLING, PART_STAGE_ONE, PART_STAGE_TWO,
    PART_STCA, PART_STCA_CROPS, augment_sampler, cached_gt_database, data_gt_database_dir,
    epoch_frame_batches, roi_loss_targets, roi_seed, sample_training_rois,
};
use burn::prelude::*;
use fusiondet_dataset::{FrameSource, InMemoryFrames, SensorFrame};
use fusiondet_models::dasanet::{
    Dasanet, DasanetRoiInputs, DasanetShape, load_dasanet, rcnn_loss, save_dasanet,
    save_dasanet_for_inference,
};
use fusiondet_models::voxel_rcnn::anchor_loss;
use fusiondet_voxel::{GtDatabase, GtSampler};
use rayon::prelude::*;
use std::path::Path;

/// Where a run keeps the ground-truth database (with pseudo points) it built.
pub const PSEUDO_GT_DATABASE_DIR: &str = "gt_database_pseudo";

/// Where `fusiondet gt-database --pseudo` keeps a data set's database of `split`.
pub fn data_pseudo_gt_database_dir(data_dir: &Path, split: &str) -> std::path::PathBuf {
    data_gt_database_dir(data_dir, &format!("{split}-pseudo"))
}

/// The data side of detection (no augmentation, no database).
pub fn detection_data(voxel: &VoxelRcnnSection, dasanet: &DasanetSection) -> Result<DasanetData> {
    DasanetData::new(
        VoxelData::new(voxel, None)?,
        dasanet,
        PseudoCloudMaker::new(&dasanet.pseudo, voxel.voxels.point_range),
    )
}

/// The labelled objects of `frames` with their LiDAR and pseudo points, built in
/// parallel (in frame order).
/// `frame_done` is called once per frame (a progress bar's tick).
pub fn build_pseudo_gt_database(
    frames: &InMemoryFrames<SensorFrame>,
    maker: &PseudoCloudMaker,
    frame_done: &(dyn Fn() + Sync),
) -> Result<GtDatabase> {
    let parts = (0..frames.len())
        .into_par_iter()
        .map(|i| {
            let frame = frames.frame(i)?;
            let cloud = maker.cloud(&frame, None)?;
            let part = GtDatabase::of_frame_with_pseudo(frame.as_ref(), &cloud);
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

pub struct DasanetTask<'a> {
    config: &'a ExperimentConfig,
    frames: InMemoryFrames<SensorFrame>,
    data: DasanetData,
    shape: DasanetShape,
    device: Device,
    /// Frames with LiDAR and pseudo points in range.
    usable: Vec<usize>,
    /// Print TDIS's scale every step to stderr (`FUSIONDET_TDIS_STATS=1`; issue 34's
    /// measurement, see `Dasanet::tdis_scale`).
    tdis_stats: bool,
}

pub struct TrainBatch {
    pub batch: DasanetBatch,
    pub roi_seed: u64,
}

/// A freshly initialised network whose weights depend on the seed alone.
pub fn seeded_network(
    config: &ExperimentConfig,
    shape: &DasanetShape,
    device: &Device,
) -> Result<Dasanet> {
    crate::trainer::seeded(config.train.seed, device, |on| {
        Dasanet::new(&shape.network, shape.grid_z, on).map_err(PipelineError::Invalid)
    })
}

impl TrainingTask for DasanetTask<'_> {
    type Model = Dasanet;
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
            " ({} of {} frames have no LiDAR or no pseudo point in range)",
            self.frames.len() - self.usable.len(),
            self.frames.len()
        )
    }
    fn new_model(&self, device: &Device) -> Result<Dasanet> {
        seeded_network(self.config, &self.shape, device)
    }
    fn load_model(&self, path: &Path, device: &Device) -> Result<Dasanet> {
        Ok(load_dasanet(&self.shape, path, device)?)
    }
    fn save_model(&self, model: &Dasanet, path: &Path) -> Result<()> {
        Ok(save_dasanet(model, &self.shape, path)?)
    }
    fn save_inference_model(&self, model: &Dasanet, path: &Path) -> Result<()> {
        Ok(save_dasanet_for_inference(model, &self.shape, path)?)
    }
    fn epoch_batches(
        &self,
        epoch: usize,
    ) -> Box<dyn ExactSizeIterator<Item = Result<TrainBatch>> + Send + '_> {
        let seed = self.config.train.seed;
        let batches = epoch_frame_batches(&self.usable, seed, epoch, self.config.train.batch_size);
        Box::new(batches.into_iter().enumerate().map(move |(k, frames)| {
            // Frames of a batch in parallel: depth completion dominates their preparation.
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
    fn loss(&self, net: &Dasanet, prepared: TrainBatch, device: &Device) -> Result<StepLoss> {
        let section = &self.data.voxel.section;
        let dasanet = &self.data.section;
        let TrainBatch { batch, roi_seed } = prepared;
        let mut parts = ForwardParts::default();
        let out = parts.time(PART_STAGE_ONE, || {
            net.stage_one(
                batch.lidar_features.clone().to_device(device),
                &batch.lidar_plan,
                batch.pseudo_features.clone().to_device(device),
                &batch.pseudo_plan,
            )
        });
        let targets = batch
            .anchor_targets
            .as_ref()
            .expect("training batches carry targets");
        let [cls, loc, dir] = parts.time(PART_STAGE_ONE, || {
            anchor_loss(&out.anchors, targets, &section.loss)
        });
        let proposals = parts.time(PART_PROPOSALS, || {
            batch_proposals(&self.data.voxel, &out.anchors, &section.proposals.train)
        });
        let (sampled, rois) = parts.time(PART_ROI_SAMPLING, || {
            sample_training_rois(section, &proposals, &batch.gts, roi_seed)
        })?;
        // Both branches' grid queries, then TDIS queued before STCA's crops on the host, so
        // that on a GPU the crops run while the device pools and fuses.
        let network = &self.shape.network;
        let mut inputs = DasanetRoiInputs {
            grids: parts.time(PART_ROI_QUERY, || roi_grids(section, network, &out, &rois)),
            points: None,
        };
        let supplemented = parts.time(PART_STAGE_TWO, || net.supplemented(network, &out, &inputs));
        inputs.points = parts.time(PART_STCA_CROPS, || {
            roi_points(network, &rois, &batch.clouds)
        });
        let attention = parts.time(PART_STCA, || {
            net.attention(&inputs, &out.anchors.cls.device())
        });
        let pred = parts.time(PART_STAGE_TWO, || net.heads(supplemented, attention, true));
        if self.tdis_stats
            && let Some((ratio, largest)) = net.tdis_scale(network, &out, &inputs)
        {
            eprintln!("tdis-scale rms_ratio {ratio:.6} max_abs_weight {largest:.6}");
        }
        let loss = parts.time(PART_LOSS, || {
            let mut terms = vec![("cls", cls), ("loc", loc), ("dir", dir)];
            terms.extend(rcnn_loss(
                &pred,
                &roi_loss_targets(&sampled, device),
                &section.loss,
                dasanet.giou_weight,
                dasanet.modules.aux_weights,
            ));
            StepLoss::from_terms(terms)
        });
        Ok(loss.with_parts(parts))
    }
}

/// Trains a DASANet row.
pub fn train(options: &TrainOptions) -> Result<TrainSummary> {
    let cfg = &options.config;
    cfg.validate(Path::new("the training configuration"))?;
    let (voxel, dasanet) = sections(cfg)?;
    let opened = open_run(options, cfg, |old| old == *cfg)?;
    let frames: InMemoryFrames<SensorFrame> = fusiondet_dataset::load_split(
        &options.data_dir,
        &cfg.train.split,
        cfg.train.max_frames,
        true,
    )?;
    let maker = PseudoCloudMaker::new(&dasanet.pseudo, voxel.voxels.point_range);
    let sampler = if voxel.augment.sample_groups.is_empty() {
        None
    } else {
        // The data set's own (`fusiondet gt-database --pseudo`) or the run's.
        let db = cached_gt_database(
            &data_pseudo_gt_database_dir(&options.data_dir, &cfg.train.split),
            &opened.run.root.join(PSEUDO_GT_DATABASE_DIR),
            &frames,
            || build_pseudo_gt_database(&frames, &maker, &|| {}),
        )?;
        Some(
            GtSampler::new(db, &voxel.augment)
                .map_err(|e| PipelineError::Invalid(e.to_string()))?,
        )
    };
    let data = DasanetData::new(VoxelData::new(voxel, sampler)?, dasanet, maker)?;
    // Frames that leave either branch without a voxel are left out. Knowing it for the pseudo
    // branch takes a depth completion per frame (about 20 ms each, once per run): a LiDAR
    // point in range does not promise a pseudo point in range once the pixel stride and
    // thinning have picked theirs.
    let usable = (0..frames.len())
        .into_par_iter()
        .map(|i| {
            let frame = frames.frame(i)?;
            Ok((i, data.sample(&frame, None)?.has_voxels()))
        })
        .collect::<Result<Vec<(usize, bool)>>>()?
        .into_iter()
        .filter_map(|(i, ok)| ok.then_some(i))
        .collect();
    let task = DasanetTask {
        config: cfg,
        shape: dasanet.shape(voxel),
        data,
        frames,
        device: options.device.device().autodiff(),
        usable,
        tdis_stats: std::env::var_os("FUSIONDET_TDIS_STATS").is_some_and(|v| v == "1"),
    };
    run_training(&task, options, opened)
}

/// Parameters of the configuration's network at inference (without the auxiliary heads).
pub fn trained_parameters(config: &ExperimentConfig) -> Result<usize> {
    let (voxel, dasanet) = sections(config)?;
    let shape = dasanet.shape(voxel);
    let model = Dasanet::new(&shape.network, shape.grid_z, &Device::flex())
        .map_err(PipelineError::Invalid)?;
    Ok(model.param_rows().iter().map(|r| r.1).sum())
}
