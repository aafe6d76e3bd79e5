//! DASANet's detector: pseudo cloud → both branches' voxels → stage one → proposals →
//! TDIS over both branches' RoI grids and STCA over the points in each RoI → detection
//! head → refined boxes → NMS → KITTI results. Batch 1, as Voxel R-CNN's detector.

use super::config::DasanetSection;
use super::data::{DasanetBatch, DasanetData, collate};
use crate::config::ExperimentConfig;
use crate::detection::{FrameResults, StageTimes};
use crate::error::{PipelineError, Result};
use crate::voxel_rcnn::VoxelRcnnSection;
// Proposals and the final boxes are Voxel R-CNN's steps, timed under its stage names.
pub use crate::voxel_rcnn::detector::{STAGE_NMS, STAGE_PROPOSALS};
use crate::voxel_rcnn::detector::{
    roi_grid_query, single_frame_rois, timed_frame_objects, timed_frame_proposals, timed_until,
    values,
};
use burn::prelude::*;
use fusiondet_dataset::{FrameSource, InMemoryFrames, SensorFrame};
use fusiondet_models::dasanet::{
    Dasanet, DasanetNetConfig, DasanetRoiInputs, DasanetShape, DasanetStageOne, RoiPoints,
    load_dasanet_for_detection,
};
use fusiondet_models::voxel_rcnn::{RoiBox, RoiGridIndex};
use std::path::Path;
use std::time::Instant;

pub const STAGE_PSEUDO: &str = "depth completion + pseudo points";
pub const STAGE_VOXELIZE: &str = "augment-free scene + voxelize (both clouds)";
/// Both clouds' sparse-convolution rulebooks, built on the host (and uploaded to a GPU).
pub const STAGE_RULEBOOKS: &str = "rulebooks, both clouds (host)";
pub const STAGE_LIDAR_BACKBONE: &str = "LiDAR 3D backbone";
pub const STAGE_PSEUDO_BACKBONE: &str = "pseudo 3D backbone";
pub const STAGE_BEV: &str = "BEV backbone + anchor head";
pub const STAGE_ROI_QUERY: &str = "RoI queries (both grids)";
/// STCA's crops of the points in each RoI: on the threads that prepare frames where stage
/// one runs there, else on the network's thread while the device pools and fuses.
pub const STAGE_CROPS: &str = "STCA crops (host)";
pub const STAGE_TDIS: &str = "RoI grid pooling (both) + TDIS";
pub const STAGE_STCA: &str = "STCA (encoder, attention)";
pub const STAGE_HEAD: &str = "detection head";

/// What stage two reads for `rois[b]` of each frame b, in two parts (TDIS can be queued
/// between them): both branches' RoI grid queries, where the network has TDIS.
pub fn roi_grids(
    section: &VoxelRcnnSection,
    network: &DasanetNetConfig,
    stage_one: &DasanetStageOne,
    rois: &[Vec<RoiBox>],
) -> Option<(RoiGridIndex, RoiGridIndex)> {
    network.modules.tdis.then(|| {
        (
            roi_grid_query(section, &stage_one.lidar, rois),
            roi_grid_query(section, &stage_one.pseudo, rois),
        )
    })
}

/// Each cloud's points in the RoIs, cropped on the host, where the network has STCA.
pub fn roi_points(
    network: &DasanetNetConfig,
    rois: &[Vec<RoiBox>],
    clouds: &[(Vec<f32>, Vec<f32>)],
) -> Option<(RoiPoints, RoiPoints)> {
    let m = &network.modules;
    m.stca.then(|| {
        let flat: Vec<RoiBox> = rois.iter().flatten().copied().collect();
        let batch_of_roi: Vec<usize> = rois
            .iter()
            .enumerate()
            .flat_map(|(b, list)| std::iter::repeat_n(b, list.len()))
            .collect();
        let lidar: Vec<(&[f32], usize)> = clouds.iter().map(|(l, _)| (l.as_slice(), 4)).collect();
        let pseudo: Vec<(&[f32], usize)> = clouds.iter().map(|(_, p)| (p.as_slice(), 6)).collect();
        (
            RoiPoints::new(&lidar, &flat, &batch_of_roi, &m.stca_shape),
            RoiPoints::new(&pseudo, &flat, &batch_of_roi, &m.stca_shape),
        )
    })
}

pub struct DasanetDetector {
    pub config: ExperimentConfig,
    pub model: Dasanet,
    pub shape: DasanetShape,
    pub data: DasanetData,
}

/// The Voxel R-CNN and DASANet sections of a DASANet configuration.
pub fn sections(config: &ExperimentConfig) -> Result<(&VoxelRcnnSection, &DasanetSection)> {
    match (&config.voxel_rcnn, &config.dasanet) {
        (Some(v), Some(d)) => Ok((v, d)),
        _ => Err(PipelineError::Invalid(format!(
            "{}: not a dasanet configuration",
            config.name
        ))),
    }
}

impl DasanetDetector {
    pub fn load(config: ExperimentConfig, checkpoint: &Path, device: &Device) -> Result<Self> {
        let (voxel, dasanet) = sections(&config)?;
        // A run's model.bpk leaves out the auxiliary heads, an epoch checkpoint holds them.
        let shape = dasanet.shape(voxel);
        let model = load_dasanet_for_detection(&shape, checkpoint, device)?;
        let data = super::task::detection_data(voxel, dasanet)?;
        Ok(DasanetDetector {
            model,
            shape,
            data,
            config,
        })
    }

    /// Detects on every frame; a frame without LiDAR or pseudo points in range gets no
    /// boxes. `depth_dir` holds completed maps to use instead of completing. Each frame's
    /// pseudo cloud, voxels and rulebooks are prepared on threads beside the network (one
    /// beside the CPU, several beside a GPU) while it runs on the frames before
    /// ([`crate::prefetch`]), and then its stage one ([`crate::prefetch::stage_one_ahead`]).
    pub fn detect_frames(
        &self,
        device: &Device,
        frames: &InMemoryFrames<SensorFrame>,
        depth_dir: Option<&Path>,
        timing: &mut StageTimes,
    ) -> Result<FrameResults> {
        let ahead = crate::prefetch::stage_one_ahead().map_err(PipelineError::Invalid)?;
        self.detect_frames_with(device, frames, depth_dir, ahead, timing)
    }

    /// [`Self::detect_frames`] with stage one on the preparing threads (`stage_one_ahead`)
    /// or on the network's thread. The same operations run on each frame either way, so
    /// the results are the same bits.
    pub fn detect_frames_with(
        &self,
        device: &Device,
        frames: &InMemoryFrames<SensorFrame>,
        depth_dir: Option<&Path>,
        stage_one_ahead: bool,
        timing: &mut StageTimes,
    ) -> Result<FrameResults> {
        let section = &self.data.voxel.section;
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
                let pseudo = data.pseudo.cloud(&frame, depth_dir)?;
                timing.add(STAGE_PSEUDO, t.elapsed());
                let t = Instant::now();
                let sample = data.sample_with_cloud(&frame, pseudo, None)?;
                timing.add(STAGE_VOXELIZE, t.elapsed());
                if !sample.has_voxels() {
                    return Ok((frame, FrameStage::Empty));
                }
                let t = Instant::now();
                let batch = collate(data, vec![sample], false, device)?;
                timing.add(STAGE_RULEBOOKS, t.elapsed());
                Ok((
                    frame,
                    match stage_one_ahead {
                        true => self.stage_one(batch, true, timing),
                        false => FrameStage::Inputs(Box::new(batch)),
                    },
                ))
            },
            |(frame, stage), timing| {
                let objects = results.objects.entry(frame.id.clone()).or_default();
                let stage = match stage {
                    FrameStage::Inputs(batch) => self.stage_one(*batch, false, timing),
                    stage => stage,
                };
                let FrameStage::Proposed(proposed) = stage else {
                    return Ok(());
                };
                let Proposed {
                    stage_one,
                    proposals,
                    rois,
                    crops,
                } = *proposed;
                let pred = self.refine_timed(&stage_one, &rois, crops, timing);
                objects.extend(timed_frame_objects(
                    section, &proposals, &pred, &frame, timing,
                ));
                results.samples += 1;
                Ok(())
            },
        )?;
        Ok(results)
    }

    /// Stage one of a frame: both 3D backbones, the BEV backbone and anchor head, the
    /// proposals (each timed as its stage; a GPU is waited for after each network stage so
    /// that its time shows), and with `crop` STCA's crops of their RoIs (on a preparing
    /// thread: host work the network's thread then does not wait for).
    /// [`FrameStage::Empty`] where there are no proposals.
    fn stage_one(&self, batch: DasanetBatch, crop: bool, timing: &mut StageTimes) -> FrameStage {
        let section = &self.data.voxel.section;
        let model = &self.model;
        let lidar = timed_until(
            timing,
            STAGE_LIDAR_BACKBONE,
            || {
                model
                    .lidar_backbone
                    .forward(batch.lidar_features, &batch.lidar_plan)
            },
            |b| b.output.features.clone(),
        );
        let pseudo = timed_until(
            timing,
            STAGE_PSEUDO_BACKBONE,
            || {
                model
                    .pseudo_backbone
                    .forward(batch.pseudo_features, &batch.pseudo_plan)
            },
            |b| b.output.features.clone(),
        );
        let anchors = timed_until(
            timing,
            STAGE_BEV,
            || model.bev_and_anchors(&lidar, &pseudo),
            |a| a.cls.clone(),
        );
        let proposals = timed_frame_proposals(&self.data.voxel, &anchors, section, timing);
        if proposals.is_empty() {
            return FrameStage::Empty;
        }
        let rois = single_frame_rois(&proposals);
        let crops = match crop {
            true => Crops::Made(timed_crops(
                &self.shape.network,
                &rois,
                &batch.clouds,
                timing,
            )),
            false => Crops::FromClouds(batch.clouds),
        };
        FrameStage::Proposed(Box::new(Proposed {
            stage_one: DasanetStageOne {
                lidar,
                pseudo,
                anchors,
            },
            proposals,
            rois,
            crops,
        }))
    }

    /// Stage two with each module's time. Where the crops were not made with stage one,
    /// TDIS is queued before STCA's points are cropped on the host, so that on a GPU the
    /// crops run while the device pools and fuses (on the CPU, which computes as it is
    /// asked, the order changes nothing); its stage then holds what is left to wait for
    /// after the crops.
    fn refine_timed(
        &self,
        stage_one: &DasanetStageOne,
        rois: &[Vec<RoiBox>],
        crops: Crops,
        timing: &mut StageTimes,
    ) -> fusiondet_models::voxel_rcnn::RoiPredictions {
        let section = &self.data.voxel.section;
        let network = &self.shape.network;
        let t = Instant::now();
        let mut inputs = DasanetRoiInputs {
            grids: roi_grids(section, network, stage_one, rois),
            points: None,
        };
        timing.add(STAGE_ROI_QUERY, t.elapsed());
        let t = Instant::now();
        let supplemented = self.model.supplemented(network, stage_one, &inputs);
        let queued = t.elapsed();
        inputs.points = match crops {
            Crops::Made(points) => points,
            Crops::FromClouds(clouds) => timed_crops(network, rois, &clouds, timing),
        };
        if let Some(f) = &supplemented {
            let t = Instant::now();
            let _ = values(&f.clone().slice([0..1, 0..1]));
            timing.add(STAGE_TDIS, queued + t.elapsed());
        }
        let t = Instant::now();
        let attention = self
            .model
            .attention(&inputs, &stage_one.anchors.cls.device());
        if let Some(f) = &attention {
            let _ = values(&f.clone().slice([0..1, 0..1]));
            timing.add(STAGE_STCA, t.elapsed());
        }
        let parts = Dasanet::head_input(&supplemented, &attention);
        let t = Instant::now();
        let pred = self.model.head.forward(parts);
        let _ = values(&pred.cls);
        timing.add(STAGE_HEAD, t.elapsed());
        pred
    }
}

/// How far a frame has come before the network's thread takes it: nothing to detect, its
/// inputs, or through stage one.
enum FrameStage {
    Empty,
    Inputs(Box<DasanetBatch>),
    Proposed(Box<Proposed>),
}

/// A frame through stage one: its backbones' maps and anchors, its proposals and their
/// RoIs, and STCA's crops of them or the clouds to crop.
struct Proposed {
    stage_one: DasanetStageOne,
    proposals: Vec<fusiondet_voxel::Proposal>,
    rois: Vec<Vec<RoiBox>>,
    crops: Crops,
}

/// [`roi_points`], its time added to [`STAGE_CROPS`].
fn timed_crops(
    network: &DasanetNetConfig,
    rois: &[Vec<RoiBox>],
    clouds: &[(Vec<f32>, Vec<f32>)],
    timing: &mut StageTimes,
) -> Option<(RoiPoints, RoiPoints)> {
    let t = Instant::now();
    let points = roi_points(network, rois, clouds);
    timing.add(STAGE_CROPS, t.elapsed());
    points
}

/// STCA's crops of a frame's RoIs, made with its stage one on a preparing thread, or the
/// clouds they are cropped from on the network's thread.
enum Crops {
    Made(Option<(RoiPoints, RoiPoints)>),
    FromClouds(Vec<(Vec<f32>, Vec<f32>)>),
}
