//! Detection: 2D detections → frustums → network → one 3D box per frustum → per-frame
//! 3D NMS → KITTI result files. Score = 3D object probability + 2D detection score,
//! as F-ConvNet reports it. A refinement model runs its first stage, then its own
//! network on frustums cut around the first stage's boxes.

use crate::config::ExperimentConfig;
use crate::device::ComputeDevice;
use crate::error::{Result, TrainError};
use crate::trainer::load_split;
use burn::prelude::*;
use fusiondet_frustum::{
    FrameSource, FrustumDataset, FrustumFrames, InMemoryFrames, SkipCounts, decode_box,
};
use fusiondet_geometry::nms_3d;
use fusiondet_kitti::{DatasetDir, Detection2d, Object, read_detections2d, write_objects};
use fusiondet_models::{FConvNet, decode};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// What `fusiondet detect` was asked to do.
#[derive(Debug, Clone)]
pub struct DetectOptions {
    pub config: ExperimentConfig,
    pub checkpoint: PathBuf,
    pub data_dir: PathBuf,
    pub split: String,
    pub out_dir: PathBuf,
    /// 2D detections; `None` reads `DATA/rgb_detections/rgb_detection_<split>.txt`.
    pub detections: Option<PathBuf>,
    /// Where the network runs.
    pub device: ComputeDevice,
}

/// What a detection run did, with its time per stage.
#[derive(Debug, Clone, Default)]
pub struct DetectSummary {
    pub frames: usize,
    pub detections_2d: usize,
    pub frustums: usize,
    pub skipped: SkipCounts,
    pub boxes_written: usize,
    pub timing: StageTimes,
}

/// Wall time per stage of detection.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StageTimes {
    pub load: Duration,
    pub frustums: Duration,
    pub network: Duration,
    pub decode_nms: Duration,
}

impl StageTimes {
    /// Everything but loading from disk: what frames/s is measured over.
    pub fn compute(&self) -> Duration {
        self.frustums + self.network + self.decode_nms
    }
}

/// A trained detector: one network, or a refinement network with the first stage whose
/// boxes it refines.
pub struct Detector {
    pub model: FConvNet,
    pub config: ExperimentConfig,
    pub first_stage: Option<Box<Detector>>,
}

/// What one detection pass over a set of frames produced.
#[derive(Debug, Clone, Default)]
pub struct FrameResults {
    /// Result objects of every frame (empty lists for frames without detections).
    pub objects: BTreeMap<String, Vec<Object>>,
    /// Frustums left out, by reason (both stages' for a refinement model).
    pub skipped: SkipCounts,
    /// Frustums the network ran on (the last stage's).
    pub frustums: usize,
}

impl Detector {
    /// Loads the checkpoint trained with `config` onto `device`, and for a refinement
    /// configuration its first stage (`refine.first_stage`).
    pub fn load(config: ExperimentConfig, checkpoint: &Path, device: &Device) -> Result<Self> {
        let model = fusiondet_models::load_checkpoint(&config.model, checkpoint, device)?;
        let first_stage = match &config.refine {
            Some(r) => {
                let first = ExperimentConfig::for_checkpoint(&r.first_stage, None)?;
                if first.refine.is_some() {
                    return Err(TrainError::Config {
                        path: r.first_stage.clone(),
                        message: "the first stage is itself a refinement model; name a \
                                  first-stage (2D-box frustum) checkpoint"
                            .into(),
                    });
                }
                Some(Box::new(Detector::load(first, &r.first_stage, device)?))
            }
            None => None,
        };
        Ok(Detector {
            model,
            config,
            first_stage,
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
                timing.frustums += t.elapsed();
                let proposals = first.detect_frames(device, frames.clone(), detections, timing)?;
                skipped.merge(&proposals.skipped);
                let t = Instant::now();
                let d = FrustumDataset::from_proposals(
                    frames,
                    &proposals.objects,
                    self.config.detect_frustum(),
                    false,
                )?;
                timing.frustums += t.elapsed();
                d
            }
            None => {
                let d = FrustumDataset::from_detections(
                    frames,
                    detections,
                    self.config.detect_frustum(),
                )?;
                timing.frustums += t.elapsed();
                d
            }
        };
        skipped.merge(&dataset.skips());
        let candidates = run_network(&self.model, device, &self.config, &dataset, ids, timing)?;
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
        timing.decode_nms += t.elapsed();
        Ok(FrameResults {
            objects,
            skipped,
            frustums: dataset.len(),
        })
    }
}

/// One box per frustum of `dataset`, by frame (before NMS). Score = the network's
/// object probability + the frustum's own score (the 2D detection's, or the
/// first-stage box's), as F-ConvNet reports it.
fn run_network<S: FrustumFrames>(
    model: &FConvNet,
    device: &Device,
    config: &ExperimentConfig,
    dataset: &FrustumDataset<S>,
    ids: Vec<String>,
    timing: &mut StageTimes,
) -> Result<BTreeMap<String, Vec<Object>>> {
    let mut candidates: BTreeMap<String, Vec<Object>> =
        ids.into_iter().map(|id| (id, Vec::new())).collect();
    let mut batches = dataset.in_order(config.detect.seed, config.detect.batch_size);
    loop {
        // Batches are prepared (sampled, sliced, collated) when asked for: time the ask.
        let t = Instant::now();
        let Some(prepared) = batches.next() else {
            break;
        };
        let prepared = prepared?;
        timing.frustums += t.elapsed();
        let t = Instant::now();
        let inputs = model.inputs(&prepared.batch, device)?;
        let output = model.forward_inputs(&inputs);
        let predictions = decode(&output, &inputs, &config.model)?;
        timing.network += t.elapsed();
        let t = Instant::now();
        for (sample, p) in prepared.samples.iter().zip(&predictions) {
            let box3d = decode_box(
                [0.0; 3],
                p.center.map(f64::from),
                p.heading_bin,
                p.heading_residual as f64,
                p.size_cluster,
                p.size_residual.map(f64::from),
                &sample.frame,
            );
            let score = p.score as f64 + sample.score.unwrap_or(0.0);
            candidates
                .entry(sample.frame_id.clone())
                .or_default()
                .push(sample.to_kitti_object(box3d, score));
        }
        timing.decode_nms += t.elapsed();
    }
    Ok(candidates)
}

/// What detection runs on: the detector (on the CPU), the split's frames and the 2D
/// detections.
pub(crate) struct DetectInputs {
    pub detector: Detector,
    pub device: Device,
    pub frames: InMemoryFrames,
    pub detections: Vec<Detection2d>,
}

/// Loads a checkpoint (with its first stage for a refinement model), the first
/// `max_frames` frames of a split (0 = all) and the 2D detections (`detections`, or
/// the dataset's own file for the split).
pub(crate) fn load_detect_inputs(
    config: &ExperimentConfig,
    checkpoint: &Path,
    data_dir: &Path,
    split: &str,
    detections: Option<&Path>,
    max_frames: usize,
    device: ComputeDevice,
) -> Result<DetectInputs> {
    let device = device.device();
    let detector = Detector::load(config.clone(), checkpoint, &device)?;
    let frames = load_split(data_dir, split, max_frames, false)?;
    let det_path = detections
        .map(Path::to_path_buf)
        .unwrap_or_else(|| DatasetDir::new(data_dir).rgb_detections(split));
    Ok(DetectInputs {
        detector,
        device,
        frames,
        detections: read_detections2d(&det_path)?,
    })
}

/// Loads the split, runs detection and writes one KITTI result file per frame of the
/// split (empty when nothing was detected), atomically.
pub fn detect(options: &DetectOptions) -> Result<DetectSummary> {
    let cfg = &options.config;
    let mut timing = StageTimes::default();
    let t = Instant::now();
    let DetectInputs {
        detector,
        device,
        frames,
        detections,
    } = load_detect_inputs(
        cfg,
        &options.checkpoint,
        &options.data_dir,
        &options.split,
        options.detections.as_deref(),
        0,
        options.device,
    )?;
    timing.load += t.elapsed();
    let num_frames = frames.len();
    let results = detector.detect_frames(&device, frames, &detections, &mut timing)?;
    write_results(&options.out_dir, &results.objects)?;
    Ok(DetectSummary {
        frames: num_frames,
        detections_2d: detections.len(),
        frustums: results.frustums,
        skipped: results.skipped,
        boxes_written: results.objects.values().map(Vec::len).sum(),
        timing,
    })
}

/// Writes `OUT/<id>.txt` for every frame.
pub fn write_results(out_dir: &Path, results: &BTreeMap<String, Vec<Object>>) -> Result<()> {
    std::fs::create_dir_all(out_dir).map_err(|e| TrainError::RunDir {
        path: out_dir.to_path_buf(),
        message: format!("cannot create the result directory: {e}"),
    })?;
    for (id, objects) in results {
        write_objects(&out_dir.join(format!("{id}.txt")), objects)?;
    }
    Ok(())
}
