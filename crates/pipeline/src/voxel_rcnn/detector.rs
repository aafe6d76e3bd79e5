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

/// Stage one's proposals of every frame of a batch: on the host, or on a GPU backend's
/// device with only the kept anchors read back ([`super::proposals::proposal_place`]).
pub fn batch_proposals(
    data: &VoxelData,
    predictions: &AnchorPredictions,
    nms: &super::config::NmsConfig,
) -> Vec<Vec<Proposal>> {
    let (anchors, classes, bins) = (
        data.assigner.anchors(),
        &data.classes,
        data.assigner.direction_bins(),
    );
    #[cfg(any(feature = "wgpu", feature = "cuda"))]
    {
        use super::proposals::{ProposalPlace, proposal_place};
        let ranked = nms.pre_max.min(anchors.len());
        let fits = ranked <= fusiondet_models::voxel_rcnn::proposals_device::MAX_RANKED;
        let device = predictions.cls.device();
        let on_device = || {
            let anchor_tensor = data.device_anchors(&device);
            device_proposals(anchors, classes, &bins, &anchor_tensor, predictions, nms)
        };
        match proposal_place(&device) {
            ProposalPlace::Device if fits => return on_device(),
            ProposalPlace::Check if fits => {
                let host = host_proposals(anchors, classes, &bins, predictions, nms);
                report_proposal_differences(&host, &on_device());
                return host;
            }
            _ => {}
        }
    }
    host_proposals(anchors, classes, &bins, predictions, nms)
}

/// Each frame's proposals from `predictions` over `anchors`, chosen on the host: every
/// anchor's predictions read back.
pub fn host_proposals(
    anchors: &fusiondet_voxel::Anchors,
    classes: &[fusiondet_kitti::ObjectClass],
    bins: &fusiondet_voxel::DirectionBins,
    predictions: &AnchorPredictions,
    nms: &super::config::NmsConfig,
) -> Vec<Vec<Proposal>> {
    let [b, a, k] = predictions.cls.dims();
    let nb = bins.bins;
    let (cls, boxes, dir) = (
        values(&predictions.cls),
        values(&predictions.boxes),
        values(&predictions.direction),
    );
    // Frames in parallel (each its own NMS), collected in frame order.
    (0..b)
        .into_par_iter()
        .map(|f| {
            decode_proposals(
                anchors,
                classes,
                bins,
                &cls[f * a * k..(f + 1) * a * k],
                &boxes[f * a * 7..(f + 1) * a * 7],
                &dir[f * a * nb..(f + 1) * a * nb],
                nms,
            )
        })
        .collect()
}

/// Each frame's proposals from `predictions` over `anchors` (`anchor_tensor`: the same
/// anchors on the predictions' device, [`super::data::anchor_tensor`]), chosen on that GPU
/// device: the anchors ranked, decoded and suppressed there, and only the kept anchors'
/// prediction rows read back and decoded in f64 as on the host.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
pub fn device_proposals(
    anchors: &fusiondet_voxel::Anchors,
    classes: &[fusiondet_kitti::ObjectClass],
    bins: &fusiondet_voxel::DirectionBins,
    anchor_tensor: &Tensor<2>,
    predictions: &AnchorPredictions,
    nms: &super::config::NmsConfig,
) -> Vec<Vec<Proposal>> {
    use super::proposals::proposals_of_rows;
    use fusiondet_models::voxel_rcnn::proposals_device::{ProposalSelection, select_proposals};
    let [b, a, k] = predictions.cls.dims();
    let nb = bins.bins;
    let selection = ProposalSelection {
        pre_max: nms.pre_max,
        post_max: nms.post_max,
        iou: nms.iou as f32,
        dir_offset: bins.offset as f32,
        dir_limit_offset: bins.limit_offset as f32,
        dir_bins: nb,
    };
    let (cls, boxes, dir) = (
        predictions.cls.clone().inner(),
        predictions.boxes.clone().inner(),
        predictions.direction.clone().inner(),
    );
    let (counts, rows) = select_proposals(
        cls.clone(),
        boxes.clone(),
        dir.clone(),
        anchor_tensor.clone(),
        selection,
    );
    let width = k + 7 + nb;
    let table = Tensor::cat(vec![cls, boxes, dir], 2)
        .reshape([b * a, width])
        .select(0, rows.clone());
    let ints = |t: Tensor<1, Int>| -> Vec<usize> {
        t.into_data()
            .convert::<i64>()
            .try_to_vec::<i64>()
            .expect("integer tensor data")
            .into_iter()
            .map(|v| v as usize)
            .collect()
    };
    let (counts, rows) = (ints(counts), ints(rows));
    let table = values(&table);
    let post = nms.post_max;
    (0..b)
        .map(|f| {
            let slots = f * post..f * post + counts[f];
            proposals_of_rows(
                anchors,
                classes,
                bins,
                slots.map(|slot| (rows[slot] - f * a, &table[slot * width..(slot + 1) * width])),
            )
        })
        .collect()
}

/// `FUSIONDET_PROPOSALS=check`: one line a frame whose device proposals are not the host's
/// (other anchors kept, or a box more than 1 mm or a score more than 1e-6 away).
#[cfg(any(feature = "wgpu", feature = "cuda"))]
fn report_proposal_differences(host: &[Vec<Proposal>], device: &[Vec<Proposal>]) {
    for (f, (h, d)) in host.iter().zip(device).enumerate() {
        let same = |p: &Proposal, q: &Proposal| {
            let (x, y) = (p.bbox.to_array(), q.bbox.to_array());
            x.iter().zip(&y).all(|(u, v)| (u - v).abs() <= 1e-3)
                && (p.score - q.score).abs() <= 1e-6
                && p.class == q.class
        };
        let first = h.iter().zip(d).position(|(p, q)| !same(p, q));
        if h.len() != d.len() || first.is_some() {
            eprintln!(
                "proposals check: frame {f}: host kept {}, device {}; first difference at rank {}",
                h.len(),
                d.len(),
                first.unwrap_or(h.len().min(d.len()))
            );
        }
    }
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

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use super::super::data::anchor_tensor;
    use super::*;
    use crate::voxel_rcnn::config::NmsConfig;
    use fusiondet_dataset::rng::Sampler;
    use fusiondet_kitti::ObjectClass;
    use fusiondet_voxel::{AnchorClass, AnchorConfig, Anchors, DirectionBins, VoxelConfig};

    /// Car and pedestrian anchors 0.4 m apart over a 2e × 2e m grid, two headings each
    /// (2,400 overlapping anchors at e = 8 m), and `frames` frames of seeded random
    /// predictions: logits [frames · A · 2], codes [· 7], direction logits [· 2].
    fn scene(frames: usize, e: f64) -> (Anchors, DirectionBins, [Vec<f32>; 3]) {
        let voxel = VoxelConfig {
            point_range: [0.0, -e, -3.0, 2.0 * e, e, 1.0],
            voxel_size: [0.2, 0.2, 0.1],
            ..VoxelConfig::default()
        };
        let mut pedestrian = AnchorClass::car();
        pedestrian.class = ObjectClass::Pedestrian;
        pedestrian.size = [0.8, 0.6, 1.7];
        let config = AnchorConfig {
            classes: vec![AnchorClass::car(), pedestrian],
            feature_map_stride: 2,
            ..AnchorConfig::default()
        };
        let anchors = Anchors::generate(&voxel, &config).unwrap();
        let bins = DirectionBins::from_config(&config);
        let a = anchors.len();
        let mut s = Sampler::new(2026);
        let mut draw = |n: usize, scale: f64| -> Vec<f32> {
            (0..n).map(|_| (s.normal() * scale) as f32).collect()
        };
        let cls = draw(frames * a * 2, 2.0);
        let codes = draw(frames * a * 7, 0.3);
        let dir = draw(frames * a * 2, 1.0);
        (anchors, bins, [cls, codes, dir])
    }

    /// The predictions on `device`, the codes laid out as a transposed view (the kernels
    /// read every input by its strides).
    fn predictions(
        values: &[Vec<f32>; 3],
        frames: usize,
        a: usize,
        device: &Device,
    ) -> AnchorPredictions {
        let [cls, codes, dir] = values;
        let codes_by_column: Vec<f32> = (0..frames)
            .flat_map(|f| (0..7).flat_map(move |j| (0..a).map(move |i| (f, i, j))))
            .map(|(f, i, j)| codes[(f * a + i) * 7 + j])
            .collect();
        AnchorPredictions {
            cls: Tensor::from_data(TensorData::new(cls.clone(), [frames, a, 2]), device),
            boxes: Tensor::<3>::from_data(TensorData::new(codes_by_column, [frames, 7, a]), device)
                .swap_dims(1, 2),
            direction: Tensor::from_data(TensorData::new(dir.clone(), [frames, a, 2]), device),
        }
    }

    #[test]
    fn on_wgpu_the_devices_proposals_are_the_hosts() {
        let Some(device) =
            fusiondet_nn::cube::working_wgpu_device("the device's choice of proposals")
        else {
            return;
        };
        use fusiondet_models::voxel_rcnn::proposals_device::SUPPRESSION_ROWS;
        let frames = 2;
        let (anchors, bins, values) = scene(frames, 8.0);
        let a = anchors.len();
        assert!(
            a > 2 * SUPPRESSION_ROWS,
            "{a} anchors: three blocks when all are ranked"
        );
        let classes = [ObjectClass::Car, ObjectClass::Pedestrian];
        let on_device = predictions(&values, frames, a, &device);
        let anchors_on_device = anchor_tensor(&anchors, &device);
        // Both ways over the same predictions: the host reads them back.
        let both = |anchors: &Anchors,
                    bins: &DirectionBins,
                    anchor_tensor: &Tensor<2>,
                    on_device: &AnchorPredictions,
                    nms: &NmsConfig| {
            (
                device_proposals(anchors, &classes, bins, anchor_tensor, on_device, nms),
                host_proposals(anchors, &classes, bins, on_device, nms),
            )
        };
        for nms in [
            // Ranked and capped: 1,000 of 2,400 ranked, at most 60 kept.
            NmsConfig {
                pre_max: 1000,
                post_max: 60,
                iou: 0.7,
            },
            // Every anchor ranked (fewer than pre_max), a lower threshold, no cap reached: the
            // greedy pass carries its state over all three blocks of SUPPRESSION_ROWS.
            NmsConfig {
                pre_max: 5000,
                post_max: 2000,
                iou: 0.3,
            },
            // The same, capped in the second block (about 1,560 kept uncapped), and in the
            // first, the later blocks then skipped.
            NmsConfig {
                pre_max: 5000,
                post_max: 1200,
                iou: 0.3,
            },
            NmsConfig {
                pre_max: 5000,
                post_max: 300,
                iou: 0.3,
            },
        ] {
            let (device_kept, host_kept) =
                both(&anchors, &bins, &anchors_on_device, &on_device, &nms);
            for (f, (kept, host)) in device_kept.iter().zip(&host_kept).enumerate() {
                assert!(host.len() > 10, "frame {f}: {} kept", host.len());
                assert!(
                    host.len() < nms.pre_max.min(a),
                    "frame {f}: nothing suppressed"
                );
                assert_eq!(kept, host, "frame {f}, {nms:?}");
            }
            if nms.post_max < 2000 {
                assert_eq!(device_kept[0].len(), nms.post_max, "the cap is reached");
            }
        }
        // Fewer anchors than one shared-memory tile of the sort (400 of 1,024).
        let (small, small_bins, small_values) = scene(frames, 2.0);
        let small_a = small.len();
        assert!(small_a < 512, "{small_a} anchors");
        let nms = NmsConfig {
            pre_max: 300,
            post_max: 100,
            iou: 0.5,
        };
        let (device_kept, host_kept) = both(
            &small,
            &small_bins,
            &anchor_tensor(&small, &device),
            &predictions(&small_values, frames, small_a, &device),
            &nms,
        );
        for (f, (kept, host)) in device_kept.iter().zip(&host_kept).enumerate() {
            assert!(!host.is_empty());
            assert_eq!(kept, host, "a small frame {f}");
        }
        // Nothing ranked or nothing kept: no proposal, as on the host.
        for (pre_max, post_max) in [(1000, 0), (0, 60)] {
            let none = NmsConfig {
                pre_max,
                post_max,
                iou: 0.7,
            };
            let (kept, host) = both(&anchors, &bins, &anchors_on_device, &on_device, &none);
            assert_eq!(kept, vec![Vec::new(); frames], "{none:?}");
            assert_eq!(host, kept, "{none:?}");
        }
    }
}
