//! The frustum family's detector: 2D detections → frustums → network → one 3D box per
//! frustum → per-frame 3D NMS. Score = 3D object probability + 2D detection score, as
//! F-ConvNet reports it. A refinement model runs its first stage, then its own network
//! on frustums cut around the first stage's boxes.

use crate::config::ExperimentConfig;
use crate::detection::{FrameResults, StageTimes};
use crate::error::{PipelineError, Result};
use burn::prelude::*;
use fusiondet_frustum::{BoxDetection, FrustumDataset, FrustumFrames, FrustumSample, SkipCounts};
use fusiondet_geometry::{Box3d, nms_3d};
use fusiondet_kitti::Detection2d;
use fusiondet_models::{FConvNet, decode};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

/// The frustum family's stages, as `bench` and `detect` report them.
pub const STAGE_FRUSTUMS: &str = "frustums (extract, sample, slice)";
pub const STAGE_NETWORK: &str = "network (tensors, forward, decode)";
pub const STAGE_DECODE: &str = "boxes + 3D NMS";

/// What detection on SUN RGB-D scenes produced: result lines by scene (upright depth),
/// frustums left out, and frustums the network ran on.
pub struct SceneResults {
    pub objects: BTreeMap<String, Vec<fusiondet_sunrgbd::Object>>,
    pub skipped: SkipCounts,
    pub samples: usize,
}

/// A trained detector: one network, or a refinement network with the first stage whose
/// boxes it refines.
pub struct FrustumDetector {
    pub model: FConvNet,
    pub config: ExperimentConfig,
    pub first_stage: Option<Box<FrustumDetector>>,
}

impl FrustumDetector {
    /// Loads the checkpoint trained with `config` onto `device`, and for a refinement
    /// configuration its first stage (`refine.first_stage`).
    pub fn load(config: ExperimentConfig, checkpoint: &Path, device: &Device) -> Result<Self> {
        let mut model = fusiondet_models::load_checkpoint(&config.model, checkpoint, device)?;
        if !device.is_autodiff() {
            model.fold_norms();
        }
        let first_stage = match &config.refine {
            Some(r) => {
                let first = ExperimentConfig::for_checkpoint(&r.first_stage, None)?;
                if first.refine.is_some() {
                    return Err(PipelineError::Config {
                        path: r.first_stage.clone(),
                        message: "the first stage is itself a refinement model; name a \
                                  first-stage (2D-box frustum) checkpoint"
                            .into(),
                    });
                }
                Some(Box::new(FrustumDetector::load(
                    first,
                    &r.first_stage,
                    device,
                )?))
            }
            None => None,
        };
        Ok(FrustumDetector {
            model,
            config,
            first_stage,
        })
    }

    /// Detection on SUN RGB-D scenes (a one-stage model): 2D detections → frustums →
    /// network → one box per frustum → 3D NMS per scene and class (indoor classes
    /// overlap where KITTI's do not: a chair under a table). Boxes come back in upright
    /// depth with their class, as result lines.
    pub fn detect_scenes<S: FrustumFrames, D: BoxDetection>(
        &self,
        device: &Device,
        frames: S,
        detections: &[D],
        timing: &mut StageTimes,
    ) -> Result<SceneResults> {
        let ids: Vec<String> = (0..frames.len())
            .map(|i| frames.frame_id(i).to_string())
            .collect();
        let t = Instant::now();
        let dataset =
            FrustumDataset::from_detections(frames, detections, self.config.detect_frustum())?;
        timing.add(STAGE_FRUSTUMS, t.elapsed());
        let candidates = run_network(
            &self.model,
            device,
            &self.config,
            &dataset,
            ids,
            timing,
            |sample, box3d, score| (sample.class, sample.box2d, box3d, score),
        )?;
        let t = Instant::now();
        let objects = candidates
            .into_iter()
            .map(|(id, found)| {
                let mut keep: Vec<usize> = Vec::new();
                let mut classes: Vec<_> = found.iter().map(|f| f.0.as_str()).collect();
                classes.sort_unstable();
                classes.dedup();
                for class in classes {
                    let mine: Vec<usize> = (0..found.len())
                        .filter(|&i| found[i].0.as_str() == class)
                        .collect();
                    let boxes: Vec<Box3d> = mine.iter().map(|&i| found[i].2).collect();
                    let scores: Vec<f64> = mine.iter().map(|&i| found[i].3).collect();
                    keep.extend(
                        nms_3d(&boxes, &scores, self.config.detect.nms_iou)
                            .into_iter()
                            .map(|k| mine[k]),
                    );
                }
                // Frustum order, whatever the classes' order.
                keep.sort_unstable();
                let lines = keep
                    .into_iter()
                    .map(|i| {
                        let (class, bbox, box3d, score) = &found[i];
                        fusiondet_sunrgbd::Object {
                            class: class.as_str().to_string(),
                            box3d: fusiondet_dataset::indoor::upright_box(box3d),
                            bbox: *bbox,
                            score: Some(*score),
                        }
                    })
                    .collect();
                (id, lines)
            })
            .collect();
        timing.add(STAGE_DECODE, t.elapsed());
        Ok(SceneResults {
            objects,
            skipped: dataset.skips(),
            samples: dataset.len(),
        })
    }

    /// Runs detection on in-memory frames: 2D detections → frustums → network → one box
    /// per frustum → per-frame 3D NMS; a refinement model then cuts a frustum around
    /// each first-stage box and runs its own network and NMS on those. A refined box
    /// scores the first-stage score plus the refinement network's object probability.
    pub fn detect_frames<S: FrustumFrames + Clone>(
        &self,
        device: &Device,
        frames: S,
        detections: &[Detection2d],
        timing: &mut StageTimes,
    ) -> Result<FrameResults> {
        let ids: Vec<String> = (0..frames.len())
            .map(|i| frames.frame_id(i).to_string())
            .collect();
        let mut skipped = SkipCounts::default();
        let t = Instant::now();
        let dataset = match &self.first_stage {
            Some(first) => {
                timing.add(STAGE_FRUSTUMS, t.elapsed());
                let proposals = first.detect_frames(device, frames.clone(), detections, timing)?;
                skipped.merge(&proposals.skipped);
                let t = Instant::now();
                let d = FrustumDataset::from_proposals(
                    frames,
                    &proposals.objects,
                    self.config.detect_frustum(),
                    false,
                )?;
                timing.add(STAGE_FRUSTUMS, t.elapsed());
                d
            }
            None => {
                let d = FrustumDataset::from_detections(
                    frames,
                    detections,
                    self.config.detect_frustum(),
                )?;
                timing.add(STAGE_FRUSTUMS, t.elapsed());
                d
            }
        };
        skipped.merge(&dataset.skips());
        let candidates = run_network(
            &self.model,
            device,
            &self.config,
            &dataset,
            ids,
            timing,
            |sample, box3d, score| sample.to_kitti_object(box3d, score),
        )?;
        let t = Instant::now();
        let objects = candidates
            .into_iter()
            .map(|(id, objects)| {
                let boxes: Vec<_> = objects.iter().map(|o| o.box3d).collect();
                let scores: Vec<f64> = objects.iter().map(|o| o.score.unwrap_or(0.0)).collect();
                let keep = nms_3d(&boxes, &scores, self.config.detect.nms_iou);
                (id, keep.into_iter().map(|k| objects[k].clone()).collect())
            })
            .collect();
        timing.add(STAGE_DECODE, t.elapsed());
        Ok(FrameResults {
            objects,
            skipped,
            samples: dataset.len(),
        })
    }
}

/// One box per frustum of `dataset`, by frame (before NMS), as `make` writes it from
/// the sample, the camera-frame box and the score. Score = the network's object
/// probability + the frustum's own score (the 2D detection's, or the first-stage box's),
/// as F-ConvNet reports it.
fn run_network<S: FrustumFrames, T>(
    model: &FConvNet,
    device: &Device,
    config: &ExperimentConfig,
    dataset: &FrustumDataset<S>,
    ids: Vec<String>,
    timing: &mut StageTimes,
    make: impl Fn(&FrustumSample, Box3d, f64) -> T,
) -> Result<BTreeMap<String, Vec<T>>> {
    let mut candidates: BTreeMap<String, Vec<T>> =
        ids.into_iter().map(|id| (id, Vec::new())).collect();
    let mut batches = dataset.in_order(config.detect.seed, config.detect.batch_size);
    loop {
        // Batches are prepared (sampled, sliced, collated) when asked for: time the ask.
        let t = Instant::now();
        let Some(prepared) = batches.next() else {
            break;
        };
        let prepared = prepared?;
        timing.add(STAGE_FRUSTUMS, t.elapsed());
        let t = Instant::now();
        let inputs = model.inputs(&prepared.batch, device)?;
        let output = model.forward_inputs(&inputs);
        let predictions = decode(&output, &inputs, &config.model)?;
        timing.add(STAGE_NETWORK, t.elapsed());
        let t = Instant::now();
        for (sample, p) in prepared.samples.iter().zip(&predictions) {
            let box3d = config
                .frustum
                .coder
                .decode_encoding(&p.encoding(), &sample.frame);
            let score = p.score as f64 + sample.score.unwrap_or(0.0);
            candidates
                .entry(sample.frame_id.clone())
                .or_default()
                .push(make(sample, box3d, score));
        }
        timing.add(STAGE_DECODE, t.elapsed());
    }
    Ok(candidates)
}
