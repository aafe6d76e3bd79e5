//! The voxel family's detector: voxels → stage one → proposals → voxel RoI pooling →
//! RoI head → refined boxes (score = the RoI head's confidence) → NMS → KITTI results in
//! the camera frame. Frames are detected one at a time (batch 1, as OpenPCDet's test).

use super::config::VoxelRcnnSection;
use super::data::{VoxelData, batch_inputs};
use super::proposals::{decode_proposals, nms_sorted, top_k};
use crate::config::ExperimentConfig;
use crate::detection::{FrameResults, StageTimes};
use crate::error::{PipelineError, Result};
use burn::prelude::*;
use fusiondet_dataset::{FrameSource, InMemoryFrames, SensorFrame};
use fusiondet_geometry::{alpha_from_ry, normalize_angle, project_to_image};
use fusiondet_kitti::Object;
use fusiondet_models::voxel_rcnn::{
    AnchorPredictions, BackboneOutput, BackbonePlan, RoiBox, RoiGridIndex, RoiPredictions,
    VoxelGeometry, VoxelRcnn, load_voxel_rcnn, pooled_maps,
};
use fusiondet_voxel::{LidarBox, Proposal, decode_roi};
use rayon::prelude::*;
use std::path::Path;
use std::time::Instant;

pub const STAGE_VOXELIZE: &str = "voxelize";
/// The sparse convolutions' rulebooks, built on the host (and uploaded to a GPU), apart
/// from the convolutions so that a GPU's share of each shows.
pub const STAGE_RULEBOOKS: &str = "rulebooks (host)";
pub const STAGE_BACKBONE: &str = "3D backbone (sparse convs)";
pub const STAGE_BEV: &str = "BEV backbone + anchor head";
pub const STAGE_PROPOSALS: &str = "proposals (decode, NMS)";
pub const STAGE_ROI_QUERY: &str = "RoI grid query";
pub const STAGE_ROI_POOL: &str = "RoI grid pooling";
pub const STAGE_HEAD: &str = "RoI head";
pub const STAGE_NMS: &str = "boxes + NMS";

/// The pooling geometry of a configuration's voxel grid.
pub fn voxel_geometry(section: &VoxelRcnnSection) -> VoxelGeometry {
    let r = &section.voxels.point_range;
    VoxelGeometry {
        origin: [r[0], r[1], r[2]],
        voxel_size: section.voxels.voxel_size,
    }
}

/// A tensor's values (inference copy).
pub fn values<const D: usize>(t: &Tensor<D>) -> Vec<f32> {
    t.try_to_vec_as::<f32>().expect("f32 tensor data")
}

/// `run()`'s output, timed as stage `name` until the device has computed `waited(&output)`
/// (one of its values read back: on a GPU the stage's time then holds its kernels, not only
/// their launching).
pub fn timed_until<T, const D: usize>(
    timing: &mut StageTimes,
    name: &'static str,
    run: impl FnOnce() -> T,
    waited: impl FnOnce(&T) -> Tensor<D>,
) -> T {
    let t = Instant::now();
    let output = run();
    let first: [std::ops::Range<usize>; D] = std::array::from_fn(|_| 0..1);
    let _ = values(&waited(&output).slice(first));
    timing.add(name, t.elapsed());
    output
}

/// Stage one's proposals of every frame of a batch.
pub fn batch_proposals(
    data: &VoxelData,
    anchors: &AnchorPredictions,
    nms: &super::config::NmsConfig,
) -> Vec<Vec<Proposal>> {
    let [b, a, k] = anchors.cls.dims();
    let bins = data.assigner.direction_bins();
    let nb = bins.bins;
    let (cls, boxes, dir) = (
        values(&anchors.cls),
        values(&anchors.boxes),
        values(&anchors.direction),
    );
    // Frames in parallel (each its own NMS), collected in frame order.
    (0..b)
        .into_par_iter()
        .map(|f| {
            decode_proposals(
                data.assigner.anchors(),
                &data.classes,
                &bins,
                &cls[f * a * k..(f + 1) * a * k],
                &boxes[f * a * 7..(f + 1) * a * 7],
                &dir[f * a * nb..(f + 1) * a * nb],
                nms,
            )
        })
        .collect()
}

/// The grid points of `rois[b]` of each frame b and their neighbours at every pooling
/// level, over the sites of the backbone's maps: on the host, or on a GPU backend's device
/// (`RoiGridIndex::on_device`).
pub fn roi_grid_query(
    section: &VoxelRcnnSection,
    backbone: &BackboneOutput,
    rois: &[Vec<RoiBox>],
) -> RoiGridIndex {
    let levels = &section.network.roi.levels;
    let maps = pooled_maps(backbone, levels);
    let device = maps
        .first()
        .map_or_else(Device::flex, |m| m.features.device());
    let sites: Vec<&fusiondet_nn::sparse::SparseSites> =
        maps.iter().map(|m| m.sites.as_ref()).collect();
    RoiGridIndex::on_device(
        rois,
        &sites,
        levels,
        section.network.roi.grid_size,
        &voxel_geometry(section),
        &device,
    )
}

/// Stage two on a grid index: RoI grid pooling and the head's predictions.
pub fn pool_and_head(
    model: &VoxelRcnn,
    section: &VoxelRcnnSection,
    backbone: &BackboneOutput,
    index: &RoiGridIndex,
) -> RoiPredictions {
    let maps = pooled_maps(backbone, &section.network.roi.levels);
    model.roi_head.forward(model.roi_pool.forward(&maps, index))
}

/// Stage two over `rois[b]` of each frame b: the grid index and the head's predictions.
pub fn refine(
    model: &VoxelRcnn,
    section: &VoxelRcnnSection,
    backbone: &BackboneOutput,
    rois: &[Vec<RoiBox>],
    timing: Option<&mut StageTimes>,
) -> RoiPredictions {
    let t = Instant::now();
    let index = roi_grid_query(section, backbone, rois);
    let queried = Instant::now();
    let maps = pooled_maps(backbone, &section.network.roi.levels);
    let pooled = model.roi_pool.forward(&maps, &index);
    let pooled_at = Instant::now();
    let out = model.roi_head.forward(pooled);
    if let Some(timing) = timing {
        timing.add(STAGE_ROI_QUERY, queried - t);
        timing.add(STAGE_ROI_POOL, pooled_at - queried);
        timing.add(STAGE_HEAD, pooled_at.elapsed());
    }
    out
}

/// A LiDAR box as a KITTI result in the camera frame; `None` when it does not project
/// into the image (the KITTI evaluation needs a 2D box).
pub fn to_result(
    b: &LidarBox,
    class: fusiondet_kitti::ObjectClass,
    score: f64,
    frame: &SensorFrame,
) -> Option<Object> {
    let mut box3d = b.to_camera(&frame.camera);
    // KITTI results keep ry in (−π, π]; decoded headings may be a turn away.
    box3d.ry = normalize_angle(box3d.ry);
    let [w, h] = frame.image_size;
    let bbox = project_to_image(&box3d, &frame.camera, w, h)?;
    Some(Object {
        class,
        truncation: 0.0,
        occlusion: 0,
        alpha: alpha_from_ry(box3d.ry, box3d.x, box3d.z),
        bbox,
        box3d,
        score: Some(score),
    })
}

/// The final boxes of one frame: refined RoIs scored by the head, thresholded, NMS.
pub fn final_boxes(
    section: &VoxelRcnnSection,
    proposals: &[Proposal],
    cls: &[f32],
    codes: &[f32],
) -> Vec<Proposal> {
    let post = &section.post;
    let candidates: Vec<Proposal> = proposals
        .iter()
        .enumerate()
        .map(|(r, p)| {
            let code: [f64; 7] = std::array::from_fn(|j| codes[r * 7 + j] as f64);
            Proposal {
                bbox: decode_roi(&code, &p.bbox),
                score: 1.0 / (1.0 + (-(cls[r] as f64)).exp()),
                class: p.class,
            }
        })
        .filter(|p| p.score >= post.score_threshold)
        .collect();
    let scores: Vec<f64> = candidates.iter().map(|p| p.score).collect();
    let order = top_k(&scores, post.nms.pre_max);
    let sorted: Vec<LidarBox> = order.iter().map(|&i| candidates[i].bbox).collect();
    nms_sorted(&sorted, post.nms.iou, post.nms.post_max)
        .into_iter()
        .map(|j| candidates[order[j]])
        .collect()
}

/// The KITTI results of one frame: its proposals refined by the head's predictions,
/// thresholded, suppressed, in the camera frame.
pub fn frame_objects(
    section: &VoxelRcnnSection,
    proposals: &[Proposal],
    pred: &RoiPredictions,
    frame: &SensorFrame,
) -> Vec<Object> {
    final_boxes(section, proposals, &values(&pred.cls), &values(&pred.boxes))
        .iter()
        .filter_map(|p| to_result(&p.bbox, p.class, p.score, frame))
        .collect()
}

/// Stage one's proposals of a single frame (detection runs batch 1), timed as their stage.
pub fn timed_frame_proposals(
    data: &VoxelData,
    anchors: &AnchorPredictions,
    section: &VoxelRcnnSection,
    timing: &mut StageTimes,
) -> Vec<Proposal> {
    let t = Instant::now();
    let proposals = batch_proposals(data, anchors, &section.proposals.test).remove(0);
    timing.add(STAGE_PROPOSALS, t.elapsed());
    proposals
}

/// A frame's result objects from stage two's predictions (boxes and NMS), timed.
pub fn timed_frame_objects(
    section: &VoxelRcnnSection,
    proposals: &[Proposal],
    pred: &RoiPredictions,
    frame: &SensorFrame,
    timing: &mut StageTimes,
) -> Vec<Object> {
    let t = Instant::now();
    let objects = frame_objects(section, proposals, pred, frame);
    timing.add(STAGE_NMS, t.elapsed());
    objects
}

/// Each frame's proposals as the RoI boxes of a batch of one.
pub fn single_frame_rois(proposals: &[Proposal]) -> Vec<Vec<RoiBox>> {
    vec![proposals.iter().map(|p| p.bbox.to_array()).collect()]
}

pub struct VoxelRcnnDetector {
    pub config: ExperimentConfig,
    pub model: VoxelRcnn,
    pub data: VoxelData,
}

impl VoxelRcnnDetector {
    pub fn section(config: &ExperimentConfig) -> Result<&VoxelRcnnSection> {
        config.voxel_rcnn.as_ref().ok_or_else(|| {
            PipelineError::Invalid(format!("{}: not a voxel_rcnn configuration", config.name))
        })
    }

    pub fn load(config: ExperimentConfig, checkpoint: &Path, device: &Device) -> Result<Self> {
        let section = Self::section(&config)?.clone();
        let model = load_voxel_rcnn(&section.shape(), checkpoint, device)?;
        Ok(VoxelRcnnDetector {
            data: VoxelData::new(&section, None)?,
            model,
            config,
        })
    }

    /// Detects on every frame; a frame without a LiDAR point in range gets no boxes. Each
    /// frame's voxels and rulebooks are prepared on threads beside the network (one beside
    /// the CPU, several beside a GPU) while it runs on the frames before
    /// ([`crate::prefetch`]), and then its stage one ([`crate::prefetch::stage_one_ahead`]).
    pub fn detect_frames(
        &self,
        device: &Device,
        frames: &InMemoryFrames<SensorFrame>,
        timing: &mut StageTimes,
    ) -> Result<FrameResults> {
        let ahead = crate::prefetch::stage_one_ahead().map_err(PipelineError::Invalid)?;
        self.detect_frames_with(device, frames, ahead, timing)
    }

    /// [`Self::detect_frames`] with stage one on the preparing threads (`stage_one_ahead`)
    /// or on the network's thread. The same operations run on each frame either way, so
    /// the results are the same bits.
    pub fn detect_frames_with(
        &self,
        device: &Device,
        frames: &InMemoryFrames<SensorFrame>,
        stage_one_ahead: bool,
        timing: &mut StageTimes,
    ) -> Result<FrameResults> {
        let section = &self.data.section;
        let data = &self.data;
        let mut results = FrameResults::default();
        let preparers = crate::prefetch::preparers(device).map_err(PipelineError::Invalid)?;
        crate::prefetch::prepared_in_order::<_, PipelineError>(
            frames.len(),
            preparers,
            timing,
            |index, timing| {
                let frame = frames.frame(index)?;
                let t = Instant::now();
                let sample = data.sample(&frame, None)?;
                timing.add(STAGE_VOXELIZE, t.elapsed());
                if sample.voxels.is_empty() {
                    return Ok((frame, FrameStage::Empty));
                }
                let t = Instant::now();
                let inputs = batch_inputs(
                    std::slice::from_ref(&sample),
                    section.voxels.sparse_shape(),
                    device,
                )?;
                timing.add(STAGE_RULEBOOKS, t.elapsed());
                Ok((
                    frame,
                    match stage_one_ahead {
                        true => self.stage_one(inputs, timing),
                        false => FrameStage::Inputs(inputs),
                    },
                ))
            },
            |(frame, stage), timing| {
                let objects = results.objects.entry(frame.id.clone()).or_default();
                let stage = match stage {
                    FrameStage::Inputs(inputs) => self.stage_one(inputs, timing),
                    stage => stage,
                };
                let FrameStage::Proposed(backbone, proposals) = stage else {
                    return Ok(());
                };
                let rois = single_frame_rois(&proposals);
                let pred = refine(&self.model, section, &backbone, &rois, Some(timing));
                objects.extend(timed_frame_objects(
                    section, &proposals, &pred, &frame, timing,
                ));
                results.samples += 1;
                Ok(())
            },
        )?;
        Ok(results)
    }

    /// Stage one of a frame: the 3D backbone, the BEV backbone and anchor head, the
    /// proposals (each timed as its stage; a GPU is waited for after each network stage so
    /// that its time shows). [`FrameStage::Empty`] where there are no proposals.
    fn stage_one(
        &self,
        (features, plan): (Tensor<2>, BackbonePlan),
        timing: &mut StageTimes,
    ) -> FrameStage {
        let section = &self.data.section;
        let backbone = timed_until(
            timing,
            STAGE_BACKBONE,
            || self.model.backbone.forward(features, &plan),
            |b| b.output.features.clone(),
        );
        let anchors = timed_until(
            timing,
            STAGE_BEV,
            || {
                let maps = fusiondet_models::voxel_rcnn::height_compression(&backbone.output);
                self.model.anchor_head.forward(self.model.bev.forward(maps))
            },
            |a| a.cls.clone(),
        );
        let proposals = timed_frame_proposals(&self.data, &anchors, section, timing);
        match proposals.is_empty() {
            true => FrameStage::Empty,
            false => FrameStage::Proposed(backbone, proposals),
        }
    }
}

/// How far a frame has come before the network's thread takes it: nothing to detect, its
/// inputs, or through stage one (its backbone's maps and its proposals).
enum FrameStage {
    Empty,
    Inputs((Tensor<2>, BackbonePlan)),
    Proposed(BackboneOutput, Vec<Proposal>),
}
